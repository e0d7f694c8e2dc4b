"""The thesis' Euler decomposition (eq. 6.3–6.7) and SO(3) helpers, on hand-made rotations."""

import numpy as np
import pytest

from egovid.core.rotations import (
    angle_deg,
    euler_from_matrix,
    euler_from_matrix_thesis,
    matrix_from_euler,
    project_to_so3,
    rot_x,
    rot_y,
    rot_z,
    rotation_homography,
    so3_exp,
    so3_log,
)


def test_elementary_rotations_by_hand():
    c, s = np.cos(np.deg2rad(30)), np.sin(np.deg2rad(30))
    np.testing.assert_allclose(rot_y(30), [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-15)
    np.testing.assert_allclose(rot_x(30), [[1, 0, 0], [0, c, -s], [0, s, c]], atol=1e-15)
    np.testing.assert_allclose(rot_z(30), [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-15)


def test_angle_conventions_by_looking_direction():
    # Camera axes x right, y down, z forward; R maps camera to world.
    fwd = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(matrix_from_euler(90, 0, 0) @ fwd, [1, 0, 0], atol=1e-12)  # yaw right
    np.testing.assert_allclose(matrix_from_euler(0, 90, 0) @ fwd, [0, -1, 0], atol=1e-12)  # pitch up
    right = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(matrix_from_euler(0, 0, 90) @ right, [0, 1, 0], atol=1e-12)  # roll cw


@pytest.mark.parametrize(
    "ypr", [(0, 0, 0), (30, 0, 0), (0, -20, 0), (0, 0, 45), (10, 2.5, -1.5), (-170, 60, 80), (179.9, -89.5, -89)]
)
def test_decomposition_recovers_hand_made_angles(ypr):
    R = matrix_from_euler(*ypr)
    np.testing.assert_allclose(euler_from_matrix(R), ypr, atol=1e-9)
    np.testing.assert_allclose(euler_from_matrix_thesis(R), ypr, atol=1e-9)


def test_decomposition_matches_thesis_formulas_on_random_rotations():
    rng = np.random.default_rng(0)
    e = rng.uniform([-180, -89, -89], [180, 89, 89], (2000, 3))
    R = matrix_from_euler(e[:, 0], e[:, 1], e[:, 2])
    np.testing.assert_allclose(euler_from_matrix(R), e, atol=1e-9)
    np.testing.assert_allclose(euler_from_matrix_thesis(R), e, atol=1e-9)


@pytest.mark.parametrize("pitch", [90.0, -90.0, 89.9999999, -89.9999999, 89.99])
def test_gimbal_lock_neighbourhood_recomposes_exactly(pitch):
    R = matrix_from_euler(35.0, pitch, 12.0)
    e = euler_from_matrix(R)
    np.testing.assert_allclose(matrix_from_euler(*e), R, atol=1e-7)
    assert abs(e[1] - pitch) < 1e-4
    if abs(pitch) == 90.0:
        # Only yaw ± roll is defined: roll goes to 0, the whole turn to yaw.
        assert e[2] == 0.0
        expected_yaw = 35.0 - 12.0 if pitch > 0 else 35.0 + 12.0
        assert abs(e[0] - expected_yaw) < 1e-6


def test_log_exp_project_and_angle():
    rng = np.random.default_rng(1)
    w = rng.normal(size=(50, 3)) * 0.5
    R = so3_exp(w)
    np.testing.assert_allclose(so3_log(R), w, atol=1e-10)
    np.testing.assert_allclose(angle_deg(R), np.rad2deg(np.linalg.norm(w, axis=1)), atol=1e-8)
    noisy = R + rng.normal(scale=1e-3, size=R.shape)
    P = project_to_so3(noisy)
    np.testing.assert_allclose(P @ np.swapaxes(P, -1, -2), np.broadcast_to(np.eye(3), P.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(P), 1.0, atol=1e-12)
    assert np.all(angle_deg(np.swapaxes(P, -1, -2) @ R) < 0.2)


def test_rotation_homography_moves_principal_point_by_focal_tan():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    R_old, R_new = np.eye(3), matrix_from_euler(10, 0, 0)
    H = rotation_homography(K, R_new.T @ R_old)
    p = H @ [320, 240, 1]
    # Turning the camera right by 10° moves the old centre left by f tan 10°.
    assert abs(p[0] / p[2] - (320 - 500 * np.tan(np.deg2rad(10)))) < 1e-9
