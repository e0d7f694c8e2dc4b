"""The smooth-pursuit model and VE/SVE (thesis ch. 7–8) against independent truth: hand-computed
thresholds, brute-force grids for B(k), brute-force path enumeration for VE, and the invariances
of §10.1.2."""

import itertools
import math

import numpy as np
import pytest

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.trajectory import Trajectory, read_motion_csv, write_motion_csv
from egovid.fpv.perception.intervals import position_error_deg, roll_intervals, yaw_pitch_intervals
from egovid.fpv.perception.model import ViewingModel
from egovid.fpv.perception.score import score_angles, world_intervals
from egovid.fpv.perception.ve import sve_windows, ve_bruteforce, ve_windows
from egovid.fpv.score import score_video
from egovid.synth import motions

HFOV, VFOV = 98.3, 66.1


def test_thresholds_by_hand():
    m = ViewingModel()  # b = 0.0183, MAR = 0.02, 30 fps
    _mar, x_lo, x_hi = m.pe_bounds(30.0)
    # (|PE| + b) / (30 |PE|) <= 0.18  <=>  |PE| >= b / 4.4;  >= 0.04  <=>  |PE| <= b / 0.2
    assert x_lo == pytest.approx(0.0183 / 4.4)
    assert x_hi == pytest.approx(0.0183 / 0.2)
    assert m.pe_threshold(30.0) == pytest.approx(0.0915)
    # At 60 fps: 0.18*60-1 = 9.8, 0.04*60-1 = 1.4.
    assert m.pe_threshold(60.0) == pytest.approx(max(0.02, 0.0183 / 1.4))
    with pytest.raises(EgovidError, match="bias"):
        ViewingModel(bias_deg=0.2).validate()


def test_position_error_hand_case():
    # Target on the optical axis, camera turns 0, 1, 3 degrees (acceleration 1°/frame²), d/f = 4:
    # PE = atan(tan(-3°)/4) - 2 atan(tan(-1°)/4) + 0.
    pe = position_error_deg("yaw", 0.0, 1.0, 3.0, 4.0)
    expected = math.degrees(math.atan(math.tan(math.radians(-3)) / 4) - 2 * math.atan(math.tan(math.radians(-1)) / 4))
    assert float(pe) == pytest.approx(expected, abs=1e-12)
    assert float(pe) == pytest.approx(-0.25, abs=2e-3)


def _grid_interval(kind, d1, d2, fov, ratio, thr, n=200001):
    beta = np.linspace(-fov / 2, fov / 2, n)
    ok = np.abs(position_error_deg(kind, beta, d1, d2, ratio)) <= thr
    if not ok.any():
        return None
    idx = np.flatnonzero(ok)
    assert np.all(np.diff(idx) == 1), "trackable set should be one interval"
    return beta[idx[0]], beta[idx[-1]]


@pytest.mark.parametrize("kind", ["yaw", "roll"])
def test_intervals_match_brute_force_grid(kind):
    rng = np.random.default_rng(0)
    fov, ratio, thr = HFOV, 4.0, 0.0915
    step = fov / 200000
    for _ in range(60):
        scale = 10 ** rng.uniform(-2, 1)
        theta = np.concatenate([[0.0], np.cumsum(rng.normal(0, scale, 2))])
        fn = yaw_pitch_intervals if kind == "yaw" else roll_intervals
        lo, hi = fn(theta, fov, ratio, thr)[0]
        ref = _grid_interval(kind, theta[1], theta[2], fov, ratio, thr)
        if ref is None:
            assert hi - lo < 2 * step
        else:
            assert lo == pytest.approx(ref[0], abs=2 * step)
            assert hi == pytest.approx(ref[1], abs=2 * step)


def test_still_camera_scores_one_everywhere():
    a = np.zeros((60, 3))
    for method in ("ve", "sve"):
        s = score_angles(a, 30, HFOV, VFOV, method=method)
        assert s.score == pytest.approx(1.0, abs=1e-12)
        assert np.allclose(s.combined, 1.0)
    iv = world_intervals(a, 30, HFOV, VFOV)
    np.testing.assert_allclose(iv.yaw, np.tile([-HFOV / 2, HFOV / 2], (58, 1)))


def test_ve_equals_brute_force_on_random_windows():
    rng = np.random.default_rng(1)
    for _trial in range(40):
        n1 = int(rng.integers(3, 11))
        sacc = int(rng.integers(1, 7))
        centre = np.cumsum(rng.normal(0, 8, n1))
        width = rng.uniform(0, 60, n1) * (rng.random(n1) > 0.15)
        lo, hi = centre - width / 2, centre + width / 2
        dp = ve_windows(lo, hi, 98.3, n1, sacc)
        bf, total = ve_bruteforce(lo, hi, 98.3, sacc)
        assert len(dp) == 1
        assert dp[0] == pytest.approx(bf, abs=1e-12)
        assert total == pytest.approx(1.0, abs=1e-12)


def test_ve_equals_brute_force_on_real_motion_windows():
    a = motions.running(80, 3.0, 1.0, 20, 0.5) + motions.jitter(80, (0.05, 0.05, 0.05), seed=4)
    iv = world_intervals(a, 30, HFOV, VFOV)
    dp = ve_windows(iv.yaw[:, 0], iv.yaw[:, 1], HFOV, 10, 6)
    for i in range(0, len(dp), 7):
        bf, total = ve_bruteforce(iv.yaw[i : i + 10, 0], iv.yaw[i : i + 10, 1], HFOV, 6)
        assert dp[i] == pytest.approx(bf, abs=1e-12)
        assert total == pytest.approx(1.0, abs=1e-12)


def test_ve_of_a_hand_made_window():
    # 3 frames, saccade 1: B̃ = full, half, full (same centre), fov 10.
    lo, hi = np.array([-5.0, -2.5, -5.0]), np.array([5.0, 2.5, 5.0])
    # Trail from 0: survives frames 0..2 with p=0.5 (3 frames); lost at 1 with p=0.5 (1 frame),
    # then a new trail at 2: tracked with p=1 (1 frame). E = 0.5*3 + 0.5*2 = 2.5 -> VE = 2.5/3.
    assert ve_windows(lo, hi, 10.0, 3, 1)[0] == pytest.approx(2.5 / 3)


@pytest.mark.parametrize("method", ["ve", "sve"])
def test_flipping_leaves_scores_unchanged(method):
    n = np.arange(240)
    base = np.zeros((240, 3))
    base[:, 0] = 3.0 * np.sin(2 * np.pi * n / 20)
    base[:, 1] = 1.0 * np.sin(4 * np.pi * n / 20)
    s0 = score_angles(base, 30, HFOV, VFOV, method=method).score
    up_down = score_angles(-base, 30, HFOV, VFOV, method=method).score
    left_right = score_angles(base[::-1].copy(), 30, HFOV, VFOV, method=method).score
    assert up_down == pytest.approx(s0, abs=1e-12)
    # Reversing a sine is the same sine shifted by a frame: only the edge windows differ.
    assert left_right == pytest.approx(s0, rel=5e-3)


def test_scores_fall_as_shake_grows():
    vals = [score_angles(motions.running(150, a, a / 4, 24), 30, HFOV, VFOV).score for a in (0.2, 1, 3, 8)]
    assert all(x > y for x, y in itertools.pairwise(vals))
    assert vals[0] > 0.95


def test_sve_readings():
    # Smooth pan: B̃(n+1) covers the whole view, so eq. 8.11 and the coverage reading agree.
    a = np.zeros((40, 3))
    a[:, 0] = 0.5 * np.arange(40)
    iv = world_intervals(a, 30, HFOV, VFOV)
    assert np.all(iv.yaw[:, 1] - iv.yaw[:, 0] == pytest.approx(HFOV))
    lit = sve_windows(iv.yaw[:, 0], iv.yaw[:, 1], HFOV, 10, "thesis")
    cov = sve_windows(iv.yaw[:, 0], iv.yaw[:, 1], HFOV, 10, "coverage")
    np.testing.assert_allclose(lit, cov, atol=1e-12)
    np.testing.assert_allclose(cov, 1 - 0.5 / HFOV, atol=1e-9)  # loses 0.5° of view per frame
    # Nothing trackable: eq. 8.11 literally claims a perfect score; the coverage reading gives 0.
    lo, hi = np.zeros(12), np.zeros(12)
    assert sve_windows(lo, hi, HFOV, 10, "thesis")[0] == pytest.approx(1.0)
    assert sve_windows(lo, hi, HFOV, 10, "coverage")[0] == pytest.approx(0.0)


def test_low_frame_rate_is_resampled_and_bad_input_refused():
    a = motions.running(100, 2, 0.5, 20)
    s = score_angles(a, 24.0, HFOV, VFOV)
    assert s.resampled_from == 24.0 and s.fps == 30.0
    with pytest.raises(EgovidError, match="NaN"):
        score_angles(np.full((30, 3), np.nan), 30, HFOV, VFOV)
    with pytest.raises(EgovidError, match="fewer than one scoring window"):
        score_angles(np.zeros((8, 3)), 30, HFOV, VFOV)
    with pytest.raises(EgovidError, match="three columns"):
        score_angles(np.zeros((30, 2)), 30, HFOV, VFOV)


def test_score_video_of_a_motion_csv_is_score_angles(tmp_path):
    """`fpv score --motion` (score_video) scores the CSV's angles at the rate of its time column
    with the intrinsics of --size: the same as score_angles on what the CSV holds."""
    a = motions.running(90, 6.0, 1.5, 24, 1.0) + motions.jitter(90, seed=2)
    csv = write_motion_csv(tmp_path / "m.csv", Trajectory.from_euler(np.arange(90) / 25.0, a))
    rep = score_video(motion=csv, size=(1280, 720), json_out=tmp_path / "s.json")
    assert list(rep.results) == ["ve", "sve"] and rep.intrinsics_source == "default"
    held = read_motion_csv(csv)
    fps = 1.0 / float(np.median(np.diff(held.times)))
    assert fps == pytest.approx(25.0)
    intr = Intrinsics.default(1280, 720)
    for m in ("ve", "sve"):
        ref = score_angles(held.euler(), fps, intr.hfov_deg, intr.vfov_deg, method=m)
        assert rep.results[m].score == ref.score
        assert np.array_equal(rep.results[m].combined, ref.combined)
    with pytest.raises(EgovidError, match="2D-VE needs the video"):
        score_video(motion=csv, method="ve2d")
