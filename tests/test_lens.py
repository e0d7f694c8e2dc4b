"""The lens models (pinhole, fisheye) and the warp through a fisheye, against hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.lens import EQUIDISTANT, PINHOLE, Lens, project, unproject
from egovid.core.rotations import matrix_from_euler
from egovid.fpv.stabilize.warp import FrameView, MeshWarp


@pytest.mark.parametrize("lens", [PINHOLE, EQUIDISTANT, Lens("fisheye", (0.04, 0.02, -0.004, -0.002))])
def test_project_undoes_unproject(lens):
    intr = Intrinsics.from_focal(848, 480, 390.0)
    px, py = np.meshgrid(np.linspace(0, 847, 9), np.linspace(0, 479, 7))
    back = project(lens, intr, unproject(lens, intr, px, py))
    assert np.allclose(back[..., 0], px, atol=1e-6) and np.allclose(back[..., 1], py, atol=1e-6)


def test_equidistant_radius_is_focal_times_angle():
    intr = Intrinsics.from_focal(800, 600, 400.0)
    ray = np.array([np.sin(1.0), 0.0, np.cos(1.0)])  # 1 rad off the axis, to the right
    p = project(EQUIDISTANT, intr, ray)
    assert p[0] == pytest.approx(intr.cx + 400.0, abs=1e-9) and p[1] == pytest.approx(intr.cy, abs=1e-9)


def test_fisheye_warp_moves_the_edge_as_the_rotation_does_not_as_a_pinhole():
    """A 1° yaw on an equidistant lens moves every pixel on the horizon by f · 1° (the angle adds);
    a pinhole warp would move the edge pixel by f · (tan(θ + 1°) - tan θ), several times more."""
    intr = Intrinsics.from_focal(848, 480, 390.0)
    warp = MeshWarp(intr, lens=EQUIDISTANT)
    view = FrameView(matrix_from_euler(np.array([1.0]), np.zeros(1), np.zeros(1))[0], np.eye(3)[None], 1.0)
    ux = np.array([intr.cx, 10.0, 837.0])
    sx, sy = warp.source_points(view, ux, np.full(3, intr.cy))
    step = np.diff(np.array([ux, sx]), axis=0)[0]
    assert np.allclose(np.abs(step), 390.0 * np.radians(1.0), rtol=1e-3) and np.allclose(sy, intr.cy, atol=1e-6)
    img = (np.arange(720 * 848) % 251).astype(np.uint8).reshape(720, 848)
    same = warp.warp_i420(img, FrameView(np.eye(3), np.eye(3)[None], 1.0))
    assert np.abs(same.astype(int) - img).max() <= 1  # identity view: the picture unchanged
