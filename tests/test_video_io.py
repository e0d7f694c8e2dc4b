"""Streaming video I/O on PyAV: exact frame counts and timestamps, rotation flag, audio copy,
atomic writes and clear errors on bad files."""

from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

from egovid.core.errors import EgovidError
from egovid.core.video import ColourTags, VideoWriter, count_frames, iter_frames, probe, read_frames


def _pattern(i: int, w: int = 64, h: int = 48) -> np.ndarray:
    img = np.full((h, w, 3), 40, np.uint8)
    img[:12, :16] = 250  # bright marker at the top-left
    img[20:28, (i * 3) % (w - 8) : (i * 3) % (w - 8) + 8] = 180
    return img


def _write_with_av(path, n, *, rotation=None, audio=False, times=None):
    c = av.open(str(path), "w")
    s = c.add_stream("libx264", rate=30)
    s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
    s.time_base = Fraction(1, 1000)
    s.codec_context.time_base = Fraction(1, 1000)
    if rotation is not None:
        s.set_display_rotation(rotation)
    a = None
    if audio:
        a = c.add_stream("aac", rate=48000)
        a.layout = "mono"
    for i in range(n):
        f = av.VideoFrame.from_ndarray(_pattern(i), format="bgr24")
        f.pts = round((times[i] if times is not None else i / 30) * 1000)
        f.time_base = s.time_base
        for p in s.encode(f):
            c.mux(p)
    for p in s.encode():
        c.mux(p)
    if a is not None:
        t = np.arange(int(48000 * n / 30)) / 48000
        samples = (0.2 * np.sin(2 * np.pi * 440 * t)).astype(np.float32)
        for k in range(0, len(samples), 1024):
            chunk = samples[k : k + 1024]
            af = av.AudioFrame.from_ndarray(chunk[None, :], format="flt", layout="mono")
            af.sample_rate = 48000
            af.pts = k
            for p in a.encode(af):
                c.mux(p)
        for p in a.encode():
            c.mux(p)
    c.close()


def test_exact_frame_count_and_variable_timestamps(tmp_path):
    times = np.cumsum([0, 0.033, 0.05, 0.02, 0.033, 0.1, 0.033, 0.033])
    _write_with_av(tmp_path / "vfr.mp4", len(times), times=times)
    imgs, t = read_frames(tmp_path / "vfr.mp4")
    assert len(imgs) == len(times) == count_frames(tmp_path / "vfr.mp4")
    np.testing.assert_allclose(t, times - times[0], atol=1.5e-3)
    # ... and the writer keeps them.
    with VideoWriter(tmp_path / "copy.mp4", 64, 48, 30) as w:
        for img, ti in zip(imgs, t, strict=True):
            w.write(img, ti)
    np.testing.assert_allclose(read_frames(tmp_path / "copy.mp4")[1], t, atol=1e-4)


def test_probe_remembers_a_file_only_while_it_is_unchanged(tmp_path):
    clip = tmp_path / "clip.mp4"
    _write_with_av(clip, 8)
    first = probe(clip)
    assert first.frame_count == 8 and probe(str(clip)).path == Path(str(clip))
    # Rewritten in place (same path, new content): probed afresh, not remembered.
    _write_with_av(clip, 12)
    assert probe(clip).frame_count == 12
    # Replaced by another file of any size: probed afresh.
    other = tmp_path / "other.mp4"
    _write_with_av(other, 5, rotation=90)
    other.replace(clip)
    assert (probe(clip).frame_count, probe(clip).rotation) == (5, 90)


@pytest.mark.parametrize("rotation", [90, -90, 180])
def test_rotation_flag_is_applied(tmp_path, rotation):
    _write_with_av(tmp_path / "rot.mp4", 3, rotation=rotation)
    info = probe(tmp_path / "rot.mp4")
    assert info.rotation == rotation % 360
    frame = next(iter_frames(tmp_path / "rot.mp4"))
    expected = np.rot90(_pattern(0), (rotation // 90) % 4)
    assert frame.image.shape == expected.shape
    assert (info.width, info.height) == (expected.shape[1], expected.shape[0])
    bright = frame.image[..., 0] > 200
    assert np.array_equal(bright, expected[..., 0] > 200) or np.mean(bright == (expected[..., 0] > 200)) > 0.97


def test_writer_copies_audio_and_keeps_timing(tmp_path):
    src = tmp_path / "with_audio.mp4"
    _write_with_av(src, 30, audio=True)
    out = tmp_path / "copy.mp4"
    with VideoWriter(out, 64, 48, 30, audio_from=src) as w:
        for f in iter_frames(src):
            w.write(255 - f.image, f.time)
    with av.open(str(out)) as c, av.open(str(src)) as s:
        assert len(c.streams.audio) == 1
        n_out = sum(1 for _ in c.demux(c.streams.audio[0]) if _.size)
        n_src = sum(1 for _ in s.demux(s.streams.audio[0]) if _.size)
        assert n_out == n_src
    assert count_frames(out) == 30


def test_writer_is_atomic_on_error(tmp_path):
    out = tmp_path / "never.mp4"
    with pytest.raises(RuntimeError), VideoWriter(out, 64, 48, 30) as w:
        w.write(_pattern(0))
        raise RuntimeError("interrupted")
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_writer_rejects_wrong_frame_size(tmp_path):
    with pytest.raises(EgovidError, match="does not match"), VideoWriter(tmp_path / "x.mp4", 64, 48, 30) as w:
        w.write(np.zeros((10, 10, 3), np.uint8))
    assert not (tmp_path / "x.mp4").exists()


def test_lossless_ffv1_round_trip_is_bit_exact(tmp_path):
    frames = [_pattern(i) for i in range(5)]
    with VideoWriter(tmp_path / "l.mkv", 64, 48, 30, codec="ffv1") as w:
        for f in frames:
            w.write(f)
    imgs, _ = read_frames(tmp_path / "l.mkv")
    assert np.array_equal(imgs, np.stack(frames))


def test_bad_files_give_one_clear_error(tmp_path):
    with pytest.raises(EgovidError, match="not found"):
        probe(tmp_path / "missing.mp4")
    (tmp_path / "empty.mp4").write_bytes(b"")
    with pytest.raises(EgovidError, match="empty"):
        probe(tmp_path / "empty.mp4")
    (tmp_path / "text.mp4").write_text("this is not a video\n" * 20)
    with pytest.raises(EgovidError, match="not a readable video"):
        probe(tmp_path / "text.mp4")
    _write_with_av(tmp_path / "ok.mp4", 30)
    data = (tmp_path / "ok.mp4").read_bytes()
    (tmp_path / "trunc.mp4").write_bytes(data[: len(data) // 3])
    with pytest.raises(EgovidError):
        list(iter_frames(tmp_path / "trunc.mp4"))
    with pytest.raises(EgovidError, match="folder"):
        probe(tmp_path)


def test_decoding_ahead_decodes_before_it_is_asked_and_stops_on_leaving(tmp_path):
    import threading

    from egovid.core.video.read import decoding_ahead

    _write_with_av(tmp_path / "ok.mp4", 30)
    want = list(iter_frames(tmp_path / "ok.mp4", i420=True))

    def readers() -> list[threading.Thread]:
        return [t for t in threading.enumerate() if t.name == "egovid-read-ahead"]

    with decoding_ahead(tmp_path / "ok.mp4", 8, i420=True) as frames:
        assert len(readers()) == 1  # decoding before the first frame is asked for
        got = list(frames)
    assert not readers()  # the thread ended with the block
    assert [f.index for f in got] == [f.index for f in want]
    assert [f.time for f in got] == [f.time for f in want]
    assert all(np.array_equal(a.image, b.image) for a, b in zip(got, want, strict=True))
    with decoding_ahead(tmp_path / "ok.mp4", 2) as frames:  # left early: the thread still ends
        next(frames)
    assert not readers()
    (tmp_path / "text.mp4").write_text("this is not a video\n" * 20)
    with pytest.raises(EgovidError), decoding_ahead(tmp_path / "text.mp4", 2):
        pass
    assert not readers()


def _packets(path, kind: str, handler: str | None = None) -> list[bytes]:
    with av.open(str(path)) as c:
        streams = [
            s
            for s in c.streams
            if s.type == kind and (handler is None or s.metadata.get("handler_name", "").strip() == handler)
        ]
        assert len(streams) == 1, [s.metadata for s in c.streams]
        return [bytes(p) for p in c.demux(streams[0]) if p.size]


def test_writer_keeps_what_the_gopro_wrote(karma_clip, tmp_path):
    """Colour tags (bt709, full range), creation time, timecode, audio and the GPMF telemetry
    track survive a re-encode; the telemetry bit for bit and readable by telemetry-parser."""
    src = probe(karma_clip)
    assert src.colour == ColourTags("bt709", "bt709", "bt709", "pc")
    assert src.timecode == "19:26:48:04" and src.audio_streams == 1
    assert src.data_streams == ("GoPro TCD", "GoPro MET", "GoPro SOS")
    out = tmp_path / "kept.mp4"
    planes = [f.image for f in iter_frames(karma_clip, i420=True, max_frames=40)]
    with VideoWriter(out, src.width, src.height, src.fps, keep_from=karma_clip) as w:
        for k, img in enumerate(planes):
            w.write_i420(img, k / src.fps)
    assert any("GoPro SOS" in d for d in w.dropped)  # GoPro's recovery track: MP4 cannot carry it
    got = probe(out)
    assert got.colour == src.colour and got.creation_time == src.creation_time
    assert got.timecode == src.timecode and got.audio_streams == 1
    assert _packets(out, "data", "GoPro MET") == _packets(karma_clip, "data", "GoPro MET")
    assert len(_packets(out, "audio")) == len(_packets(karma_clip, "audio"))
    # Full range kept: the luma comes back at the same level (no 16-235 squeeze, no 2-level shift).
    back = [f.image for f in iter_frames(out, i420=True)]
    h = src.height
    shift = np.mean([b[:h].astype(float).mean() - a[:h].mean() for a, b in zip(planes, back, strict=True)])
    assert abs(shift) < 0.3, shift
    import telemetry_parser

    gyro = [s["gyro"] for s in telemetry_parser.Parser(str(out)).normalized_imu()]
    assert gyro == [s["gyro"] for s in telemetry_parser.Parser(str(karma_clip)).normalized_imu()]


def test_writer_sets_the_rotation_flag_and_stores_coded_frames(tmp_path):
    frames = [_pattern(i) for i in range(4)]  # display orientation: 64x48
    out = tmp_path / "rot.mp4"
    with VideoWriter(out, 64, 48, 30, rotation=90, crf=0) as w:
        for f in frames:
            w.write(f)
    info = probe(out)
    assert info.rotation == 90 and (info.width, info.height) == (64, 48)
    with av.open(str(out)) as c:
        coded = next(c.decode(video=0))
        assert (coded.width, coded.height) == (48, 64)  # stored turned back, as a camera does
    assert np.abs(read_frames(out)[0].astype(int) - np.stack(frames)).mean() < 3


@pytest.mark.parametrize(
    ("colour", "grey_y", "white_y"),
    [(ColourTags(), 126, 235), (ColourTags(matrix="bt709", range="pc"), 128, 255), (ColourTags(range="tv"), 126, 235)],
)
def test_writer_converts_bgr_with_the_tagged_matrix_and_range(tmp_path, colour, grey_y, white_y):
    img = np.full((48, 64, 3), 128, np.uint8)
    img[:, 32:] = 255
    out = tmp_path / "c.mkv"
    with VideoWriter(out, 64, 48, 30, codec="ffv1", pix_fmt="yuv420p", colour=colour) as w:
        w.write(img)
    y = next(iter_frames(out, i420=True)).image[:48]
    # By hand: limited range Y = 16 + 219 * v / 255, full range Y = v (grey has no chroma).
    assert np.all(y[:, :30] == grey_y) and np.all(y[:, 34:] == white_y)
    assert probe(out).colour.range == colour.range


@pytest.mark.parametrize("suffix", [".mkv", ".mp4"])
def test_x264_with_frame_delay_keeps_even_frame_times_in_any_container(tmp_path, suffix):
    """libx264 (default tune) holds frames back; Matroska switches the stream's time base to 1/1000
    when it writes its header at the first packet. Frame times must still be i / fps."""
    out = tmp_path / f"d{suffix}"
    opts = {"qp": "0", "preset": "ultrafast"}  # one thread: a delay of a frame or two
    with VideoWriter(out, 64, 48, 20, codec="libx264", crf=None, preset=None, options=opts, threads=1) as w:
        for i in range(12):
            w.write(_pattern(i))
    _, times = read_frames(out)
    assert np.allclose(times - times[0], np.arange(12) / 20, atol=1e-3), times
