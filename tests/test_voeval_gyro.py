"""``voeval run --sequence gyro:VIDEO`` on the real GoPro HERO5 clip (../shared/data/real/SOURCES.md):
the camera's own gyro, synced to the picture, is the reference. Checked against the raw gyro
samples (the reference is the gyro, at the offset and axes the sync found, with the bias of its
still parts, not vision's) and against an independent sensor (egovid's vision odometer agrees with
it frame to frame once the gyro's bias is removed)."""

from __future__ import annotations

import json

import numpy as np

from egovid.core.camera.telemetry import read_camera_telemetry
from egovid.core.rotations import so3_log
from egovid.core.trajectory import read_tum
from egovid.core.video import iter_frames

from conftest import real_clip, run_cli

FRAMES = 40


def test_gyro_sequence_reference_is_the_synced_gyro_and_vision_agrees(tmp_path):
    clip = real_clip("gopro-hero5-karma.mp4")
    out = tmp_path / "run"
    args = ["voeval", "run", "--out", out, "--no-synthetic", "--sequence", f"gyro:{clip}", "--frames", str(FRAMES)]
    r = run_cli(*args, "--vo", "egovid", "--levels", "lossless", "--real-factors", "", "--workers", "1", "--no-report")
    assert r.returncode == 0, r.stderr
    name = "gopro-hero5-karma"
    meta = json.loads((out / "scenes" / "real" / f"{name}.json").read_text())
    assert meta["format"] == "gyro" and meta["reference"] == "gyro" and meta["frames"] == FRAMES
    sync = meta["gyro_sync"]
    assert sync["r_vector"] > 0.9 and sync["axes_snapped"]
    # The lens table says 518 px (94.4° Medium lens); the gyro fit may move it, but not far.
    assert 0.85 < meta["fx"] / 518.33 < 1.15

    # The stored video is the clip's first frames (lossless), at the clip's own times.
    ref = read_tum(out / "scenes" / "real" / f"{name}.gt.tum")
    src = [f for f, _ in zip(iter_frames(clip), range(FRAMES), strict=False)]
    stored = list(iter_frames(out / "scenes" / "real" / f"{name}.mkv"))
    assert len(stored) == FRAMES
    np.testing.assert_allclose(ref.times, [f.time - src[0].time for f in src], atol=1e-4)
    assert np.mean(np.abs(stored[-1].image.astype(float) - src[-1].image.astype(float))) < 1.0

    # Independent of the sync code: integrate the raw gyro samples (minus a bias) over each frame
    # interval shifted by the offset, map to camera axes: that is the reference's step rotation.
    imu = read_camera_telemetry(clip).imu
    t = np.asarray(ref.times) + src[0].time + sync["offset_ms"] / 1000.0

    def gyro_steps(bias_deg_s):
        w = imu.gyro - np.radians(bias_deg_s)
        theta = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(imu.times)[:, None], 0)])
        at = np.column_stack([np.interp(t, imu.times, theta[:, i]) for i in range(3)])
        return np.diff(at, axis=0) @ np.asarray(sync["axes"]).T

    # The bias is not vision's: the drone never rests (its shake is several °/s), so none is removed.
    bias = meta["reference_bias"]
    assert bias["from"].startswith("none") and bias["still_seconds"] < 1.0 and bias["deg_s"] == [0.0, 0.0, 0.0]
    steps = so3_log(np.swapaxes(ref.R[:-1], 1, 2) @ ref.R[1:])
    # The gimbal rolls slowly here (about 0.03° per frame); a wrong axis mapping would be off by
    # about 0.04°, an offset wrong by 30 ms by 0.03°: the match is to a thousandth of a degree.
    assert np.max(np.degrees(np.linalg.norm(steps, axis=1))) > 0.02  # the camera does move
    assert np.max(np.degrees(np.linalg.norm(steps - gyro_steps(bias["deg_s"]), axis=1))) < 0.001

    # Another sensor: egovid's vision odometer on the stored video agrees with the gyro once the
    # gyro's bias (the sync's fit, 0.9°/s on one axis: 0.03° per frame) is removed.
    c = json.loads((out / "results" / "egovid" / "s0" / f"{name}__lossless.json").read_text())
    assert c["status"] == "ok" and c["first_pose_frame"] == 0
    ego = read_tum(out / "results" / "egovid" / "s0" / f"{name}__lossless.tum")
    ego_steps = so3_log(np.swapaxes(ego.R[:-1], 1, 2) @ ego.R[1:])
    err = np.degrees(np.linalg.norm(ego_steps - gyro_steps(sync["bias_deg_s"]), axis=1))
    assert np.mean(err) < 0.05, np.mean(err)


def test_still_bias_comes_from_the_parts_at_rest():
    from egovid.voeval.gyro_reference import still_bias

    rng = np.random.default_rng(4)
    t = np.arange(0, 5.0, 1 / 400)
    b = np.radians([0.3, -0.9, 0.5])
    gyro = b + rng.normal(0, np.radians(0.1), (len(t), 3))
    moving = t >= 2.0  # at rest for 2 s, then shaken like a hand-held camera (±5°/s at 8 Hz)
    gyro[moving] += np.radians(5.0) * np.sin(2 * np.pi * 8 * t[moving])[:, None]
    est, still = still_bias(t, gyro)
    assert 1.9 < still < 2.1
    np.testing.assert_allclose(np.degrees(est), np.degrees(b), atol=0.02)
    est, still = still_bias(t[moving], gyro[moving])  # never at rest: no bias is removed
    assert still < 1.0 and not est.any()
