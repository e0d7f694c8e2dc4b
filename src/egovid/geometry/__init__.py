"""Rotations: SO(3) helpers, the thesis' Z-X-Y Euler decomposition, rotation homographies."""

from egovid.geometry.rotations import (
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

__all__ = [
    "angle_deg",
    "euler_from_matrix",
    "euler_from_matrix_thesis",
    "matrix_from_euler",
    "project_to_so3",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_homography",
    "so3_exp",
    "so3_log",
]
