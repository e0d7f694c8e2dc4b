"""Decoded frames → a self-contained fragmented MP4 chunk (H.264) that a browser appends through
Media Source Extensions.

Each chunk is its own small file: an initialisation segment (``ftyp`` + ``moov``, with the H.264
parameter sets) followed by one media segment (``moof`` + ``mdat``) that starts with an IDR picture
and holds no B-frames, timed from 0 in units of one frame. The page appends a chunk at any position
of the drive's timeline by setting the SourceBuffer's ``timestampOffset`` to the chunk's start, so
chunks may be fetched in any order and from any producer (a seek is just another chunk).

Why H.264 (x264 ``ultrafast``, ``zerolatency``, constrained baseline): it is the one codec in MP4
that Chrome/Edge, Firefox and Safari all decode through MSE (Debian's Chromium included, checked
by the browser test), and x264 encodes 720p several times faster than real time on one core.
"""

from __future__ import annotations

import io
from collections.abc import Iterable
from dataclasses import dataclass
from fractions import Fraction

import av
import numpy as np

from egovid.core.video import ColourTags


@dataclass(frozen=True)
class EncodeSettings:
    """x264 settings of the stream: ``crf`` (quality, lower = better and larger), ``preset``,
    ``threads`` (0 = x264's choice) and ``max_height`` (pixels; taller drives are scaled down to
    it, keeping the aspect ratio; 0 = never)."""

    crf: int = 26
    preset: str = "ultrafast"
    threads: int = 2
    max_height: int = 0


def frame_rate(fps: float) -> Fraction:
    """The drive's frame rate as a fraction (29.97 → 30000/1001), so that frame times in the MP4
    (one tick per frame of 1/rate seconds) are exact."""
    r = Fraction(fps).limit_denominator(1001)
    return r if r > 0 else Fraction(30)


def output_size(width: int, height: int, max_height: int) -> tuple[int, int]:
    """(width, height) pixels of the stream: the drive's size, or scaled to ``max_height`` (even
    numbers, as 4:2:0 needs)."""
    if not max_height or height <= max_height:
        return width - width % 2, height - height % 2
    w = round(width * max_height / height)
    return w - w % 2, max_height - max_height % 2


def encode_chunk(
    frames: Iterable[np.ndarray],
    width: int,
    height: int,
    fps: float,
    settings: EncodeSettings = EncodeSettings(),
    colour: ColourTags | None = None,
) -> bytes:
    """Encode I420 frames (each ``(height * 3 / 2, width)`` uint8, as the archive decodes them)
    into one fragmented MP4 chunk (see the module docstring); returns its bytes."""
    rate = frame_rate(fps)
    ow, oh = output_size(width, height, settings.max_height)
    buf = io.BytesIO()
    with av.open(buf, "w", format="mp4", options={"movflags": "frag_keyframe+empty_moov+default_base_moof"}) as c:
        s = c.add_stream("libx264", rate=rate)
        s.width, s.height, s.pix_fmt = ow, oh, "yuv420p"
        tb = Fraction(rate.denominator, rate.numerator)
        s.time_base = tb
        s.codec_context.time_base = tb
        if colour is not None:
            colour.apply(s.codec_context)
        # One IDR at the start, none after (the chunk is one GOP); no B-frames, no lookahead.
        s.options = {"preset": settings.preset, "tune": "zerolatency", "crf": str(settings.crf),
                     "x264-params": "keyint=100000:min-keyint=100000:scenecut=0:bframes=0"}  # fmt: skip
        if settings.threads:
            s.codec_context.thread_count = settings.threads
        for n, img in enumerate(frames):
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="yuv420p")
            if (ow, oh) != (width, height):
                vf = vf.reformat(ow, oh)
            vf.pts = n
            for p in s.encode(vf):
                p.duration = 1
                c.mux(p)
        for p in s.encode():
            p.duration = 1
            c.mux(p)
    return buf.getvalue()


def mime_codec(chunk: bytes) -> str:
    """The MSE type of a chunk, e.g. ``video/mp4; codecs="avc1.42c01f"``, from its ``avcC`` box
    (profile, constraints and level of the H.264 stream)."""
    i = chunk.find(b"avcC")
    if i < 0 or i + 8 > len(chunk):
        raise ValueError("not an H.264 MP4 chunk (no avcC box)")
    profile, compat, level = chunk[i + 5], chunk[i + 6], chunk[i + 7]
    return f'video/mp4; codecs="avc1.{profile:02x}{compat:02x}{level:02x}"'
