"""Gyroflow's method as a stabilisation peer, where a gyro exists.

What Gyroflow (gyroflow/gyroflow, GPL-3.0; re-implemented here from its documented steps, no code
taken) does with its defaults, on the camera's orientation sampled at the gyro's rate:

1. **Smoothing, "Default" algorithm** (``src/core/smoothing/default_algo.rs``; smoothness 0.5,
   max smoothness 1 s, 0.1 s at high speed, second pass on): the angular speed of every sample is
   smoothed forwards and backwards with a 0.1-s exponential, divided by
   ``500 °/s · smoothness · 0.5``; the orientation is smoothed by spherical interpolation towards
   each sample, forwards then backwards, with a time constant blended from 1 s (at rest) to
   0.1 s (at that speed, extrapolated beyond it). The second pass measures how far the result
   strays from the raw orientation, keeps the half of the largest distances (normalised, below
   0.5 set to 0, smoothed with 0.1 s, renormalised to 0.5–1), and smooths once more with the
   speed ratio multiplied by that distance.
2. **Horizon lock** (optional, ``smoothing/horizon.rs``): the smoothed view keeps its viewing
   direction and its roll about it is set level with gravity.
3. **Adaptive zoom** (``zooming/zoom_dynamic.rs``, method "envelope follower", window 4 s, zoom
   limit 130 %): the zoom each frame needs to stay covered, as a field-of-view factor
   ``1/zoom``, followed backwards then forwards by ``q = min(x, a x + (1 - a) q)`` with the 4-s
   time constant, then again with 0.2 s; never more than the zoom limit.
4. **Rolling-shutter correction**: every row is warped with the orientation of its own readout
   time (``frame_readout_time``), here by :class:`egovid.fpv.stabilize.warp.MeshWarp`.

Quaternions are (w, x, y, z), camera-to-world, angles radians, times seconds.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
from numba import njit

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.lens import PINHOLE, Lens
from egovid.core.errors import EgovidError
from egovid.fpv.stabilize.render_views import render_views
from egovid.fpv.stabilize.warp import FrameView, MeshWarp, required_zoom, rows_at

#: Gyroflow's defaults (Default algorithm, adaptive zoom, zoom limit).
SMOOTHNESS = 0.5
MAX_SMOOTHNESS_S = 1.0
HIGH_SPEED_SMOOTHNESS_S = 0.1
MAX_VELOCITY_DEG_S = 500.0
ZOOM_WINDOW_S = 4.0
ZOOM_SECOND_PASS_S = 0.2
MAX_ZOOM = 1.30


@njit(cache=True)
def _slerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:  # pragma: no cover - numba
    d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
    bb = b.copy()
    if d < 0.0:
        bb = -bb
        d = -d
    if d > 0.9995:
        out = a + t * (bb - a)
    else:
        th = math.acos(min(d, 1.0))
        s = math.sin(th)
        out = (math.sin((1.0 - t) * th) / s) * a + (math.sin(t * th) / s) * bb
    return out / math.sqrt(np.sum(out * out))


@njit(cache=True)
def _angle_between(a: np.ndarray, b: np.ndarray) -> float:  # pragma: no cover - numba
    d = abs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3])
    return 2.0 * math.acos(min(d, 1.0))


@njit(cache=True)
def _exp_both(x: np.ndarray, alpha: float) -> np.ndarray:  # pragma: no cover - numba
    """Exponential smoothing forwards, then backwards from the forward pass's end (Gyroflow's order)."""
    y = x.copy()
    prev = y[0]
    for i in range(1, len(y)):
        y[i] = prev * (1.0 - alpha) + y[i] * alpha
        prev = y[i]
    for i in range(len(y) - 2, -1, -1):
        y[i] = prev * (1.0 - alpha) + y[i] * alpha
        prev = y[i]
    return y


@njit(cache=True)
def _slerp_both(q: np.ndarray, alphas: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    """Forward then backward spherical smoothing of quaternions ``q`` (N, 4) with per-sample ``alphas``."""
    n = q.shape[0]
    f = np.empty_like(q)
    cur = q[0].copy()
    for i in range(n):
        cur = _slerp(cur, q[i], min(alphas[i], 1.0))
        f[i] = cur
    out = np.empty_like(q)
    cur = f[n - 1].copy()
    for i in range(n - 1, -1, -1):
        cur = _slerp(cur, f[i], min(alphas[i], 1.0))
        out[i] = cur
    return out


def smooth_default(
    times: np.ndarray,
    quats: np.ndarray,
    smoothness: float = SMOOTHNESS,
    max_smoothness_s: float = MAX_SMOOTHNESS_S,
    fast_smoothness_s: float = HIGH_SPEED_SMOOTHNESS_S,
) -> np.ndarray:
    """Gyroflow's Default smoothing (module docstring, step 1) of ``quats`` (N, 4) sampled at
    ``times`` (N,) seconds; returns (N, 4) smoothed quaternions."""
    q = np.ascontiguousarray(quats, dtype=float)
    n = len(q)
    if n < 2:
        return q.copy()
    duration = float(times[-1] - times[0])
    rate = n / max(duration, 1e-9)

    def alpha(tc: float) -> float:
        return 1.0 - math.exp(-(1.0 / rate) / tc)

    a_slow, a_fast = alpha(max_smoothness_s), alpha(fast_smoothness_s)
    vel = np.zeros(n)
    dots = np.abs(np.sum(q[1:] * q[:-1], axis=1))
    vel[1:] = 2.0 * np.arccos(np.clip(dots, -1.0, 1.0)) * rate * 180.0 / math.pi
    vel = _exp_both(vel, a_fast)
    ratio = vel / (MAX_VELOCITY_DEG_S * smoothness * 0.5)
    s2 = _slerp_both(q, a_slow * (1.0 - ratio) + a_fast * ratio)
    dist = np.array([_angle_between(q[i], s2[i]) for i in range(n)])
    top = dist.max()
    if top <= 1e-12:
        return s2
    dist = dist / top
    dist[dist < 0.5] = 0.0
    dist = _exp_both(dist, a_fast)
    top = dist.max()
    dist = (dist / top + 1.0) / 2.0 if top > 1e-12 else np.full(n, 0.5)
    r = ratio * dist
    return _slerp_both(s2, a_slow * (1.0 - r) + a_fast * r)


def level_horizon(R: np.ndarray, down_world: np.ndarray) -> np.ndarray:
    """(N, 3, 3) orientations with the viewing direction of ``R`` (camera-to-world) and no roll
    against gravity (``down_world`` (3,), the world's down direction): the camera's x axis
    horizontal, its y axis as close to down as the viewing direction allows."""
    z = R[:, :, 2]
    g = np.asarray(down_world, float) / np.linalg.norm(down_world)
    y = g[None] - np.sum(g[None] * z, axis=1, keepdims=True) * z
    norm = np.linalg.norm(y, axis=1, keepdims=True)
    y = np.where(norm > 1e-9, y / np.maximum(norm, 1e-12), R[:, :, 1])
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=2)


def envelope_zoom(
    required: np.ndarray, fps: float, window_s: float = ZOOM_WINDOW_S, max_zoom: float = MAX_ZOOM
) -> np.ndarray:
    """Gyroflow's adaptive zoom (envelope follower, module docstring step 3): per-frame zoom
    (>= ``required`` (K,) everywhere, <= ``max_zoom``)."""
    fov = 1.0 / np.maximum(np.asarray(required, float), 1.0)

    def follow(x: np.ndarray, a: float) -> np.ndarray:
        out = np.empty_like(x)
        q = x[-1]
        for i in range(len(x) - 1, -1, -1):
            q = min(x[i], x[i] * a + q * (1.0 - a))
            out[i] = q
        res = np.empty_like(x)
        q = out[0]
        for i in range(len(x)):
            q = min(out[i], out[i] * a + q * (1.0 - a))
            res[i] = q
        return res

    a1 = 1.0 - math.exp(-(1.0 / fps) / window_s)
    a2 = 1.0 - math.exp(-(1.0 / fps) / ZOOM_SECOND_PASS_S)
    fov = follow(follow(fov, a1), a2)
    return np.minimum(1.0 / fov, max_zoom)


@dataclass
class GyroflowPlan:
    """What the peer renders: the per-frame views and zoom, and the smoothed orientations at the
    frame centres (K, 3, 3)."""

    views: list[FrameView]
    zoom: np.ndarray
    smoothed: np.ndarray


def plan_gyroflow(
    gyro_times: np.ndarray,
    gyro_R: np.ndarray,
    frame_times: np.ndarray,
    intr: Intrinsics,
    fps: float,
    *,
    readout_s: float = 0.0,
    rotation: int = 0,
    horizon_down: np.ndarray | None = None,
    max_zoom: float = MAX_ZOOM,
    bands: int = 16,
    lens: Lens = PINHOLE,
) -> GyroflowPlan:
    """Gyroflow's views of every frame: ``gyro_R`` (N, 3, 3) camera-to-world orientations at
    ``gyro_times`` (N,) seconds on the video clock; frames start their readout at
    ``frame_times`` (K,); ``horizon_down`` the world's down direction to lock the horizon to;
    ``lens`` the camera's projection (Gyroflow warps through the lens profile)."""
    from scipy.spatial.transform import Rotation, Slerp

    rot = Rotation.from_matrix(gyro_R)
    xyzw = rot.as_quat()
    q = np.ascontiguousarray(np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1))
    q[np.cumsum(np.r_[0, np.sum(q[1:] * q[:-1], axis=1) < 0]) % 2 == 1] *= -1  # one hemisphere
    qs = smooth_default(np.asarray(gyro_times, float), q)
    smooth = Slerp(gyro_times, Rotation.from_quat(np.concatenate([qs[:, 1:], qs[:, :1]], axis=1)))
    raw = Slerp(gyro_times, rot)
    lo, hi = float(gyro_times[0]), float(gyro_times[-1])
    centre = np.clip(np.asarray(frame_times, float) + 0.5 * readout_s, lo, hi)
    R_new = smooth(centre).as_matrix()
    if horizon_down is not None:
        R_new = level_horizon(R_new, horizon_down)
    b = bands if readout_s > 0 else 1
    rows = np.clip(rows_at(frame_times, readout_s, b), lo, hi)
    R_rows = raw(rows.ravel()).as_matrix().reshape(len(frame_times), b, 3, 3)
    views = [FrameView(R_new[k], R_rows[k], 1.0) for k in range(len(frame_times))]
    warp = MeshWarp(intr, rotation, lens=lens)
    zoom = envelope_zoom(required_zoom(warp, views), fps, max_zoom=max_zoom)
    for v, z in zip(views, zoom, strict=True):
        v.zoom = float(z)
    return GyroflowPlan(views, zoom, R_new)


def run_gyroflow(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    plan: GyroflowPlan,
    intr: Intrinsics,
    *,
    rotation: int = 0,
    crf: int = 18,
    lens: Lens = PINHOLE,
) -> float:
    """Render ``plan`` from ``src`` into ``dst``; returns the seconds it took."""

    if len(plan.views) == 0:
        raise EgovidError("nothing to render", "give the frames' views")
    return render_views(src, dst, plan.views, MeshWarp(intr, rotation, lens=lens), crf=crf).seconds
