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

import numpy as np

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
    d = row_offsets(p[:, 1], height, readout_s)
    rays = np.column_stack([p, np.ones(len(p))]) @ np.linalg.inv(K).T
    R = so3_exp(np.outer(d, np.asarray(omega, float)))  # (N, 3, 3)
    turned = np.einsum("nij,nj->ni", R, rays) @ K.T
    return turned[:, :2] / turned[:, 2:3]


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
