"""Rotation conventions of egovid, and the thesis' Euler decomposition (eq. 6.3–6.7).

Conventions (used everywhere in egovid):

* Camera axes: x right, y down, z forward (OpenCV). World axes are the camera axes of frame 0.
* A camera orientation ``R`` is the camera-to-world rotation (the TUM convention): a direction
  ``d`` in camera coordinates is ``R @ d`` in world coordinates.
* Relative rotation between frames i and j: ``Q_ij = R_i.T @ R_j`` maps camera-j coordinates to
  camera-i coordinates.
* Angles are degrees at every public interface: ``R = Ry(yaw) @ Rx(pitch) @ Rz(roll)``.
  Positive yaw turns the view to the right, positive pitch turns it up, positive roll turns the
  camera clockwise about its viewing direction as seen from behind it (so the scene appears to
  turn counter-clockwise in the video).

The thesis decomposes the world-to-camera matrix ``R_cw = R.T`` as ``Rz(θz) Rx(θx) Ry(θy)``
(eq. 6.3). Since ``R.T = Rz(-roll) Rx(-pitch) Ry(-yaw)``, its angles are the negatives of ours:
yaw is taken first (the primary, intentional motion), then pitch, and roll last.
"""

from __future__ import annotations

import numpy as np

ArrayLike = np.ndarray | float


def _as_rad(a: ArrayLike) -> np.ndarray:
    return np.deg2rad(np.asarray(a, dtype=float))


def rot_x(deg: ArrayLike) -> np.ndarray:
    """Rotation about the x axis by ``deg`` degrees; shape ``(..., 3, 3)``."""
    a = _as_rad(deg)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(deg: ArrayLike) -> np.ndarray:
    """Rotation about the y axis by ``deg`` degrees; shape ``(..., 3, 3)``."""
    a = _as_rad(deg)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(deg: ArrayLike) -> np.ndarray:
    """Rotation about the z axis by ``deg`` degrees; shape ``(..., 3, 3)``."""
    a = _as_rad(deg)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def matrix_from_euler(yaw: ArrayLike, pitch: ArrayLike, roll: ArrayLike) -> np.ndarray:
    """Camera-to-world rotation ``Ry(yaw) Rx(pitch) Rz(roll)`` from angles in degrees."""
    return rot_y(yaw) @ rot_x(pitch) @ rot_z(roll)


def euler_from_matrix(R: np.ndarray, *, gimbal_eps: float = 1e-9) -> np.ndarray:
    """Yaw, pitch, roll in degrees (shape ``(..., 3)``) of camera-to-world rotations ``R``.

    Inverse of :func:`matrix_from_euler`. It is the thesis' decomposition (eq. 6.4–6.7) written
    with ``atan2`` on entries that stay well conditioned: pitch from ``asin``, yaw and roll from
    entries that are scaled by ``cos(pitch)``. At gimbal lock (pitch = ±90°) only yaw ± roll is
    defined; roll is then set to 0 and the whole turn given to yaw, the primary motion.
    """
    R = np.asarray(R, dtype=float)
    # M = R.T = Rz(a) Rx(b) Ry(c) with (a, b, c) = (-roll, -pitch, -yaw); see module docstring.
    M = np.swapaxes(R, -1, -2)
    sb = np.clip(M[..., 2, 1], -1.0, 1.0)
    b = np.arcsin(sb)
    cb = np.sqrt(np.maximum(0.0, 1.0 - sb * sb))
    c = np.arctan2(-M[..., 2, 0], M[..., 2, 2])
    a = np.arctan2(-M[..., 0, 1], M[..., 1, 1])
    lock = cb < gimbal_eps
    if np.any(lock):
        a = np.where(lock, 0.0, a)
        # With a = 0 the first column of M is (cos c, ±sin c, 0) for sin(b) = ±1.
        c_lock = np.where(sb > 0, np.arctan2(M[..., 1, 0], M[..., 0, 0]), np.arctan2(-M[..., 1, 0], M[..., 0, 0]))
        c = np.where(lock, c_lock, c)
    return np.rad2deg(np.stack([-c, -b, -a], axis=-1))


def euler_from_matrix_thesis(R: np.ndarray) -> np.ndarray:
    """The literal thesis formulas (eq. 6.4–6.7) on ``R_cw = R.T``, returned as yaw, pitch, roll.

    Kept to show that :func:`euler_from_matrix` is the same decomposition: they agree wherever
    |roll| < 90° and |pitch| < 90° (the literal eq. 6.6 divides by cos(roll) and eq. 6.4 by
    cos(pitch), so it breaks down outside that range and at gimbal lock).
    """
    M = np.swapaxes(np.asarray(R, dtype=float), -1, -2)
    theta_y = np.arctan2(-M[..., 2, 0], M[..., 2, 2])  # eq. 6.4
    Ry_inv = np.swapaxes(rot_y(np.rad2deg(theta_y)), -1, -2)
    Rzx = M @ Ry_inv  # eq. 6.7
    theta_z = np.arctan2(Rzx[..., 1, 0], Rzx[..., 0, 0])  # eq. 6.5
    theta_x = np.arctan2(-Rzx[..., 1, 2], Rzx[..., 1, 1])  # eq. 6.6
    return np.rad2deg(np.stack([-theta_y, -theta_x, -theta_z], axis=-1))


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (axis * angle, radians), shape ``(..., 3)``."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    return Rotation.from_matrix(flat).as_rotvec().reshape((*R.shape[:-2], 3))


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrices from rotation vectors (radians), shape ``(..., 3, 3)``."""
    from scipy.spatial.transform import Rotation

    w = np.asarray(w, dtype=float)
    return Rotation.from_rotvec(w.reshape(-1, 3)).as_matrix().reshape((*w.shape[:-1], 3, 3))


def angle_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angle of ``R`` in degrees (shape ``R.shape[:-2]``)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    return np.rad2deg(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius norm) to each 3x3 matrix ``M``: SVD with the sign fixed."""
    M = np.asarray(M, dtype=float)
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones(M.shape[:-1])
    D[..., -1] = d
    return (U * D[..., None, :]) @ Vt


def rotation_homography(K: np.ndarray, Q: np.ndarray, K_out: np.ndarray | None = None) -> np.ndarray:
    """Homography ``K_out Q K^-1`` that maps pixels of a view to a view rotated by ``Q``.

    With ``Q = R_new.T @ R_old`` it re-renders a frame taken with orientation ``R_old`` as if it
    had been taken with orientation ``R_new`` (valid for distant scenes or pure rotation).
    """
    K_out = K if K_out is None else K_out
    return K_out @ Q @ np.linalg.inv(K)
