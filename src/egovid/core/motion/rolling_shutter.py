"""Rolling shutter: points moved to their frame's time stamp, per row, as Gyroflow does.

A rolling-shutter sensor exposes row ``y`` of an ``H``-row frame at ``t_k + δ(y)`` with
``δ(y) = (y / (H - 1) - 1/2) · readout`` (the middle row at the frame's time stamp; a negative
readout reads bottom to top). While the camera turns at angular velocity ``ω`` (rad/s, camera
axes), the camera of row ``y`` is ``R(t_k) exp(ω δ(y))``, so a ray ``r`` seen there is the ray
``exp(ω δ(y)) r`` of the frame's own (middle-row) camera. Mapping every matched point that way
(:func:`to_frame_time`) makes a frame pair an exact rotation again, which is what the pairwise
rotation fit assumes: without it, a yaw shake shears the rows and vision reads part of it as
roll (on a synthetic clip with a 30 ms readout at 30 fps: per-frame error 1.25°, roll r 0.24).

``ω`` of a pair comes from its own first fit (:func:`pair_rate`: ``Log(Q) / Δt``), a fixed point
that converges in one or two steps because the correction is small against the motion; with a
synced gyro its rates serve as well. The readout comes from the file (GoPro ``SROT``) or the
lens profile (:mod:`egovid.core.camera.lens_profiles`); :func:`row_offsets` is the one copy of
the row-time rule, shared with the stabiliser's per-row warp.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from egovid.core.motion.pairwise import rotation_from_correspondences
from egovid.core.rotations import so3_exp, so3_log


def row_offsets(y: np.ndarray, height: int, readout_s: float) -> np.ndarray:
    """Exposure time (seconds, relative to the frame's time stamp) of pixel rows ``y`` (any
    shape, pixels from the top, of a ``height``-row picture) read out in ``readout_s`` seconds."""
    return (np.asarray(y, float) / max(height - 1, 1) - 0.5) * readout_s


def to_frame_time(pts: np.ndarray, K: np.ndarray, omega: np.ndarray, readout_s: float, height: int) -> np.ndarray:
    """Points ``pts`` (N, 2) pixels as the frame's middle-row camera would have seen them, for a
    camera turning at ``omega`` (3,) rad/s in camera axes; ``K`` the 3x3 camera matrix of these
    pixels (``height`` rows)."""
    p = np.asarray(pts, float)
    if len(p) == 0 or readout_s == 0 or not np.any(omega):
        return p.copy()
    return _to_frame_time_rows(p, p[:, 1], K, omega, readout_s, height)


def pair_rate(Q: np.ndarray, dt_s: float) -> np.ndarray:
    """Mean angular velocity (rad/s, camera axes) of a frame pair with ``Q = R_iᵀ R_j`` over
    ``dt_s`` seconds (right perturbation: ``R_j = R_i exp(ω Δt)``)."""
    return so3_log(np.asarray(Q, float)) / max(dt_s, 1e-9)


def corrected_pair(
    pi: np.ndarray, pj: np.ndarray, K: np.ndarray, Q: np.ndarray, dt_s: float, readout_s: float, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """The matched points of frames i and j moved to their frames' time stamps, with the rate of
    the pair's current rotation ``Q`` over its ``dt_s`` seconds."""
    w = pair_rate(Q, dt_s)
    return to_frame_time(pi, K, w, readout_s, height), to_frame_time(pj, K, w, readout_s, height)


def frame_rates(R: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Angular velocity (N, 3) rad/s in each frame's own axes at the frame times, from camera-to-world
    orientations ``R`` (N, 3, 3): central differences (one-sided at the ends)."""
    n = len(R)
    if n < 2:
        return np.zeros((n, 3))
    a = np.clip(np.arange(n) - 1, 0, n - 1)
    b = np.clip(np.arange(n) + 1, 0, n - 1)
    steps = so3_log(np.swapaxes(R[a], 1, 2) @ R[b])
    return steps / np.maximum(np.asarray(times)[b] - np.asarray(times)[a], 1e-9)[:, None]


def undistort_fisheye(pts: np.ndarray, K: np.ndarray, distortion) -> np.ndarray:
    """Pixels (N, 2) of an OpenCV-fisheye picture (``K``, ``k1..k4``) as the pinhole camera ``K``
    would see them."""
    import cv2

    p = np.asarray(pts, np.float64).reshape(-1, 1, 2)
    if len(p) == 0:
        return np.zeros((0, 2))
    return cv2.fisheye.undistortPoints(p, K, np.asarray(distortion, np.float64), P=K).reshape(-1, 2)


def refit_pairs(pairs, rates: np.ndarray | None, readout_s: float, *, distortion=None):
    """The pair set (:class:`egovid.core.motion.estimate.PairSet`) re-fitted from its kept matches
    (raw pixels of the work picture) with the lens ``distortion`` (fisheye ``k1..k4``) removed and
    every point moved to its frame's time stamp for a camera turning at ``rates`` (N, 3) rad/s
    (camera axes, per frame: vision's first pass or the synced gyro). Rows are timed where the
    sensor read them (the distorted picture's rows). Pairs without kept matches, or whose re-fit
    fails, stay as they were."""
    K, h = pairs.work.K, pairs.work.height
    out = []
    for i, j, p in pairs.pairs:
        m = pairs.matches.get((i, j))
        if m is None or not p.ok:
            out.append((i, j, p))
            continue
        fixed = []
        for pts, k in ((m[0], i), (m[1], j)):
            pts = np.asarray(pts, float)
            rows = pts[:, 1].copy()
            if distortion is not None:  # all k zero: the equidistant fisheye, not a pinhole
                pts = undistort_fisheye(pts, K, distortion)
            if rates is not None and readout_s:
                pts = _to_frame_time_rows(pts, rows, K, rates[k], readout_s, h)
            fixed.append(pts)
        q = rotation_from_correspondences(fixed[0], fixed[1], K, threshold_px=pairs.threshold_px)
        out.append((i, j, q if q.ok else p))
    return replace(pairs, pairs=out)


def _to_frame_time_rows(pts, rows, K, omega, readout_s, height) -> np.ndarray:
    """:func:`to_frame_time` with the rows' times taken from ``rows`` (the sensor rows)."""
    d = row_offsets(rows, height, readout_s)
    rays = np.column_stack([pts, np.ones(len(pts))]) @ np.linalg.inv(K).T
    R = so3_exp(np.outer(d, np.asarray(omega, float)))
    turned = np.einsum("nij,nj->ni", R, rays) @ K.T
    return turned[:, :2] / turned[:, 2:3]
