"""The stabiliser on phone-style 10-bit HDR HEVC: 10 bits from decoder to encoder, the HDR tags and
metadata kept; 8-bit inputs rendered exactly as before."""

import hashlib

import av
import numpy as np
import pytest

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.rotations import matrix_from_euler
from egovid.core.video import ColourTags, VideoWriter, iter_frames, probe
from egovid.core.video.colour import HdrMetadata
from egovid.fpv.stabilize.measure import pixel_measures
from egovid.fpv.stabilize.pipeline import row_rotations
from egovid.fpv.stabilize.render import homographies, render_stabilized
from egovid.fpv.stabilize.render_views import render_views
from egovid.fpv.stabilize.warp import FrameView, MeshWarp

from conftest import assert_one_error, run_cli

W, H, N = 384, 216, 8
# x265's units: chromaticities in 0.00002, luminance in 0.0001 cd/m² (a P3-D65 1000-nit display).
MASTER = "G(13250,34500)B(7500,3000)R(34000,16000)WP(15635,16450)L(10000000,50)"
DISPLAY = ((13250, 34500, 7500, 3000, 34000, 16000, 15635, 16450), (10000000, 50))


def _gradient() -> np.ndarray:
    """(H*3/2, W) uint16 10-bit I420: luma a smooth ramp over most of the limited range (64-940),
    chroma neutral."""
    x = np.arange(W)[None, :] / (W - 1)
    y = np.arange(H)[:, None] / (H - 1)
    luma = np.round(64 + 876 * (0.8 * x + 0.2 * y)).astype(np.uint16)
    return np.vstack([luma, np.full((H // 2, W), 512, np.uint16)])


def _hevc10(path, picture: np.ndarray, transfer: str, params: str = "", rotation: int = 0) -> None:
    """A lossless 10-bit HEVC clip of N copies of ``picture`` tagged BT.2020 / ``transfer``, made
    with PyAV alone (as a phone's file: yuv420p10le, bt2020nc, limited range)."""
    h, w = picture.shape[0] * 2 // 3, picture.shape[1]
    tags = ColourTags("bt2020", transfer, "bt2020nc", "tv")
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx265", rate=30)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p10le"
        tags.apply(s.codec_context)
        s.options = {"x265-params": "log-level=error:lossless=1" + (":" + params if params else "")}
        if rotation:
            s.set_display_rotation(rotation)
        for k in range(N):
            f = av.VideoFrame.from_ndarray(picture, format="yuv420p10le")
            tags.apply(f)
            f.pts = k
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)


def _still(n: int) -> np.ndarray:
    return np.repeat(np.eye(3)[None], n, 0)


def test_hlg_input_gives_10bit_hevc_that_really_holds_10_bits(tmp_path):
    src, out = tmp_path / "hlg.mp4", tmp_path / "out.mp4"
    truth = _gradient()
    _hevc10(src, truth, "arib-std-b67")
    stats = render_stabilized(src, out, _still(N))
    assert stats.bits == 10
    with av.open(str(out)) as c:
        cc = c.streams.video[0].codec_context
        assert (cc.name, cc.pix_fmt, cc.profile) == ("hevc", "yuv420p10le", "Main 10")
        assert c.streams.video[0].codec_tag == "hvc1"  # what Apple's players want
    assert probe(out).colour == ColourTags("bt2020", "arib-std-b67", "bt2020nc", "tv")
    frames = [f.image for f in iter_frames(out, i420=True, bits=10)]
    assert len(frames) == N and frames[0].dtype == np.uint16
    centre = (slice(H // 4, 3 * H // 4), slice(W // 4, 3 * W // 4))
    for img in frames:
        got, want = img[:H][centre].astype(int), truth[:H][centre].astype(int)
        assert len(np.unique(got)) > 300  # 8 bits hold at most 256 levels
        assert np.mean(got % 4 != 0) > 0.5  # not 8-bit samples shifted up
        err = np.abs(got - want)
        assert err.mean() < 1.0 and np.percentile(err, 99) <= 2, (err.mean(), err.max())
    # The same input forced to 8 bits: H.264, and a quarter of the levels at most.
    out8 = tmp_path / "out8.mp4"
    assert render_stabilized(src, out8, _still(N), bit_depth="8").bits == 8
    assert (probe(out8).codec, probe(out8).pix_fmt) == ("h264", "yuv420p")
    img8 = next(iter_frames(out8, i420=True, bits=10)).image
    assert np.all(img8 % 4 == 0) and len(np.unique(img8[:H][centre])) <= 256
    # The measuring step reads the 10-bit output (as 8-bit grey): a still picture does not shake.
    itf, jitter, shake = pixel_measures(out)
    assert np.isfinite(itf) and shake < 0.05, (itf, jitter, shake)  # (jitter needs a longer clip)


def test_pq_hdr10_metadata_and_rotation_are_kept(tmp_path):
    src, out = tmp_path / "pq.mp4", tmp_path / "out.mp4"
    rng = np.random.default_rng(3)
    picture = _gradient()
    picture[:H] += rng.integers(0, 40, (H, W), dtype=np.uint16)  # texture for the warp to move
    _hevc10(src, picture, "smpte2084", f"master-display={MASTER}:max-cll=1000,400", rotation=90)
    assert probe(src).hdr == HdrMetadata(DISPLAY, (1000, 400))
    # A small turn through the mesh warp (rolling shutter): the other render path.
    intr = Intrinsics.default(H, W)  # portrait in display orientation
    a = np.radians(np.stack([np.linspace(0, 1, N), np.zeros(N), np.zeros(N)], 1))
    R = matrix_from_euler(a[:, 0], a[:, 1], a[:, 2])
    rows = row_rotations(np.arange(N) / 30, R, 0.02, W)
    views = [FrameView(np.eye(3), rows[k], 1.05) for k in range(N)]
    done = render_views(src, out, views, MeshWarp(intr, 90))
    assert done.bits == 10 and any(k.startswith("HDR10 metadata") for k in done.kept)
    info = probe(out)
    assert (info.codec, info.pix_fmt, info.rotation, info.width, info.height) == ("hevc", "yuv420p10le", 90, H, W)
    assert info.colour == ColourTags("bt2020", "smpte2084", "bt2020nc", "tv")
    with av.open(str(out)) as c:
        first = next(c.decode(video=0))
        assert HdrMetadata.of(first) == HdrMetadata(DISPLAY, (1000, 400))  # the SEI, as decoded
    # The warp turned the 10-bit picture: still far more than 256 levels.
    img = next(iter_frames(out, i420=True, bits=10)).image
    assert len(np.unique(img[: img.shape[0] * 2 // 3])) > 600


def _clip8(path, n: int = 20, w: int = 320, h: int = 180) -> None:
    """A lossless (FFV1) 8-bit clip of a seeded texture panning, neutral chroma."""
    rng = np.random.default_rng(7)
    tex = rng.integers(0, 256, (h * 2, w * 2), dtype=np.uint8)
    with VideoWriter(path, w, h, 30, codec="ffv1", pix_fmt="yuv420p", crf=None, preset=None) as wr:
        for k in range(n):
            y = tex[10 + k : 10 + k + h, 20 + 2 * k : 20 + 2 * k + w]
            wr.write_i420(np.vstack([y, np.full((h // 2, w), 128, np.uint8)]))


# SHA-256 of the outputs of the code before 10-bit support (main at 8ab9ce2, PyAV 18.1.1 and its
# libx264): an 8-bit input must still give these bytes. A new PyAV wheel (another x264) changes
# them; then recompute them with that commit's code.
FROZEN_8BIT_PYAV = "18.1.1"
FROZEN_8BIT = {
    "crop": "66ef8b6ad2a30f7fe0830632d718d1dbd6999462a420adfa2eb727e31778ff6f",
    "fill": "d73acc15622d7c5f75b0cdd32a1bcbfbb6b8de856fe68c32d6215b9e2a618ed5",
    "views": "aa87505f6c7852883df483380a02898fc600ad235a631dd27b3906754251dc32",
}


def test_8bit_input_renders_byte_identical_to_before(tmp_path):
    if av.__version__ != FROZEN_8BIT_PYAV:  # another wheel, another x264: other bytes
        pytest.skip(f"digests frozen with PyAV {FROZEN_8BIT_PYAV}, this is {av.__version__}")
    src = tmp_path / "c8.mkv"
    _clip8(src)
    n = 20
    intr = Intrinsics.default(320, 180)
    a = np.radians(np.stack([np.linspace(0, 2, n), np.sin(np.arange(n)) * 0.5, np.zeros(n)], 1))
    R_old = matrix_from_euler(a[:, 0], a[:, 1], a[:, 2])
    R_new = matrix_from_euler(a[:, 0] * 0, a[:, 1] * 0, a[:, 2])
    Hs = homographies(R_old, R_new, intr)
    got = {}
    for b in ("crop", "fill"):
        out = tmp_path / f"{b}.mp4"
        assert render_stabilized(src, out, Hs, keep=np.full(n, 0.95), borders=b, R_new=R_new, intrinsics=intr).bits == 8
        got[b] = hashlib.sha256(out.read_bytes()).hexdigest()
    rows = row_rotations(np.arange(n) / 30, R_old, 0.02, 180)
    out = tmp_path / "views.mp4"
    render_views(src, out, [FrameView(R_new[k], rows[k], 1.05) for k in range(n)], MeshWarp(intr, 0))
    got["views"] = hashlib.sha256(out.read_bytes()).hexdigest()
    assert probe(out).codec == "h264" and probe(out).pix_fmt == "yuv420p"
    assert got == FROZEN_8BIT


def test_cli_refuses_an_unknown_bit_depth(tmp_path):
    src = tmp_path / "c8.mkv"
    _clip8(src, n=4)
    r = run_cli("fpv", "stabilize", src, "-o", tmp_path / "o.mp4", "--bit-depth", "12", timeout=60)
    assert_one_error(r, "--bit-depth")
    assert not (tmp_path / "o.mp4").exists()
