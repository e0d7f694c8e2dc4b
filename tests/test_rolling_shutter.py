"""Rolling-shutter correction of matched points, against exact rolling-shutter projections."""

from __future__ import annotations

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.motion.rolling_shutter import corrected_pair, pair_rate, row_offsets, to_frame_time
from egovid.core.rotations import so3_exp, so3_log
from egovid.synth.rolling import row_times


def _rolling_project(dirs: np.ndarray, R0: np.ndarray, omega: np.ndarray, K: np.ndarray, h: int, readout: float):
    """Project world directions through a camera R(t) = R0 exp(omega t) whose row y is read at
    row_offsets(y): solve y = row(t(y)) by fixed-point iteration (exact to 1e-9 px)."""
    y = np.full(len(dirs), (h - 1) / 2.0)
    for _ in range(50):
        d = row_offsets(y, h, readout)
        R = R0[None] @ so3_exp(np.outer(d, omega))
        cam = np.einsum("nji,nj->ni", R, dirs) @ K.T
        p = cam[:, :2] / cam[:, 2:3]
        y = p[:, 1]
    return p


def test_points_move_to_the_frame_time_exactly():
    intr = Intrinsics.default(640, 360)
    K, h = intr.K, intr.height
    rng = np.random.default_rng(0)
    px = np.column_stack([rng.uniform(20, 620, 300), rng.uniform(10, 350, 300), np.ones(300)])
    dirs = px @ np.linalg.inv(K).T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    omega = np.radians([40.0, -25.0, 15.0])  # rad/s, a fast shake
    readout, dt = 0.03, 1 / 30
    R_i, R_j = np.eye(3), so3_exp(omega * dt)
    pi = _rolling_project(dirs, R_i, omega, K, h, readout)
    pj = _rolling_project(dirs, R_j, omega, K, h, readout)
    # Global-shutter truth: where the frame-time cameras see the same directions.
    gi = dirs @ R_i @ K.T
    gi = gi[:, :2] / gi[:, 2:3]
    gj = dirs @ R_j @ K.T
    gj = gj[:, :2] / gj[:, 2:3]
    assert np.abs(pi - gi).max() > 5.0  # the shutter moves points by pixels here
    ci = to_frame_time(pi, K, omega, readout, h)
    cj = to_frame_time(pj, K, omega, readout, h)
    np.testing.assert_allclose(ci, gi, atol=1e-6)
    np.testing.assert_allclose(cj, gj, atol=1e-6)
    # With the pair's own rate (its rotation over dt) the same.
    a, b = corrected_pair(pi, pj, K, R_i.T @ R_j, dt, readout, h)
    np.testing.assert_allclose(a, gi, atol=1e-6)
    np.testing.assert_allclose(b, gj, atol=1e-6)
    np.testing.assert_allclose(pair_rate(R_i.T @ R_j, dt), omega, atol=1e-12)
    np.testing.assert_allclose(so3_log(R_i.T @ R_j), omega * dt, atol=1e-12)
    # Nothing to do without a readout or a motion.
    np.testing.assert_array_equal(to_frame_time(pi, K, omega, 0.0, h), pi)


def test_row_rule_is_the_renderers():
    """The synthetic clips' band times follow the same row rule (middle row at the time stamp)."""
    h, ro = 360, 0.02
    bands = row_times(h, ro, 6)
    centres = np.linspace(0, h, 7)
    centres = 0.5 * (centres[:-1] + centres[1:]) - 0.5
    np.testing.assert_allclose(bands, row_offsets(centres, h, ro))
    assert row_offsets(np.array([0.0, (h - 1) / 2, h - 1]), h, ro).tolist() == [-ro / 2, 0.0, ro / 2]


def test_synthetic_rolling_shutter_clip_is_corrected(tmp_path):
    """A 30 ms readout at 30 fps: vision reads the shake's row skew as roll; re-fitting the kept
    matches at the frame times with vision's own rates takes most of that error away."""
    from egovid.core.motion import gyro
    from egovid.core.motion.estimate import MotionOptions, collect_pairs, solve_motion
    from egovid.core.motion.rolling_shutter import frame_rates, refit_pairs
    from egovid.synth.motions import jitter, running
    from egovid.synth.rolling import render_rolling_fpv

    n = 40
    angles = running(n, yaw_amp=6, pitch_amp=2, period=10) + jitter(n, (0.6, 0.6, 0.3), seed=3)
    intr = Intrinsics.default(480, 270)
    clip = render_rolling_fpv(tmp_path / "rs.mp4", angles, 0.03, width=480, height=270, intrinsics=intr)
    pairs = collect_pairs(clip.video, intr, MotionOptions(keep_matches=10**6, threshold_px=3.0))
    plain = solve_motion(pairs, intr)
    before = gyro.compare_rotations(plain.trajectory.R, clip.truth.R)
    est = plain
    for _ in range(2):
        est = solve_motion(refit_pairs(pairs, frame_rates(est.trajectory.R, pairs.times), 0.03), intr)
    after = gyro.compare_rotations(est.trajectory.R, clip.truth.R)
    assert before.rms_deg > 0.5  # the shutter's error is there...
    assert after.rms_deg < 0.6 * before.rms_deg and after.r > before.r  # ...and mostly gone
