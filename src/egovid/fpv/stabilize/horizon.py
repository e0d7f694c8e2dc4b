"""Horizon lock: the rendered view's roll levelled with gravity.

Where the camera logs an accelerometer, gravity comes from it: at rest and on average over a clip
an accelerometer reads the specific force ``f = a - g``, so the camera's down direction at time t
is ``-f(t)/|f(t)|`` and the world's down direction the mean of ``R(t) · down_cam(t)`` over the clip
(``R`` camera-to-world; the body's own accelerations average out). Where it does not, the world's
down is taken from the estimated path: the camera's mean down axis over the clip (a camera held
level on average; the stabiliser's default already levels roll to the clip's median).

Levelling keeps each view's viewing direction and turns it about that direction until its x axis
is horizontal (its y axis as close to down as the direction allows), as Gyroflow's horizon lock
does (:func:`egovid.fpv.stabilize.gyroflow_peer.level_horizon`). Angles in degrees (yaw, pitch,
roll as :mod:`egovid.core.rotations`), rotations camera-to-world.
"""

from __future__ import annotations

import numpy as np

from egovid.core.rotations import euler_from_matrix, matrix_from_euler
from egovid.fpv.stabilize.gyroflow_peer import level_horizon


def down_from_accelerometer(R_at: np.ndarray, accel_cam: np.ndarray) -> np.ndarray:
    """(3,) unit world down direction from accelerometer samples ``accel_cam`` (N, 3) m/s² in
    camera axes and the camera orientations ``R_at`` (N, 3, 3) at the same times."""
    f = np.asarray(accel_cam, float)
    n = np.linalg.norm(f, axis=1, keepdims=True)
    ok = n[:, 0] > 1e-6
    down_cam = -f[ok] / n[ok]
    d = np.einsum("nij,nj->i", np.asarray(R_at, float)[ok], down_cam)
    return d / np.linalg.norm(d)


def down_from_path(angles: np.ndarray) -> np.ndarray:
    """(3,) unit world down direction as the camera's mean down (y) axis over a (K, 3) path."""
    R = matrix_from_euler(angles[:, 0], angles[:, 1], angles[:, 2])
    d = R[:, :, 1].mean(axis=0)
    return d / np.linalg.norm(d)


def lock_horizon(angles: np.ndarray, down_world: np.ndarray) -> np.ndarray:
    """(K, 3) the path ``angles`` with every view levelled against ``down_world`` (3,)."""
    R = matrix_from_euler(angles[:, 0], angles[:, 1], angles[:, 2])
    L = level_horizon(R, down_world)
    out = euler_from_matrix(L)
    out[:, 0] = angles[:, 0] + ((out[:, 0] - angles[:, 0] + 180.0) % 360.0 - 180.0)  # keep unwrapped yaw
    return out
