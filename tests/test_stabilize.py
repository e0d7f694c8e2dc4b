"""FPMI-preserving stabilisation (thesis ch. 9): motion structure on hand-made motions, the
optimiser's trade-off, rendering geometry, and whole clips against ffmpeg's vid.stab."""

import shutil

import numpy as np
import pytest

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.metrics.itf import ITFAccumulator
from egovid.core.rotations import matrix_from_euler
from egovid.core.video import count_frames, iter_frames, read_frames
from egovid.fpv.perception.score import score_angles
from egovid.fpv.stabilize.fpm import (
    anchor_geometry,
    ease,
    find_anchors,
    pure_fpm,
    reduce_anchors,
    reduction_rates,
)
from egovid.fpv.stabilize.measure import pure_motion
from egovid.fpv.stabilize.optimize import optimize_axis
from egovid.fpv.stabilize.path import required_keep
from egovid.fpv.stabilize.pipeline import stabilize
from egovid.fpv.stabilize.render import homographies
from egovid.fpv.stabilize.vidstab import run_vidstab
from egovid.synth import motions
from egovid.synth.fpv import render_fpv


def test_anchors_are_the_turning_points_and_ignore_small_jitter():
    n = np.arange(100)
    theta = 10 * np.sin(2 * np.pi * n / 20) + np.random.default_rng(0).normal(0, 0.1, 100)
    a = find_anchors(theta, 0.5)
    assert a[0] == 0 and a[-1] == 99
    np.testing.assert_array_equal(a[1:-1], [5, 15, 25, 35, 45, 55, 65, 75, 85, 95])
    assert len(find_anchors(np.random.default_rng(1).normal(0, 0.1, 100), 0.5)) == 2  # jitter only


def test_pure_fpm_and_easing_by_hand():
    anchors, values = np.array([0, 4, 8]), np.array([0.0, 4.0, 0.0])
    np.testing.assert_allclose(pure_fpm(anchors, values, 9), [0, 1, 2, 3, 4, 3, 2, 1, 0])
    # k = 1, s = 1: two parabolas per segment (constant acceleration), through the anchors.
    e = ease(anchors, values, np.ones(2), np.ones(2), 9)
    np.testing.assert_allclose(e, [0, 0.5, 2, 3.5, 4, 3.5, 2, 0.5, 0])
    # s = 0 is the zigzag itself.
    np.testing.assert_allclose(ease(anchors, values, np.ones(2), np.zeros(2), 9), pure_fpm(anchors, values, 9))
    # The eased motion never overshoots its anchors (no new extremes, eq. 9.2's constraint).
    for k in (1.0, 1.7, 3.0):
        for s in (0.3, 1.0):
            e = ease(anchors, values, np.full(2, k), np.full(2, s), 9)
            assert e.max() <= 4.0 + 1e-12 and e.min() >= -1e-12
            assert np.all(np.diff(e[:5]) >= -1e-12) and np.all(np.diff(e[4:]) <= 1e-12)


def test_reduction_towards_trend_and_eq_9_1_rates():
    anchors, values = np.array([0, 10, 20, 30]), np.array([0.0, 6.0, -6.0, 0.0])
    g = anchor_geometry(anchors, values, trend=np.zeros(4))
    v = reduce_anchors(g, np.array([0.5, 0.5, 0.5, 0.5]))
    np.testing.assert_allclose(v, [0, 3, -3, 0])
    # eq. 9.1: |move| / |value - nearest neighbour's value| (ties: the smaller amplitude).
    np.testing.assert_allclose(reduction_rates(g, v), [0, 3 / 6, 3 / 6, 0])
    # An anchor on the wrong side of its trend is not pushed to a bigger swing.
    g2 = anchor_geometry(anchors, values, trend=np.array([0, 8.0, -6.0, 0]))
    assert reduce_anchors(g2, np.ones(4))[1] == 6.0


def test_optimiser_trades_stability_for_little_fpmi():
    a = motions.running(240, 10, 2.5, 24) + motions.jitter(240, (0.1, 0.1, 0.0), seed=2)
    plan = optimize_axis(a[:, 0], "yaw", 98.3, 66.1)
    e = plan.edited
    from egovid.fpv.stabilize.lut import motion_ve

    assert motion_ve(e, "yaw", _model()) > motion_ve(a[:, 0], "yaw", _model()) + 0.5
    # It keeps part of the look-around (the first-person feeling), it does not flatten it.
    assert 0.5 < np.ptp(e) < np.ptp(a[:, 0])


def test_compiled_objective_is_eq_9_4_from_the_public_pieces():
    """The optimiser's one-call objective against eq. 9.4 assembled from the public functions
    (anchors reduced, easing from the table, eased and pure motion, the scores' own windows)."""
    from egovid.fpv.perception.score import axis_windows
    from egovid.fpv.stabilize.optimize import AxisModel, OptimizeOptions

    a = motions.running(150, 8, 2.5, 20, 1.5) + motions.jitter(150, (0.1, 0.1, 0.1), seed=3)
    rng = np.random.default_rng(1)
    for axis, col in (("yaw", 0), ("pitch", 1), ("roll", 2)):
        for method in ("ve", "sve"):
            am = AxisModel(a[:, col], axis, 98.3, 66.1, _model(), OptimizeOptions(method=method), context=a)

            def score(theta, lo, am=am):
                b = am.context[lo : lo + len(theta)].copy()
                b[:, am.col] = theta
                w = axis_windows(b, am.axis, am.hfov, am.vfov, am.model, am.opts.method)
                return float(np.sqrt(np.mean(w * w)))

            for _ in range(5):
                D = rng.random(len(am.anchors))
                lo, hi = sorted(rng.choice(np.arange(0, 151), 2, replace=False))
                hi = max(hi, lo + 20)
                v = reduce_anchors(am.geom, D)
                k, s = am.shape(v)
                eased = ease(am.anchors, v, k, s, am.n)[lo:hi]
                pure = pure_fpm(am.anchors, v, am.n)[lo:hi]
                want = 1.0 - score(eased, lo) + score(pure, lo)
                movable = am.geom.room > 0
                want += am.opts.tie_break * float(np.mean(1.0 - D[movable]))
                assert am.objective(D, lo, hi) == pytest.approx(want, abs=1e-12)


def _model():
    from egovid.fpv.perception.model import ViewingModel

    return ViewingModel()


def test_homography_maps_a_turned_view_back():
    intr = Intrinsics.default(640, 360)
    R_old = matrix_from_euler(np.array([5.0]), np.array([0.0]), np.array([0.0]))
    R_new = np.eye(3)[None]
    H = homographies(R_old, R_new, intr)[0]
    p = H @ [intr.cx, intr.cy, 1.0]
    # The old centre looked 5° right of the new view direction.
    assert p[0] / p[2] - intr.cx == pytest.approx(intr.fx * np.tan(np.deg2rad(5)), rel=1e-9)
    # A pure 3-degree roll needs a crop; no motion needs none.
    still = np.zeros((1, 3))
    assert required_keep(still, still, intr)[0] == 1.0
    c = required_keep(np.array([[0.0, 0.0, 3.0]]), still, intr)[0]
    # By hand: rotating the frame by 3° about its centre, the corner of the kept w x h box hits
    # the long edge at half-height: c (h/2 cos 3° + w/2 sin 3°) = h/2.
    assert c == pytest.approx(180 / (180 * np.cos(np.radians(3)) + 320 * np.sin(np.radians(3))), abs=2e-3)


@pytest.fixture(scope="module")
def pan_clip(tmp_path_factory):
    """A 40° intentional pan with running bob and shake, 640x360, 120 frames."""
    n = 120
    a = motions.pan(n, 40.0, 0.2, 0.8) + motions.running(n, 2.5, 1.0, 20, 1.0) + motions.jitter(n, seed=5)
    out = tmp_path_factory.mktemp("pan") / "pan.mp4"
    render_fpv(out, a, width=640, height=360, noise_std=1.5, seed=3)
    return out, a


def test_large_intentional_pan_survives(pan_clip, tmp_path):
    clip, _truth = pan_clip
    res = stabilize(clip, tmp_path / "out.mp4", borders="black", measure=False)
    before = res.original[:, 0]
    after = res.path[:, 0]
    # Anchor amplitude of the pan: the view direction after it minus before it.
    span_before = before[-15:].mean() - before[:15].mean()
    span_after = after[-15:].mean() - after[:15].mean()
    assert span_before == pytest.approx(40.0, abs=3.0)
    assert abs(span_after - span_before) <= 0.1 * abs(span_before)
    assert res.planned.ve > res.planned_before.ve


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg (vid.stab) is installed by make")
def test_running_clip_beats_vidstab_on_itf_and_keeps_fpmi(shaky_clip, tmp_path):
    """Measured on the decoded outputs (masked ITF, masks from geometry for both), without zoom."""
    res = stabilize(shaky_clip, tmp_path / "ours.mp4", borders="black")
    assert res.after.ve > res.before.ve + 0.3
    assert abs(res.after.pure_fpm_ve - res.before.pure_fpm_ve) < 0.1  # pure-FPM VE changes little
    assert count_frames(tmp_path / "ours.mp4") == count_frames(shaky_clip)
    vs = run_vidstab(shaky_clip, tmp_path / "vs.mp4", tmp_path)
    acc = ITFAccumulator()
    for f, m in zip(iter_frames(tmp_path / "vs.mp4", gray=True), vs.masks, strict=True):
        acc.add(f.image, m)
    gain_vidstab = acc.value - res.before.itf_db
    gain_ours = res.after.itf_db - res.before.itf_db
    assert gain_ours >= gain_vidstab, (gain_ours, gain_vidstab)


def test_output_keeps_frame_count_timestamps_and_is_atomic(still_clip, tmp_path):
    out = tmp_path / "s.mp4"
    stabilize(still_clip, out, measure=False)
    a, ta = read_frames(still_clip)
    b, tb = read_frames(out)
    assert len(a) == len(b)
    np.testing.assert_allclose(ta, tb, atol=1e-4)
    # A still camera stays still and uncropped: the output is the input (up to re-encoding).
    assert np.abs(a.astype(int) - b.astype(int)).mean() < 2.0
    with pytest.raises(EgovidError):
        stabilize(still_clip, tmp_path / "bad.mp4", strength=2.0, measure=False)
    assert not (tmp_path / "bad.mp4").exists()


def test_pure_motion_of_a_zigzag_is_itself():
    n = np.arange(41)
    z = np.abs((n % 20) - 10.0) - 5.0
    a = np.stack([z, np.zeros(41), np.zeros(41)], 1)
    np.testing.assert_allclose(pure_motion(a)[:, 0], z, atol=1e-12)
    assert score_angles(pure_motion(a), 30, 98.3, 66.1).score == pytest.approx(score_angles(a, 30, 98.3, 66.1).score)


def test_an_interrupt_inside_submit_waits_for_the_job_it_left_running(still_clip, tmp_path, monkeypatch):
    """A signal handled inside the render's ``submit`` (after the job is queued, before it is
    assigned) must not close the writer under that job: the clean-up waits for every job
    submitted, then aborts the output (closing the encoder under a running write crashed the
    process on an interrupt, seen once in a clean-clone test run)."""
    import time
    from concurrent.futures import ThreadPoolExecutor

    from egovid.fpv.stabilize import render as render_mod

    events: list[str] = []
    real_write, real_abort = render_mod.VideoWriter.write_i420, render_mod.VideoWriter.abort

    def slow_write(self, frame, t=None):
        time.sleep(0.2)
        real_write(self, frame, t)
        events.append("written")

    def abort(self):
        events.append("abort")
        real_abort(self)

    class InterruptedPool(ThreadPoolExecutor):
        writes = 0

        def submit(self, fn, *args, **kwargs):
            job = super().submit(fn, *args, **kwargs)
            if getattr(fn, "__name__", "") == "slow_write":
                InterruptedPool.writes += 1
                if InterruptedPool.writes == 3:
                    raise KeyboardInterrupt  # as the signal handler would, inside submit
            return job

    monkeypatch.setattr(render_mod.VideoWriter, "write_i420", slow_write)
    monkeypatch.setattr(render_mod.VideoWriter, "abort", abort)
    monkeypatch.setattr(render_mod, "ThreadPoolExecutor", InterruptedPool)
    out = tmp_path / "out.mp4"
    with pytest.raises(KeyboardInterrupt):
        render_mod.render_stabilized(still_clip, out, np.tile(np.eye(3), (20, 1, 1)))
    assert events == ["written"] * 3 + ["abort"]
    assert not out.exists()
