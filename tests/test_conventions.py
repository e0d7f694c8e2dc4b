"""The README states the rotation convention; check the words against the code."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from egovid.core.rotations import euler_from_matrix, matrix_from_euler

README = Path(__file__).resolve().parents[1] / "README.md"


def _readme() -> str:
    return " ".join(README.read_text(encoding="utf-8").split())


def test_readme_formula_and_scipy_call_are_the_code():
    text = _readme()
    assert "camera-to-world" in text
    m = re.search(r"`R = R(\w)\((\w+)\) · R(\w)\((\w+)\) · R(\w)\((\w+)\)`", text)
    assert m, "the README must state R = Rα(angle) · Rβ(angle) · Rγ(angle)"
    axes, names = m.group(1, 3, 5), m.group(2, 4, 6)
    assert names == ("yaw", "pitch", "roll")
    seq = re.search(r'from_euler\("([XYZ]{3})", \[yaw, pitch, roll\], degrees=True\)', text)
    assert seq and seq.group(1) == "".join(a.upper() for a in axes)
    rng = np.random.default_rng(0)
    angles = rng.uniform([-180, -89, -180], [180, 89, 180], (500, 3))
    stated = Rotation.from_euler(seq.group(1), angles, degrees=True).as_matrix()
    np.testing.assert_allclose(matrix_from_euler(*angles.T), stated, atol=1e-12)
    np.testing.assert_allclose(euler_from_matrix(stated), angles, atol=1e-9)


def test_readme_signs_are_the_code():
    text = _readme()
    assert "positive yaw turns the view right, positive pitch up, positive roll turns the camera clockwise" in text
    forward, right = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    # x right, y down, z forward: the view direction in world coordinates is R @ forward.
    assert (matrix_from_euler(10, 0, 0) @ forward)[0] > 0  # yaw: view goes right (+x)
    assert (matrix_from_euler(0, 10, 0) @ forward)[1] < 0  # pitch: view goes up (-y)
    # roll: the camera's right axis tips down (+y): clockwise for someone looking along +z.
    assert (matrix_from_euler(0, 0, 10) @ right)[1] > 0
    # The thesis' world-to-camera form: Rᵀ = Rz(-roll) Rx(-pitch) Ry(-yaw).
    y, p, r = 20.0, -7.0, 3.0
    Rt = Rotation.from_euler("ZXY", [-r, -p, -y], degrees=True).as_matrix()
    np.testing.assert_allclose(matrix_from_euler(y, p, r).T, Rt, atol=1e-12)
