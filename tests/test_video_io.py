"""Streaming video I/O on PyAV: exact frame counts and timestamps, rotation flag, audio copy,
atomic writes and clear errors on bad files."""

from fractions import Fraction

import av
import numpy as np
import pytest

from egovid.errors import EgovidError
from egovid.io.video import VideoWriter, count_frames, iter_frames, probe, read_frames


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
