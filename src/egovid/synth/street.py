"""Ray-cast rendering of a street scene for synthetic dashcam drives.

The scene is laid out in street coordinates: x to the right of the street's centre line, y up,
z along the street (metres). A straight corridor: the road (two lanes each way, 10.5 m, dashed
centre line and edge lines), sidewalks, building facades at x = ±9 m in blocks with their own
height and photo texture (with alleys between some), trees on the sidewalks, passing vehicles
(boxes), sky with clouds, sun shadows of the buildings on the ground, and distance haze. A curved
street is rendered as if straight (its GPS track still curves): what matters for the archive is
that the same place looks the same on every drive, under that drive's light.

Textures are bundled photos with a blur pyramid chosen per pixel from its footprint, so distant
surfaces are smooth instead of aliased (as through a real lens). The kernel runs in numba, in
parallel over image rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit, prange

from egovid.synth.photos import COLOUR, GREY, photo

FACADE_X = 9.0
ROAD_HALF = 5.25
TREE_X = 6.6
TEX = 256  # texture side (pixels)
LEVELS = 5
TEX_PER_M = 48.0  # texels per metre on facades and ground


@dataclass
class StreetScene:
    """Static content of one street (everything that is the same on every drive)."""

    length: float
    block_z: np.ndarray  # (2, B) block start z per side (0 = left, 1 = right), sorted
    block_h: np.ndarray  # (2, B) building height, 0 for an alley
    block_tex: np.ndarray  # (2, B) texture index
    tree_z: np.ndarray  # (2, T) tree positions per side (sorted), padded with 1e9
    tree_r: np.ndarray  # (2, T) crown radius
    textures: np.ndarray  # (n, LEVELS, TEX, TEX, 3) uint8 blur pyramid at full size
    road_tex: int
    walk_tex: int
    cloud_tex: int
    leaf_tex: int


def _pyramid(img: np.ndarray) -> np.ndarray:
    base = cv2.resize(img, (TEX, TEX), interpolation=cv2.INTER_AREA)
    out = [base]
    for level in range(1, LEVELS):
        k = 2**level
        small = cv2.resize(base, (TEX // k, TEX // k), interpolation=cv2.INTER_AREA)
        out.append(cv2.resize(small, (TEX, TEX), interpolation=cv2.INTER_LINEAR))
    return np.stack(out)


def build_scene(length: float, seed: int) -> StreetScene:
    """Blocks, alleys, trees and textures of a street ``length`` metres long (deterministic)."""
    rng = np.random.default_rng(seed)
    facade_names = [n for n in (*COLOUR, *GREY) if n not in ("grass", "gravel", "text", "page")]
    names = [*facade_names, "gravel", "brick", "grass"]
    tex = []
    for n in names:
        img = photo(n)
        if n == "gravel":
            img = cv2.convertScaleAbs(cv2.GaussianBlur(img, (0, 0), 1.5), alpha=0.3, beta=55)  # smooth dark asphalt
        tex.append(_pyramid(img))
    # Clouds: smooth random field, mostly white on transparent-ish grey.
    noise = rng.random((32, 64)).astype(np.float32)
    clouds = cv2.resize(noise, (TEX, TEX), interpolation=cv2.INTER_CUBIC)
    clouds = cv2.GaussianBlur(clouds, (0, 0), 6)
    clouds = (255 * (clouds - clouds.min()) / (np.ptp(clouds) + 1e-6)).astype(np.uint8)
    tex.append(_pyramid(cv2.merge([clouds, clouds, clouds])))
    textures = np.stack(tex)
    n_facade = len(facade_names)
    B = int(length // 12) + 8
    block_z = np.zeros((2, B))
    block_h = np.zeros((2, B))
    block_tex = np.zeros((2, B), np.int64)
    for side in range(2):
        z = -30.0
        for b in range(B):
            block_z[side, b] = z
            alley = rng.random() < 0.15
            block_h[side, b] = 0.0 if alley else rng.uniform(6.0, 24.0)
            block_tex[side, b] = rng.integers(0, n_facade)
            z += rng.uniform(4.0, 8.0) if alley else rng.uniform(12.0, 30.0)
    T = int(length // 15) + 4
    tree_z = np.full((2, T), 1e9)
    tree_r = np.ones((2, T))
    for side in range(2):
        zs = np.sort(rng.uniform(-20, length + 20, T - 2))
        tree_z[side, : T - 2] = zs
        tree_r[side, : T - 2] = rng.uniform(1.2, 2.4, T - 2)
    return StreetScene(
        length=length,
        block_z=block_z,
        block_h=block_h,
        block_tex=block_tex,
        tree_z=tree_z,
        tree_r=tree_r,
        textures=textures,
        road_tex=names.index("gravel"),
        walk_tex=names.index("brick"),
        cloud_tex=len(names),
        leaf_tex=names.index("grass"),
    )


@njit(cache=True, inline="always")
def _sample(tex, t: int, level: int, u: float, v: float, out: np.ndarray) -> None:
    """Bilinear, wrapping texture lookup at texel coordinates (u, v) of pyramid ``level``."""
    n = tex.shape[2]
    u = u - math.floor(u / n) * n
    v = v - math.floor(v / n) * n
    x0 = int(u)
    y0 = int(v)
    fx = u - x0
    fy = v - y0
    x1 = (x0 + 1) % n
    y1 = (y0 + 1) % n
    x0 %= n
    y0 %= n
    for c in range(3):
        a = tex[t, level, y0, x0, c] * (1 - fx) + tex[t, level, y0, x1, c] * fx
        b = tex[t, level, y1, x0, c] * (1 - fx) + tex[t, level, y1, x1, c] * fx
        out[c] = a * (1 - fy) + b * fy


@njit(cache=True, inline="always")
def _level(dist: float, pix_angle: float, cos_inc: float) -> int:
    foot = dist * pix_angle / max(cos_inc, 0.15) * TEX_PER_M
    if foot <= 1.0:
        return 0
    lv = int(math.log2(foot) + 0.5)
    return min(lv, LEVELS - 1)


@njit(cache=True, inline="always")
def _block(zs: np.ndarray, z: float) -> int:
    lo, hi = 0, zs.shape[0] - 1
    if z < zs[0]:
        return -1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if zs[mid] <= z:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(cache=True, inline="always")
def _shadow(bz, bh, px: float, pz: float, sun: np.ndarray) -> bool:
    for side in range(2):
        fx = -FACADE_X if side == 0 else FACADE_X
        sx = sun[0]
        if (side == 0 and sx >= 0) or (side == 1 and sx <= 0):
            continue
        t = (fx - px) / sx
        if t <= 0:
            continue
        y = t * sun[1]
        z = pz + t * sun[2]
        b = _block(bz[side], z)
        if b >= 0 and y < bh[side, b]:
            return True
    return False


@njit(cache=True, parallel=True)
def render_kernel(
    width,
    height,
    fx,
    fy,
    cx,
    cy,
    R,
    cam,
    textures,
    bz,
    bh,
    btex,
    tz,
    tr,
    vehicles,
    vcolor,
    road_tex,
    walk_tex,
    cloud_tex,
    leaf_tex,
    gain,
    sun,
    shadow_dim,
    cloud_cover,
    cloud_shift,
    haze,
):
    """Render one frame (H, W, 3) BGR uint8. ``R`` maps camera (x right, y down, z ahead) to street
    (x right, y up, z along); ``cam`` is the camera position in street coordinates."""
    img = np.zeros((height, width, 3), np.uint8)
    pix_angle = 1.0 / fx
    sky_h = np.array([235.0, 215.0, 190.0])  # horizon (BGR)
    sky_z = np.array([200.0, 140.0, 80.0])  # zenith
    for row in prange(height):
        col = np.empty(3)
        tmp = np.empty(3)
        for colx in range(width):
            dcx = (colx - cx) / fx
            dcy = (row - cy) / fy
            nrm = math.sqrt(dcx * dcx + dcy * dcy + 1.0)
            dcx /= nrm
            dcy /= nrm
            dcz = 1.0 / nrm
            dx = R[0, 0] * dcx + R[0, 1] * dcy + R[0, 2] * dcz
            dy = R[1, 0] * dcx + R[1, 1] * dcy + R[1, 2] * dcz
            dz = R[2, 0] * dcx + R[2, 1] * dcy + R[2, 2] * dcz
            best = 1e18
            kind = 0  # 0 sky, 1 ground, 2 facade, 3 tree, 4 vehicle
            tmpz, tmpy, tside, tblock = 0.0, 0.0, 0, 0
            tree_trunk, tree_u, tree_v = False, 0.0, 0.0
            veh, vy = 0, 0.0
            # Ground.
            if dy < -1e-6:
                t = -cam[1] / dy
                if t < best:
                    best, kind = t, 1
            # Facades.
            for side in range(2):
                fxp = -FACADE_X if side == 0 else FACADE_X
                if (side == 0 and dx < -1e-6) or (side == 1 and dx > 1e-6):
                    t = (fxp - cam[0]) / dx
                    if 0 < t < best:
                        z = cam[2] + t * dz
                        y = cam[1] + t * dy
                        b = _block(bz[side], z)
                        if b >= 0 and 0.0 <= y <= bh[side, b]:
                            best, kind = t, 2
                            tmpz, tmpy, tside, tblock = z, y, side, b
            # Trees (billboards parallel to the street).
            for side in range(2):
                txp = -TREE_X if side == 0 else TREE_X
                if (side == 0 and dx < -1e-6) or (side == 1 and dx > 1e-6):
                    t = (txp - cam[0]) / dx
                    if 0 < t < best:
                        z = cam[2] + t * dz
                        y = cam[1] + t * dy
                        k = _block(tz[side], z + 3.0)
                        for kk in (k - 1, k, k + 1):
                            if kk < 0 or kk >= tz.shape[1]:
                                continue
                            r = tr[side, kk]
                            ddz = z - tz[side, kk]
                            trunk = abs(ddz) < 0.18 and y < 3.0
                            cyc = 2.6 + r
                            crown = ddz * ddz + (y - cyc) * (y - cyc) < r * r
                            if trunk or crown:
                                best, kind = t, 3
                                tree_trunk = trunk and not crown
                                tree_u, tree_v = ddz, y
                                break
            # Vehicles (axis-aligned boxes: x0, x1, y0, y1, z0, z1).
            for vi in range(vehicles.shape[0]):
                tmin, tmax = 0.0, best
                ok = True
                for a in range(3):
                    o = cam[a]
                    d = dx if a == 0 else (dy if a == 1 else dz)
                    lo = vehicles[vi, 2 * a]
                    hi = vehicles[vi, 2 * a + 1]
                    if abs(d) < 1e-9:
                        if o < lo or o > hi:
                            ok = False
                            break
                    else:
                        t1 = (lo - o) / d
                        t2 = (hi - o) / d
                        if t1 > t2:
                            t1, t2 = t2, t1
                        tmin = max(tmin, t1)
                        tmax = min(tmax, t2)
                        if tmin > tmax:
                            ok = False
                            break
                if ok and tmin < best:
                    best, kind = tmin, 4
                    veh, vy = vi, cam[1] + tmin * dy
            # Shade the hit.
            if kind == 0:
                el = max(dy, 0.0)
                for c in range(3):
                    col[c] = sky_h[c] * (1 - el) + sky_z[c] * el
                if dy > 0.02:
                    az = math.atan2(dx, dz)
                    u = (az / (2 * math.pi)) * 4 * TEX + cloud_shift
                    v = (1.0 - el) * 1.5 * TEX
                    _sample(textures, cloud_tex, 1, u, v, tmp)
                    a = min(max((tmp[0] / 255.0 - (1 - cloud_cover)) * 3.0, 0.0), 1.0) * min(el * 6, 1.0)
                    for c in range(3):
                        col[c] = col[c] * (1 - a) + 245.0 * a
            elif kind == 1:
                px = cam[0] + best * dx
                pz = cam[2] + best * dz
                lv = _level(best, pix_angle, abs(dy))
                if abs(px) <= ROAD_HALF:
                    _sample(textures, road_tex, lv, px * TEX_PER_M, pz * TEX_PER_M, col)
                    mark = abs(px) < 0.08 and (pz - math.floor(pz / 9.0) * 9.0) < 3.0
                    mark = mark or abs(abs(px) - (ROAD_HALF - 0.15)) < 0.1
                    if mark:
                        for c in range(3):
                            col[c] = 0.25 * col[c] + 0.75 * 225.0
                else:
                    _sample(textures, walk_tex, lv, px * TEX_PER_M, pz * TEX_PER_M, col)
                if _shadow(bz, bh, px, pz, sun):
                    for c in range(3):
                        col[c] *= shadow_dim
            elif kind == 2:
                lv = _level(best, pix_angle, abs(dx))
                tx = btex[tside, tblock]
                u = (tmpz - bz[tside, tblock]) * TEX_PER_M * 0.7
                v = (bh[tside, tblock] - tmpy) * TEX_PER_M * 0.7
                _sample(textures, tx, lv, u, v, col)
                lit = 0.75 + 0.35 * (sun[0] if tside == 0 else -sun[0])
                # Dark window bands give every facade a building-like structure.
                if (tmpy - math.floor(tmpy / 3.2) * 3.2) > 2.6:
                    lit *= 0.55
                for c in range(3):
                    col[c] *= lit
            elif kind == 3:
                if tree_trunk:
                    col[0], col[1], col[2] = 40.0, 60.0, 85.0
                else:
                    lv = _level(best, pix_angle, 1.0)
                    _sample(textures, leaf_tex, lv, tree_u * TEX_PER_M * 2, tree_v * TEX_PER_M * 2, col)
                    col[0] *= 0.35
                    col[1] *= 0.8
                    col[2] *= 0.35
            else:
                for c in range(3):
                    col[c] = vcolor[veh, c]
                if vy > vehicles[veh, 2] + 0.9:  # windows
                    for c in range(3):
                        col[c] *= 0.3
            if kind != 0:
                for c in range(3):
                    col[c] *= gain[c]
                h = 1.0 - math.exp(-best / haze)
                for c in range(3):
                    col[c] = col[c] * (1 - h) + sky_h[c] * gain[c] * h
            for c in range(3):
                v = col[c]
                img[row, colx, c] = 255 if v >= 255 else (0 if v <= 0 else int(v + 0.5))
    return img
