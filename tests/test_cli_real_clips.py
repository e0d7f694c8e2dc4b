"""`egovid fpv motion` and `egovid fpv stabilize` on the two real clips of ../shared/data/real
(SOURCES.md), every motion source that applies; `voeval run` with the GoPro clip's gyro as the
reference.

Must-show (issue 13): on the GoPro clip, vision's per-frame rotation against the camera's own gyro
has r >= 0.98 and a magnitude ratio within 0.95-1.05, with no intrinsics flag.

The stabiliser runs, keeps what the camera wrote, stays under the zoom cap, and its measured
(decoded) output shakes less than its input; `fpv score` reads the result.

Every source (vision, auto, fused, the stabiliser's own, voeval's gyro sync) starts by measuring the same frame pairs
of the clip: the commands run in this process (:func:`conftest.invoke_cli`), where
``shared_vision_pairs`` measures them once per clip for the module instead of once per command
(about 45 s each on the GoPro clip, 2 cores).
"""

from __future__ import annotations

import csv
import json

import av
import numpy as np
import pytest

from egovid.core.camera.telemetry import read_camera_telemetry
from egovid.core.rotations import so3_log
from egovid.core.trajectory import read_tum
from egovid.core.video import count_frames, iter_frames, probe

from conftest import assert_one_error, invoke_cli, run_cli


def _run(clip, tmp_path, source: str, *extra: str, capsys=None) -> tuple[dict, list[dict]]:
    out = tmp_path / f"{source}.csv"
    r = invoke_cli(["fpv", "motion", clip, "-o", out, "--source", source, *extra], capsys)
    assert r.returncode == 0, r.stdout + r.stderr
    doc = json.loads(out.with_suffix(".json").read_text())
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return doc, rows


@pytest.fixture(scope="module")
def karma_vision(karma_clip, tmp_path_factory, shared_vision_pairs):
    return _run(karma_clip, tmp_path_factory.mktemp("kv"), "vision")


def test_gopro_vision_against_its_own_gyro(karma_vision):
    doc, rows = karma_vision
    assert doc["source"] == "vision" and len(rows) == doc["frames"] == 362
    # No flag: the camera's calibrated lens profile (HERO5 Black, Medium, with its distortion),
    # picked from the file's own facts; the gyro only checks it.
    assert doc["intrinsics"]["source"] == "lens-profile"
    assert "Medium" in doc["intrinsics"]["detail"] and doc["intrinsics"]["distortion_fisheye_k"]
    sync = doc["gyro_sync"]
    assert sync["axes_snapped"] and sync["r_vector"] > 0.95
    assert -60 < sync["offset_ms"] < -15  # rolling shutter and exposure: about -36 ms
    cmp = doc["vision_vs_gyro"]
    assert cmp["r"] >= 0.98, cmp
    assert 0.95 <= cmp["ratio"] <= 1.05, cmp
    # The 5-frame periodic error of the old pose graph is gone: no peak at lag 5.
    acf = cmp["error_autocorrelation_lag1_10"]
    assert acf[4] < 0.5 * (acf[3] + acf[5]) + 0.1, acf
    assert {"frame", "time", "yaw", "pitch", "roll", "confidence"} <= set(rows[0])


def test_gopro_auto_uses_the_gyro_and_fused_runs(karma_clip, karma_vision, tmp_path, capsys):
    _, vision_rows = karma_vision
    doc, rows = _run(karma_clip, tmp_path, "auto", "--plot", str(tmp_path / "auto.png"), capsys=capsys)
    assert doc["source"] == "gyro" and "gyro" in doc["reason"]
    # On the gimbal the body barely shakes: whether the camera stabilised the picture cannot be
    # told from it (the file says it did not), and the gyro is kept.
    pic = doc["picture_vs_body_gyro"]
    assert pic["verdict"] == "cannot tell" and pic["gyro_rms_deg_s"] < 2.0 and pic["measured"] >= 0.9, pic
    assert doc["camera"]["model"] == "HERO5 Black" and doc["camera"]["lens_mode"] == "Medium"
    assert (tmp_path / "auto.png").stat().st_size > 10_000
    fused, fused_rows = _run(karma_clip, tmp_path, "fused", capsys=capsys)
    assert fused["source"] == "fused"

    # Frame to frame, vision and fused turn like the gyro (yaw rate per frame from the CSVs).
    def yaw_steps(r):
        return np.diff([float(x["yaw"]) for x in r])

    gyro_yaw = yaw_steps(rows)
    assert abs(np.sum(gyro_yaw)) > 10  # the final pan
    for other in (vision_rows, fused_rows):
        steps = yaw_steps(other)
        assert np.corrcoef(steps, gyro_yaw)[0, 1] > 0.99
        assert np.dot(steps, gyro_yaw) / np.dot(gyro_yaw, gyro_yaw) == pytest.approx(1.0, abs=0.05)
    # The gyro covers every frame but the first (the sync puts frame 0 36 ms before its first sample).
    conf = np.array([float(r["confidence"]) for r in rows])
    assert np.all(conf[2:] == 1.0)


def test_handheld_without_telemetry(handheld_clip, tmp_path, capsys, shared_vision_pairs):
    doc, rows = _run(handheld_clip, tmp_path, "auto", capsys=capsys)
    assert doc["source"] == "vision" and doc["reason"] == "the file records no gyro"
    assert doc["intrinsics"]["source"] == "default" and len(rows) == 171
    yaw = np.array([float(r["yaw"]) for r in rows])
    assert abs(yaw[-1] - yaw[0]) > 5  # a pan
    for source in ("gyro", "fused"):
        r = invoke_cli(["fpv", "motion", handheld_clip, "-o", tmp_path / "x.csv", "--source", source], capsys)
        assert_one_error(r, "needs a gyro")


def _data_packets(path, handler: str) -> list[bytes]:
    with av.open(str(path)) as c:
        (s,) = [s for s in c.streams.data if s.metadata.get("handler_name", "").strip() == handler]
        return [bytes(p) for p in c.demux(s) if p.size]


def test_gopro_clip_stabilised_measured_and_kept(karma_clip, tmp_path, capsys, shared_vision_pairs):
    out = tmp_path / "karma.mp4"
    args = ["fpv", "stabilize", karma_clip, "-o", out, "--json", tmp_path / "k.json", "--report", tmp_path / "k.html"]
    r = invoke_cli(args, capsys)
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "k.json").read_text())
    # What the camera wrote: full-range BT.709, timecode, creation time, audio, GPMF telemetry.
    src, got = probe(karma_clip), probe(out)
    assert got.colour == src.colour and got.colour.range == "pc"
    assert (got.timecode, got.creation_time, got.audio_streams) == (src.timecode, src.creation_time, 1)
    assert _data_packets(out, "GoPro MET") == _data_packets(karma_clip, "GoPro MET")
    assert count_frames(out) == count_frames(karma_clip)
    # Under the default zoom cap, and measured on the decoded output: less high-frequency jitter.
    assert s["zoom"]["max"] <= 1.10 + 1e-9
    mb, ma = s["measured"]["before"], s["measured"]["after"]
    assert ma["jitter_px"] < mb["jitter_px"], (mb, ma)
    assert ma["itf_db"] > mb["itf_db"]
    assert "input | output" in (tmp_path / "k.html").read_text()


def test_handheld_clip_stabilised_and_scored(handheld_clip, tmp_path, capsys, shared_vision_pairs):
    out = tmp_path / "hand.mp4"
    args = ["fpv", "stabilize", handheld_clip, "-o", out, "--json", tmp_path / "h.json", "--no-measure"]
    r = invoke_cli(args, capsys)
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "h.json").read_text())
    assert "measured" not in s and s["zoom"]["max"] <= 1.10 + 1e-9
    assert s["planned"]["after"]["ve"] >= s["planned"]["before"]["ve"]
    assert probe(out).audio_streams == 1 and count_frames(out) == count_frames(handheld_clip)
    r = run_cli("fpv", "score", out, "--method", "ve2d", "--json", tmp_path / "score.json")
    assert r.returncode == 0, r.stderr
    assert 0.0 < json.loads((tmp_path / "score.json").read_text())["results"]["ve2d"]["score"] <= 1.0


#: Frames of the GoPro clip that the voeval run stores and runs the odometer on.
VOEVAL_FRAMES = 40


def test_voeval_gyro_sequence_reference_is_the_synced_gyro_and_vision_agrees(
    karma_clip, tmp_path, capsys, shared_vision_pairs
):
    """``voeval run --sequence gyro:VIDEO``: the camera's own gyro, synced to the picture, is the
    reference. Checked against the raw gyro samples (the reference is the gyro, at the offset and
    axes the sync found, with the bias of its still parts, not vision's) and against an independent
    sensor (egovid's vision odometer agrees with it frame to frame once the gyro's bias is removed).
    With one worker the run is in this process, and its sync measures the clip's pairs as auto does."""
    clip = karma_clip
    out = tmp_path / "run"
    args = ["voeval", "run", "--out", out, "--no-synthetic", "--sequence", f"gyro:{clip}", "--frames", VOEVAL_FRAMES]
    args += ["--vo", "egovid", "--levels", "lossless", "--real-factors", "", "--workers", "1", "--no-report"]
    r = invoke_cli(args, capsys)
    assert r.returncode == 0, r.stderr
    name = "gopro-hero5-karma"
    meta = json.loads((out / "scenes" / "real" / f"{name}.json").read_text())
    assert meta["format"] == "gyro" and meta["reference"] == "gyro" and meta["frames"] == VOEVAL_FRAMES
    sync = meta["gyro_sync"]
    assert sync["r_vector"] > 0.9 and sync["axes_snapped"]
    # The lens table says 518 px (94.4° Medium lens); the gyro fit may move it, but not far.
    assert 0.85 < meta["fx"] / 518.33 < 1.15

    # The stored video is the clip's first frames (lossless), at the clip's own times.
    ref = read_tum(out / "scenes" / "real" / f"{name}.gt.tum")
    src = [f for f, _ in zip(iter_frames(clip), range(VOEVAL_FRAMES), strict=False)]
    stored = list(iter_frames(out / "scenes" / "real" / f"{name}.mkv"))
    assert len(stored) == VOEVAL_FRAMES
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
