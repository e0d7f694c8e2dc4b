"""One remap per frame: the new view of a frame from per-row source rotations and a zoom.

Output pixel ``u`` of frame k (the stabilised view, orientation ``R̃_k``, zoomed by ``z_k`` about
the image centre) shows the scene direction ``R̃_k K⁻¹ Z_k⁻¹ u``. A rolling-shutter sensor read
that direction at the row where it lands, with the orientation the camera had when that row was
read: ``p = K R(s)ᵀ R̃_k K⁻¹ Z_k⁻¹ u`` with ``s`` the row's readout position (0 first row, 1 last).
``s`` depends on ``p`` itself; one fixed-point step from the frame-centre rotation is exact to
well below a pixel for any real readout (the rotation changes by a fraction of a degree across
a frame). Where the readout time is 0 every row has the frame's rotation and the map is a
homography. With a fisheye lens (:mod:`egovid.core.camera.lens`) the same holds with the lens's
own projection in place of ``K`` and ``K⁻¹``: the output keeps the input's projection (a fisheye
stays a fisheye) and every pixel moves as the rotation really moves it, not as a pinhole would.

The map is computed on a mesh (every ``cell`` pixels, and one cell beyond each edge) and
interpolated bilinearly to every pixel by ``cv2.resize``; the map is smooth (a homography per
row band), so a 16-px mesh is within a few hundredths of a pixel of the exact per-pixel map.
Luma and the two 4:2:0 chroma planes are remapped with their own mesh (chroma sited as in
:mod:`egovid.fpv.stabilize.render`). Angles in radians inside, rotations camera-to-world.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.lens import PINHOLE, Lens, project, unproject

#: Readout direction in display orientation for each rotation flag: the sensor's first row is
#: the display's top row (0), left column (90), bottom row (180) or right column (270).
READOUT_AXES = {0: ("y", False), 90: ("x", False), 180: ("y", True), 270: ("x", True)}


def readout_position(px: np.ndarray, py: np.ndarray, width: int, height: int, rotation: int) -> np.ndarray:
    """Readout position (0 first sensor row, 1 last) of display pixels ``(px, py)``."""
    axis, flip = READOUT_AXES[int(rotation) % 360]
    s = (py / max(height - 1, 1)) if axis == "y" else (px / max(width - 1, 1))
    return np.clip(1.0 - s if flip else s, 0.0, 1.0)


@dataclass
class FrameView:
    """What one output frame shows: ``R_new`` (3, 3) its orientation; ``R_rows`` (B, 3, 3) the
    source orientation at B evenly spaced readout positions (B = 1: global shutter); ``zoom``."""

    R_new: np.ndarray
    R_rows: np.ndarray
    zoom: float = 1.0


class MeshWarp:
    """Per-frame remap tables for a video of ``intr`` (display orientation) through ``lens`` with
    rotation flag ``rotation`` (for the readout direction), on a mesh of ``cell`` pixels."""

    def __init__(self, intr: Intrinsics, rotation: int = 0, cell: int = 16, lens: Lens = PINHOLE) -> None:
        self.intr = intr
        self.lens = lens
        self.rotation = int(rotation) % 360
        self.w, self.h = intr.width, intr.height
        self._luma = self._mesh(self.w, self.h, cell, 1.0, 0.0)
        self._chroma = self._mesh(self.w // 2, self.h // 2, max(cell // 2, 4), 2.0, 0.5)

    @staticmethod
    def _mesh(w: int, h: int, cell: int, scale: float, offset: float):
        """Mesh nodes (in luma pixels) whose bilinear resize to (w + 2m, h + 2m) has node values
        exactly at the resize's sample positions; cropping m on each side gives the plane."""
        m = cell
        gw = int(np.ceil((w + 2 * m) / cell))
        gh = int(np.ceil((h + 2 * m) / cell))
        W, H = gw * cell, gh * cell
        # cv2.resize (linear) samples source node j at destination x = (j + 0.5) * cell - 0.5.
        xs = (np.arange(gw) + 0.5) * cell - 0.5 - m
        ys = (np.arange(gh) + 0.5) * cell - 0.5 - m
        gx, gy = np.meshgrid(xs, ys)
        # Plane pixel -> luma pixel (chroma: luma = 2 c + 0.5).
        return {
            "lx": gx * scale + offset,
            "ly": gy * scale + offset,
            "size": (W, H),
            "crop": (m, m, w, h),
            "scale": scale,
            "offset": offset,
        }

    def source_points(self, view: FrameView, ux: np.ndarray, uy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Source pixels (luma, display orientation) that output pixels ``(ux, uy)`` show.

        ``view`` may also hold K views at once (``R_new`` (K, 3, 3), ``R_rows`` (B, K, 3, 3),
        ``zoom`` (K, 1)) with points (1, N) or (K, N): then (K, N) pixels each."""
        cx, cy = (self.w - 1) / 2.0, (self.h - 1) / 2.0
        z = view.zoom
        vx = cx + (ux - cx) / z
        vy = cy + (uy - cy) / z
        rays = unproject(self.lens, self.intr, vx, vy)
        d = rays @ np.swapaxes(view.R_new, -1, -2)  # world directions
        B = len(view.R_rows)
        Rc = view.R_rows[B // 2] if B > 1 else view.R_rows[0]
        p = project(self.lens, self.intr, d @ Rc)  # Rᵀ d, row vectors
        if B > 1:
            s = readout_position(p[..., 0], p[..., 1], self.w, self.h, self.rotation)
            idx = np.clip(np.rint(s * (B - 1)).astype(int), 0, B - 1)
            # (..., 3, 3); K views: each point's band of its own frame, (K, N, 3, 3)
            Rs = view.R_rows[idx, np.arange(len(idx))[:, None]] if np.ndim(view.R_new) == 3 else view.R_rows[idx]
            cam = np.einsum("...ji,...j->...i", Rs, d)  # R(s)ᵀ d
            p = project(self.lens, self.intr, cam)
        return p[..., 0], p[..., 1]

    def _maps(self, view: FrameView, mesh: dict) -> tuple[np.ndarray, np.ndarray]:
        sx, sy = self.source_points(view, mesh["lx"], mesh["ly"])
        sx = ((sx - mesh["offset"]) / mesh["scale"]).astype(np.float32)
        sy = ((sy - mesh["offset"]) / mesh["scale"]).astype(np.float32)
        W, H = mesh["size"]
        m, _, w, h = mesh["crop"]
        mx = cv2.resize(sx, (W, H), interpolation=cv2.INTER_LINEAR)[m : m + h, m : m + w]
        my = cv2.resize(sy, (W, H), interpolation=cv2.INTER_LINEAR)[m : m + h, m : m + w]
        return mx, my

    def inverse_homography(self, view: FrameView) -> np.ndarray:
        """(3, 3) output -> source pixel map of a global-shutter view, ``K Rᵀ R̃ K⁻¹ Z⁻¹``."""
        K, Ki = self.intr.K, self.intr.K_inv
        cx, cy = (self.w - 1) / 2.0, (self.h - 1) / 2.0
        z = view.zoom
        Zi = np.array([[1 / z, 0, cx * (1 - 1 / z)], [0, 1 / z, cy * (1 - 1 / z)], [0, 0, 1.0]])
        return K @ view.R_rows[0].T @ view.R_new @ Ki @ Zi

    def warp_i420(self, img: np.ndarray, view: FrameView, border: tuple[int, int] = (0, 128)) -> np.ndarray:
        """The output I420 picture ((h*3/2, w), the dtype of ``img``: uint8, or uint16 at 10 bits)
        of source picture ``img`` for ``view``. A global-shutter view through a pinhole lens is one
        homography: ``cv2.warpPerspective`` (half the time of a remap through full-size maps at
        1080p, the same map); rows read at their own times go through the mesh."""
        w, h = self.w, self.h
        out = np.empty_like(img)
        if len(view.R_rows) == 1 and not self.lens.fisheye:
            Hi = self.inverse_homography(view)
            flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
            out[:h] = cv2.warpPerspective(
                img[:h], Hi, (w, h), flags=flags, borderMode=cv2.BORDER_CONSTANT, borderValue=border[0]
            )
            C = np.array([[0.5, 0.0, -0.25], [0.0, 0.5, -0.25], [0.0, 0.0, 1.0]])  # luma -> chroma
            Hc = C @ Hi @ np.linalg.inv(C)
            cw, ch = w // 2, h // 2
            planes = img[h:].reshape(2, ch, cw)
            oc = out[h:].reshape(2, ch, cw)
            for p in range(2):
                oc[p] = cv2.warpPerspective(
                    planes[p], Hc, (cw, ch), flags=flags, borderMode=cv2.BORDER_CONSTANT, borderValue=border[1]
                )
            return out
        mx, my = self._maps(view, self._luma)
        out[:h] = cv2.remap(img[:h], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=border[0])
        cx, cy = self._maps(view, self._chroma)
        cw, ch = w // 2, h // 2
        planes = img[h:].reshape(2, ch, cw)
        oc = out[h:].reshape(2, ch, cw)
        for p in range(2):
            oc[p] = cv2.remap(
                planes[p], cx, cy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=border[1]
            )
        return out

    def _border(self) -> tuple[np.ndarray, np.ndarray]:
        """Output-border points (x, y) that :meth:`coverage_shortfall` checks (132 of them)."""
        w, h = self.w, self.h
        t = np.linspace(0, 1, 33)
        ux = np.concatenate([t * (w - 1), np.full_like(t, w - 1), t[::-1] * (w - 1), np.zeros_like(t)])
        uy = np.concatenate([np.zeros_like(t), t * (h - 1), np.full_like(t, h - 1), t[::-1] * (h - 1)])
        return ux, uy

    def coverage_shortfall(self, view: FrameView) -> float:
        """Pixels by which the output frame's border falls outside the source frame (<= 0:
        covered), checked on the output border at every ``cell``/2 pixels."""
        w, h = self.w, self.h
        px, py = self.source_points(view, *self._border())
        return float(np.max(np.maximum.reduce([-px, -py, px - (w - 1), py - (h - 1)])))

    def coverage_shortfalls(self, R_new: np.ndarray, R_rows: np.ndarray, zoom: np.ndarray) -> np.ndarray:
        """(K,) :meth:`coverage_shortfall` of K views at once: ``R_new`` (K, 3, 3), ``R_rows``
        (K, B, 3, 3), ``zoom`` (K,)."""
        w, h = self.w, self.h
        ux, uy = self._border()
        view = FrameView(R_new, R_rows.swapaxes(0, 1), np.asarray(zoom, float)[:, None])
        px, py = self.source_points(view, ux[None, :], uy[None, :])
        return np.max(np.maximum.reduce([-px, -py, px - (w - 1), py - (h - 1)]), axis=1)


def required_zoom(warp: MeshWarp, views: list[FrameView], max_zoom: float = 4.0) -> np.ndarray:
    """(K,) the least zoom that keeps each view's output frame inside its source (bisection, 24
    halvings from [1, ``max_zoom``]; 1 where zoom 1 is covered). All frames are bisected together
    (:meth:`MeshWarp.coverage_shortfalls`): the same arithmetic, point by point, as one
    :meth:`MeshWarp.coverage_shortfall` per frame and step, without its per-call cost."""
    if not views:
        return np.ones(0)
    R_new = np.stack([v.R_new for v in views])
    R_rows = np.stack([v.R_rows for v in views])
    out = np.ones(len(views))
    todo = np.flatnonzero(warp.coverage_shortfalls(R_new, R_rows, np.ones(len(views))) > 0.0)
    if len(todo) == 0:
        return out
    R_new, R_rows = R_new[todo], R_rows[todo]
    lo, hi = np.ones(len(todo)), np.full(len(todo), float(max_zoom))
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        good = warp.coverage_shortfalls(R_new, R_rows, mid) <= 0.0
        hi = np.where(good, mid, hi)
        lo = np.where(good, lo, mid)
    out[todo] = hi
    return out


def rows_at(times: np.ndarray, readout_s: float, bands: int = 1) -> np.ndarray:
    """(K, B) times (seconds) of B evenly spaced readout positions of frames starting at ``times``."""
    b = max(int(bands), 1)
    s = np.linspace(0.0, 1.0, b) if b > 1 else np.array([0.5])
    return np.asarray(times, float)[:, None] + s[None, :] * readout_s
