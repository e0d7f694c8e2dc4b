"""``voeval run --sequence gyro:VIDEO`` on the real GoPro HERO5 clip (../shared/data/real/SOURCES.md):
the camera's own gyro, synced to the picture, is the reference. Checked against the raw gyro
samples (the reference is the gyro, at the offset and axes the sync found, not vision's estimate)
and against an independent sensor (egovid's vision odometer agrees with it frame to frame)."""

from __future__ import annotations

import json

import numpy as np

from egovid.geometry import so3_log
from egovid.io.telemetry import read_camera_telemetry
from egovid.io.trajectory import read_tum
from egovid.io.video import iter_frames

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

    # Independent of the sync code: integrate the raw gyro samples (bias removed) over each frame
    # interval shifted by the offset, map to camera axes: that is the reference's step rotation.
    imu = read_camera_telemetry(clip).imu
    w = imu.gyro - np.radians(sync["bias_deg_s"])
    theta = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(imu.times)[:, None], 0)])
    t = np.asarray(ref.times) + src[0].time + sync["offset_ms"] / 1000.0
    at = np.column_stack([np.interp(t, imu.times, theta[:, i]) for i in range(3)])
    expected = np.diff(at, axis=0) @ np.asarray(sync["axes"]).T
    steps = so3_log(np.swapaxes(ref.R[:-1], 1, 2) @ ref.R[1:])
    # The gimbal rolls slowly here (about 0.03° per frame); a wrong axis mapping would be off by
    # about 0.04°, an offset wrong by 30 ms by 0.03°: the match is to a thousandth of a degree.
    assert np.max(np.degrees(np.linalg.norm(steps, axis=1))) > 0.02  # the camera does move
    assert np.max(np.degrees(np.linalg.norm(steps - expected, axis=1))) < 0.001

    # Another sensor: egovid's vision odometer on the stored video agrees with the gyro reference.
    c = json.loads((out / "results" / "egovid" / "s0" / f"{name}__lossless.json").read_text())
    assert c["status"] == "ok" and c["first_pose_frame"] == 0
    assert c["pose_error_per_pair"] < 0.05, c["pose_error_per_pair"]
