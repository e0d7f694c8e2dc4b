"""The stabiliser's rolling-shutter warp and its zoom budget through a lens.

Against independent truth: a synthetic rolling-shutter clip whose rows were rendered at their own
times (:mod:`egovid.synth.rolling`, known readout), measured on the decoded output by phase
correlation of its top and bottom row bands; the synthetic motion's own spline at the row times;
the fisheye's own coverage check at the zoom used."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.lens import EQUIDISTANT
from egovid.core.rotations import matrix_from_euler
from egovid.core.trajectory import Trajectory
from egovid.core.video import iter_frames
from egovid.fpv.stabilize.pipeline import row_rotations, stabilize, view_zooms
from egovid.fpv.stabilize.warp import FrameView, MeshWarp

FPS = 30.0


def _shake(n: int) -> np.ndarray:
    """(n, 3) yaw, pitch, roll degrees: shake only (4, 3 and 2.5 Hz sines), nothing intended."""
    t = np.arange(n) / FPS
    return np.stack(
        [
            1.5 * np.sin(2 * np.pi * 4.0 * t),
            0.8 * np.sin(2 * np.pi * 3.0 * t + 1.0),
            0.3 * np.sin(2 * np.pi * 2.5 * t),
        ],
        axis=1,
    )


def _band_shear(path) -> float:
    """RMS (px) of the difference between the frame-to-frame shifts of the top and the bottom
    third of the picture (phase correlation): 0 for a global-shutter picture of a camera turning
    about any axis through the centre but roll, the rolling shutter's skew and stretch otherwise."""
    g = [f.image.astype(np.float32) for f in iter_frames(path, gray=True)]
    h, w = g[0].shape
    b, cols = h // 3, slice(w // 8, w - w // 8)
    han = cv2.createHanningWindow((cols.stop - cols.start, b), cv2.CV_32F)
    d = [
        np.subtract(
            cv2.phaseCorrelate(p[:b, cols], q[:b, cols], han)[0], cv2.phaseCorrelate(p[-b:, cols], q[-b:, cols], han)[0]
        )
        for p, q in itertools.pairwise(g)
    ]
    return float(np.sqrt(np.mean(np.sum(np.square(d), axis=1))))


def test_row_rotations_follow_the_motion_between_frames():
    """Row bands get the orientation of their own readout time (the middle row at the frame's
    time stamp), as the motion's own spline gives it; no readout: the frame's rotation."""
    n, ro = 40, 0.03
    a = _shake(n)
    t = np.arange(n) / FPS
    R = matrix_from_euler(a[:, 0], a[:, 1], a[:, 2])
    rows = row_rotations(t, R, ro, rows=270, bands=5)
    assert rows.shape == (n, 5, 3, 3)
    assert np.allclose(row_rotations(t, R, 0.0, rows=270), R[:, None])
    spline = CubicSpline(t, a, axis=0)
    k = np.arange(3, n - 3)
    for b, s in enumerate(np.linspace(0, 1, 5)):
        want = spline(t[k] + (s - 0.5) * ro)
        Rw = matrix_from_euler(want[:, 0], want[:, 1], want[:, 2])
        err = np.degrees(
            np.arccos(np.clip((np.trace(np.swapaxes(Rw, 1, 2) @ rows[k, b], axis1=1, axis2=2) - 1) / 2, -1, 1))
        )
        assert err.max() < 0.02, (b, err.max())  # the band's turn is up to 0.6°
    assert np.allclose(rows[:, 2], R, atol=1e-6)  # the middle band is the frame's own
    flipped = row_rotations(t, R, -ro, rows=270, bands=5)  # bottom row first
    assert np.allclose(flipped[:, ::-1], rows, atol=1e-9)


def test_per_row_warp_removes_the_rolling_shutter_wobble(tmp_path):
    """A shaken camera with a 30 ms readout: stabilised with the true motion, the global warp
    (one rotation per frame) leaves the rows' skew and stretch in the output, the per-row warp
    takes most of it away. Measured on the decoded outputs."""
    from egovid.fpv.stabilize.run import stabilize_video
    from egovid.synth.rolling import render_rolling_fpv

    n, ro = 60, 0.03
    a = _shake(n)
    intr = Intrinsics.default(480, 270)
    clip = render_rolling_fpv(tmp_path / "rs.mp4", a, ro, width=480, height=270, intrinsics=intr)
    truth = Trajectory.from_euler(np.arange(n) / FPS, a)
    shear = {}
    for r in (ro, 0.0):  # through `fpv stabilize`'s function, as --readout gives it
        out = tmp_path / f"out-{r}.mp4"
        res = stabilize_video(clip.video, out, motion=truth, focal=intr.focal, measure=False, readout_ms=1000 * r)
        assert res.params["readout_ms"] == pytest.approx(1000 * r) and np.max(1 / res.keep) <= 1.10 + 1e-9
        shear[r] = _band_shear(out)
    shear_in = _band_shear(clip.video)
    assert shear[0.0] > 0.8 * shear_in > 0.5  # the global warp leaves the wobble (1.8 px measured)
    assert shear[ro] < 0.4 * shear[0.0], shear  # the per-row warp: 0.37 px measured


def test_lens_zoom_is_held_at_the_budget_and_the_frames_are_named():
    """A fisheye view turned 6° away needs more zoom than a 1.02 budget: the zoom stays at 1.02,
    the warning names the frames and the border they show, measured by the lens's own check."""
    intr = Intrinsics.from_focal(848, 480, 390.0)
    warp = MeshWarp(intr, lens=EQUIDISTANT)
    turned = matrix_from_euler(np.array([6.0, 0.5]), np.array([0.0, 0.3]), np.zeros(2))
    views = [FrameView(turned[0], np.eye(3)[None]), FrameView(turned[1], np.eye(3)[None])]
    zoom, warnings = view_zooms(warp, views, np.array([1.0, 1.01]), 1.02, "fisheye lens")
    assert zoom.tolist() == pytest.approx([1.02, 1.01])  # the second frame kept its planned zoom
    assert len(warnings) == 1 and "on 1 frames" in warnings[0] and "--max-zoom 1.02" in warnings[0]
    border = warp.coverage_shortfall(FrameView(turned[0], np.eye(3)[None], 1.02))
    assert border > 1.0 and f"{border:.1f} px" in warnings[0]
    assert warp.coverage_shortfall(FrameView(turned[1], np.eye(3)[None], 1.02)) <= 0  # covered within budget
    zoom, warnings = view_zooms(warp, views, np.array([1.0, 1.01]), 1.3)
    assert warnings == [] and 1.02 < zoom[0] < 1.3 and zoom[1] == pytest.approx(1.01)


def test_stabilize_through_a_fisheye_keeps_its_zoom_budget(tmp_path):
    """The whole stabiliser on a fisheye: the path programme's pinhole corners ask for a little
    more than the budget on a few frames (1.102x here); the fisheye's own projection covers every
    frame within it, so no frame zooms beyond the budget (the lens's zoom used to be taken as the
    larger of the two, uncapped) and every output frame is covered by the lens's own check."""
    from egovid.synth.rolling import render_rolling_fpv

    n = 45
    a = _shake(n) * 2.0
    intr = Intrinsics.default(320, 180)
    clip = render_rolling_fpv(tmp_path / "gs.mp4", a, 0.0, width=320, height=180, intrinsics=intr)
    truth = Trajectory.from_euler(np.arange(n) / FPS, a)
    res = stabilize(clip.video, tmp_path / "o.mp4", intrinsics=intr, motion=truth, measure=False, lens=EQUIDISTANT)
    assert np.max(1 / res.fitted.keep) > 1.10  # the programme's own zoom went beyond the budget
    assert np.max(1 / res.keep) <= 1.10 + 1e-9
    warp = MeshWarp(intr, lens=EQUIDISTANT)
    R_old = matrix_from_euler(a[:, 0], a[:, 1], a[:, 2])
    R_new = matrix_from_euler(res.path[:, 0], res.path[:, 1], res.path[:, 2])
    shortfall = [warp.coverage_shortfall(FrameView(R_new[k], R_old[k][None], 1 / res.keep[k])) for k in range(n)]
    assert max(shortfall) <= 0.0
    assert res.summary()["warnings"] == []


def test_readout_flag_is_checked_before_any_work(tmp_path):
    from conftest import assert_one_error, run_cli

    r = run_cli("fpv", "stabilize", tmp_path / "none.mp4", "-o", tmp_path / "o.mp4", "--readout", "500")
    assert_one_error(r, "--readout")
