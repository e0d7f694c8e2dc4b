"""CAMM (Camera Motion Metadata) read natively: every record of every sample, timed by the track's
sample table and edit list, and used as the camera's gyro, accelerometer and readout time.

Truths are independent of the reader: a hand-built file whose records, sample times and edit
list are written here byte by byte (checked also against telemetry-parser, which reads half of
them); a rendered clip whose CAMM gyro is made from the rendered orientations (with a known bias,
noise and clock offset) and whose accelerometer reads a gravity chosen here.
"""

from __future__ import annotations

import fractions
import struct

import numpy as np
import pytest

from egovid.core.camera import camm
from egovid.core.camera.gpmf import gpmd_payloads
from egovid.core.camera.resolve import resolve_camera
from egovid.core.camera.telemetry import read_camera_telemetry
from egovid.core.motion import source as source_mod
from egovid.core.trajectory import read_motion_csv
from egovid.core.video.isobmff import read_tracks, sample_bytes
from egovid.fpv.stabilize.run import gravity_down
from egovid.synth import motions
from egovid.synth.camm import add_camm_track, camm_record, imu_for_motion, write_camm_imu
from egovid.synth.fpv import render_fpv

from conftest import real_clip

FPS = 30.0


def _tiny_video(path, frames: int = 30) -> None:
    import av

    with av.open(str(path), "w", format="mp4") as c:
        v = c.add_stream("libx264", rate=fractions.Fraction(30, 1))
        v.width, v.height, v.pix_fmt = 64, 48, "yuv420p"
        v.options = {"preset": "ultrafast"}
        for i in range(frames):
            f = av.VideoFrame.from_ndarray(np.full((48, 64, 3), 8 * i, np.uint8), "rgb24")
            f.pts = i
            for pkt in v.encode(f):
                c.mux(pkt)
        for pkt in v.encode():
            c.mux(pkt)


def _f32(x) -> np.ndarray:
    return np.asarray(x, np.float32).astype(float)


@pytest.fixture(scope="module", params=["camm", "meta"])
def hand_built(request, tmp_path_factory):
    """10 samples of 0.1 s (time scale 1000, 3 samples per chunk, the last chunk short), shown
    from 0.25 s by an edit list; each holds two gyro records, one accelerometer record and one
    exposure record; sample 4 also a type-5 and a type-6 GPS fix, sample 9 ends in 6 stray bytes."""
    path = tmp_path_factory.mktemp("camm") / f"hand-{request.param}.mp4"
    _tiny_video(path)
    gyro = [(0.1 * i + 0.01 * k, -0.2 * i, 0.3 + k) for i in range(10) for k in range(2)]
    accel = [(0.5, -9.8 + 0.01 * i, 0.25) for i in range(10)]
    samples = []
    for i in range(10):
        s = camm_record(camm.GYRO, *gyro[2 * i]) + camm_record(camm.ACCEL, *accel[i])
        s += camm_record(camm.EXPOSURE, 4_000_000 + i, 21_500_000) + camm_record(camm.GYRO, *gyro[2 * i + 1])
        if i == 4:
            s += camm_record(camm.GPS_MIN, 46.5, 6.5, 420.25)
            s += camm_record(camm.GPS, 1.4e9, 3, 46.5, 6.5, 420.0, 2.5, 4.0, 1.0, -2.0, 0.5, 0.3)
        if i == 9:
            s += b"\0\0\x09\0ab"  # an unknown type: ends the sample
        samples.append(s)
    add_camm_track(path, samples, [100] * 10, timescale=1000, samples_per_chunk=3, handler=request.param, start_s=0.25)
    return path, request.param, np.array(gyro), np.array(accel)


def test_every_record_is_read_with_its_time(hand_built):
    path, handler, gyro, accel = hand_built
    c = camm.read_camm(path)
    assert c is not None and c.handler == handler and c.samples == 10
    assert c.records == 10 * 4 + 2
    g = c.stream(camm.GYRO)
    assert len(g) == 20  # both gyro records of every sample
    assert np.array_equal(g.values, _f32(gyro))
    # Sample i is shown at 0.25 + 0.1 i; its two gyro records share the sample's 0.1 s.
    expected = 0.25 + 0.1 * np.repeat(np.arange(10), 2) + 0.05 * np.tile([0, 1], 10)
    assert np.allclose(g.times, expected, atol=1e-9)
    a = c.stream(camm.ACCEL)
    assert np.array_equal(a.values, _f32(accel)) and np.allclose(a.times, 0.25 + 0.1 * np.arange(10))
    e = c.stream(camm.EXPOSURE)
    assert np.array_equal(e.values[:, 0], 4_000_000 + np.arange(10)) and c.readout_ms() == 21.5
    assert np.array_equal(c.stream(camm.GPS_MIN).values, [[46.5, 6.5, 420.25]])
    gps = c.stream(camm.GPS).values[0]
    assert gps[:4].tolist() == [1.4e9, 3, 46.5, 6.5] and gps[4] == 420.0 and len(gps) == len(camm.GPS_FIELDS)
    assert np.allclose(c.stream(camm.GPS).times, [0.65])
    assert len(c.notes) == 1 and c.notes[0].startswith("sample 9: 6 bytes")
    imu = c.imu()
    assert len(imu) == 20 and len(imu.accel) == 10


def test_telemetry_takes_every_record_where_telemetry_parser_reads_half_or_none(hand_built):
    """telemetry-parser 0.3 reads the first gyro record of each ``meta`` sample (10 of 20), none
    from a ``camm`` handler; the camera's telemetry then carries the native reading."""
    import telemetry_parser

    path, handler, gyro, _ = hand_built
    tp = len(telemetry_parser.Parser(str(path)).normalized_imu() or [])
    assert tp == (10 if handler == "meta" else 0)
    tel = read_camera_telemetry(path)
    assert tel.imu is not None and len(tel.imu) == 20 and tel.imu_source == f"CAMM track ({handler} handler)"
    assert np.array_equal(tel.imu.gyro, _f32(gyro))
    assert tel.readout_ms == 21.5 and "CAMM" in tel.readout_source
    assert tel.has_gyro and source_mod.choose_source("auto", tel)[0] == "gyro"
    assert "CAMM track" in source_mod.choose_source("auto", tel)[1]
    cam = resolve_camera(path, telemetry=tel)  # the rolling-shutter correction's readout
    assert cam.readout_ms == 21.5 and cam.readout_source == "the file (CAMM rolling-shutter skew)"


def test_sample_table_and_edit_list_of_the_video_track(hand_built):
    """The video track's first frame is shown at 0 (FFmpeg's start time): CAMM times are on the
    clock of the frames."""
    import av

    path = hand_built[0]
    tracks, data = read_tracks(path)
    data.close()
    video = next(t for t in tracks if t.handler == "vide")
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        assert video.first_presentation_s() == pytest.approx(float(s.start_time * s.time_base), abs=1e-9)
        assert len(video) == s.frames == 30
    assert camm.read_camm(__file__) is None  # not an MP4


@pytest.mark.parametrize("name", ["gopro-hero5-karma.mp4", "gopro-hero6-2s.mp4"])
def test_sample_tables_of_real_gopro_files_agree_with_ffmpeg(name):
    """The sample-table reader against FFmpeg's demuxer on the real GoPro files (several tracks,
    edit lists, a 90 kHz video clock): every track's sample count, and the GPMF track's samples
    byte for byte at the same times. Neither file has a CAMM track."""
    import av

    path = real_clip(name)
    tracks, data = read_tracks(path)
    try:
        with av.open(str(path)) as c:
            assert [len(t) for t in tracks] == [s.frames for s in c.streams]
        gpmd = next(t for t in tracks if t.sample_entry == "gpmd")
        video = next(t for t in tracks if t.handler == "vide")
        payloads = gpmd_payloads(path)
        assert [sample_bytes(data, gpmd, i) for i in range(len(gpmd))] == [p[2] for p in payloads]
        t, kept = gpmd.presentation_times()
        assert kept.all() and np.allclose(t - video.first_presentation_s(), [p[0] for p in payloads], atol=1e-9)
    finally:
        data.close()
    assert camm.read_camm(path) is None


def test_samples_of_one_size_with_other_records_are_read_one_by_one():
    """Samples decoded together must hold the same records as the first of their size: one that
    packs the same sizes in another order is read on its own, with the same values."""
    g = [camm_record(camm.GYRO, k, 2 * k, 3 * k) for k in range(3)]
    a = [camm_record(camm.ACCEL, -k, 0.5, 9.75) for k in range(3)]
    samples = [g[0] + a[0], a[1] + g[1], g[2] + a[2]]
    buf = np.frombuffer(b"".join(samples), np.uint8)
    streams, total, notes = camm.decode_samples(
        buf, np.array([0, 32, 64]), np.array([32, 32, 32]), np.array([0.0, 0.1, 0.2]), np.full(3, 0.1)
    )
    assert total == 6 and notes == []
    assert np.array_equal(streams[camm.GYRO].values, [[0, 0, 0], [1, 2, 3], [2, 4, 6]])
    assert np.array_equal(streams[camm.ACCEL].values, [[0, 0.5, 9.75], [-1, 0.5, 9.75], [-2, 0.5, 9.75]])
    assert np.allclose(streams[camm.ACCEL].times, [0.0, 0.1, 0.2])


def test_parse_sample_edges():
    recs, left = camm.parse_sample(camm_record(camm.GYRO, 1, 2, 3) + camm_record(camm.ACCEL, 4, 5, 6)[:10])
    assert recs == [(camm.GYRO, (1.0, 2.0, 3.0))] and left == 10  # a cut record is not read
    # Google's mp4v2 example writes the exposure record as two int64.
    assert camm.parse_sample(struct.pack("<HHqq", 0, 1, 5, 7)) == ([(camm.EXPOSURE, (5, 7))], 0)


# ------------------------------------------------------------------------------------------
# A rendered clip with a CAMM IMU.


@pytest.fixture(scope="module")
def camm_clip(tmp_path_factory):
    """320x180, 3 s: a slow look around with a head bob and jitter; a 200 Hz CAMM gyro and
    accelerometer (camm handler) 40 ms ahead of the video, biased and noisy; gravity along the
    render world's (0.2, 1, 0.1)."""
    out = tmp_path_factory.mktemp("camm-clip") / "clip.mp4"
    n = 90
    angles = motions.running(n, 8.0, 0.5, 60.0) + motions.jitter(n, (0.05, 0.05, 0.03), seed=4)
    angles[:, 1] += 0.6 * np.sin(2 * np.pi * 2.0 * np.arange(n) / FPS)
    render_fpv(out, angles, width=320, height=180, fps=FPS, noise_std=1.0, seed=2)
    R = read_motion_csv(out.with_name("clip.gt.csv")).R
    truth = imu_for_motion(R, FPS, offset_s=0.04, gravity_world=(0.2, 1.0, 0.1), seed=3)
    write_camm_imu(out, truth)
    return out, truth


def test_auto_source_syncs_the_camm_gyro_to_the_picture(camm_clip):
    clip, truth = camm_clip
    tel = read_camera_telemetry(clip)
    assert len(tel.imu) == len(truth.times) and len(tel.imu.accel) == len(truth.times)
    cm = source_mod.camera_motion(clip, "auto")
    assert cm.source == "gyro" and "CAMM track (camm handler)" in cm.reason, cm.reason
    assert cm.to_dict()["camera"]["gyro_from"] == "CAMM track (camm handler)"
    s = cm.sync
    assert s.offset_s == pytest.approx(truth.offset_s, abs=0.003)
    assert np.array_equal(s.axes, np.eye(3))  # CAMM's camera axes are egovid's
    assert np.degrees(np.abs(s.bias - truth.bias)).max() < 0.1
    c = cm.comparison
    assert c.r >= 0.99 and abs(c.ratio - 1.0) <= 0.05, c.to_dict()
    down = gravity_down(cm)
    err = np.degrees(np.arccos(np.clip(down @ truth.down_world, -1.0, 1.0)))
    assert err < 1.5, err
