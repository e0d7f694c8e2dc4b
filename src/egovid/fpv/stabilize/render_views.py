"""Render a video view by view: decode, one remap per frame (:class:`MeshWarp`), encode, overlapped.

Three stages run at once on threads (PyAV decodes and encodes, OpenCV remaps, all without the
GIL): the next frame decodes and the previous one encodes while this one is warped; one job in
flight per stage keeps the order and bounds memory to a few frames. Frames are warped as decoded
(I420 planes, 10-bit ones as uint16), the output keeps what the camera wrote (``VideoWriter(keep_from=src)``) and only
appears at ``dst`` when complete.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

from egovid.core.errors import EgovidError
from egovid.core.video import Frame, VideoWriter, iter_frames, probe
from egovid.fpv.stabilize.render import OutputFormat
from egovid.fpv.stabilize.warp import FrameView, MeshWarp


@dataclass
class ViewsRendered:
    """``frames`` written, ``seconds`` taken, what was ``kept`` from and ``dropped`` of the input,
    the output's ``bits`` per sample."""

    frames: int
    seconds: float
    kept: list[str]
    dropped: list[str]
    bits: int = 8


def render_views(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    views: Sequence[FrameView],
    warp: MeshWarp,
    *,
    crf: int = 18,
    preset: str = "veryfast",
    bit_depth: str | int = "auto",
    progress: Callable[[int, int], None] | None = None,
    frames: Iterator[Frame] | None = None,
) -> ViewsRendered:
    """Write ``dst``: frame k of ``src`` seen as ``views[k]`` (see the module docstring), at the
    bits per sample :func:`~egovid.fpv.stabilize.render.output_bits` gives for ``bit_depth``.
    ``frames`` are ``src``'s I420 frames at those bits where the caller decodes them already."""
    info = probe(src)
    w, h = info.width, info.height
    if w % 2 or h % 2:
        raise EgovidError(f"{src} is {w}x{h}; the stabiliser needs even dimensions", "crop or scale it by one pixel")
    fmt = OutputFormat.of(info, bit_depth)
    t0 = time.perf_counter()
    n = 0
    if frames is None:
        frames = iter_frames(src, i420=True, bits=fmt.bits)
    stages = ThreadPoolExecutor(max_workers=2, thread_name_prefix="render")
    decoding = stages.submit(next, frames, None)
    encoding: Future | None = None
    try:
        with VideoWriter(
            dst, w, h, info.fps, codec=fmt.codec, pix_fmt=fmt.pix_fmt, crf=crf, preset=preset, thread_type="AUTO",
            keep_from=src,
        ) as writer:  # fmt: skip
            try:
                while (frame := decoding.result()) is not None:
                    decoding = stages.submit(next, frames, None)
                    k = frame.index
                    if k >= len(views):
                        raise EgovidError(
                            f"{src} has more frames than its motion ({len(views)})",
                            "re-estimate the motion of this video",
                        )
                    out = warp.warp_i420(frame.image, views[k], fmt.black)
                    if encoding is not None:
                        encoding.result()
                    encoding = stages.submit(writer.write_i420, out, frame.time)
                    n += 1
                    if progress is not None:
                        progress(n, info.frame_count)
                if encoding is not None:
                    encoding.result()
            finally:
                stages.shutdown(wait=True)
            if n != len(views):
                raise EgovidError(
                    f"{src} decoded {n} frames but its motion has {len(views)}", "re-estimate the motion of this video"
                )
    finally:
        stages.shutdown(wait=True)
        close = getattr(frames, "close", None)
        if close is not None:
            close()
    return ViewsRendered(n, time.perf_counter() - t0, writer.kept, writer.dropped, fmt.bits)
