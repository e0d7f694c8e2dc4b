"""Decoding a video frame by frame (:func:`iter_frames`, never the whole video), in display
orientation and presentation order, and counting its frames exactly (:func:`count_frames`)."""

from __future__ import annotations

import contextlib
import heapq
import os
import queue
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import av
import numpy as np
from av.video.reformatter import VideoReformatter

from egovid.core.errors import EgovidError
from egovid.core.video.container import FIX_VIDEO, cut_accepted, ffmpeg_reason, open_video, packet_cut
from egovid.core.video.orientation import rotate_i420, rotation_of, to_display

T = TypeVar("T")

#: Frames held back to put a decoder's output into presentation order.
_REORDER_DEPTH = 4
#: FFmpeg's planar YUV 4:2:0 pixel format by bits per sample (as :func:`iter_frames` yields them
#: with ``i420=True`` and :class:`~egovid.core.video.write.VideoWriter` takes them).
I420_FORMATS = {8: "yuv420p", 10: "yuv420p10le"}


@dataclass
class Frame:
    """One decoded frame: ``image`` is HxWx3 BGR uint8 (or HxW grey, or an (H*3/2, W) I420
    picture: uint8, uint16 at 10 bits), ``time`` in seconds."""

    index: int
    time: float
    image: np.ndarray


def _decoded(container: av.container.InputContainer, stream: av.video.VideoStream, path: str | os.PathLike):
    """Decode ``stream``; for a truncated file the caller accepted, stop at the cut and flush."""
    if not cut_accepted(path):
        yield from container.decode(stream)
        return
    size = Path(path).stat().st_size
    try:
        for packet in container.demux(stream):
            if packet.size and packet_cut(packet, size):
                break
            yield from packet.decode()
    except av.error.FFmpegError:
        pass
    with contextlib.suppress(av.error.FFmpegError):
        yield from stream.decode(None)


def iter_frames(
    path: str | os.PathLike,
    *,
    gray: bool = False,
    i420: bool = False,
    bits: int = 8,
    scale: float | None = None,
    max_frames: int | None = None,
) -> Iterator[Frame]:
    """Decode ``path`` frame by frame.

    Parameters
    ----------
    gray:
        Yield HxW uint8 luma instead of HxWx3 BGR (cheaper: no colour conversion).
    i420:
        Yield the decoded YUV 4:2:0 picture as one (H*3/2, W) uint8 array (Y, then U, then V),
        without any colour conversion (for re-encoding bit-exactly).
    bits:
        Bits per sample of the ``i420`` planes: 8 (uint8), or 10 (uint16 holding 0-1023, FFmpeg's
        ``yuv420p10le``: a 10-bit video's samples as decoded, an 8-bit one's times 4).
    scale:
        Resize by this factor (0 < scale <= 1) inside FFmpeg's scaler, e.g. 0.5 for half size.
    max_frames:
        Stop after this many frames.

    Frames come in display orientation and in presentation order (a small buffer reorders frames
    a decoder hands out of order); ``time`` is the presentation time in seconds from the first
    frame, from the timestamps (so variable frame rate is kept), made strictly increasing (a
    repeated or backward timestamp becomes the previous one plus a nominal frame interval).
    Raises :class:`EgovidError` if the video is unreadable or stops decoding midway.
    """
    if scale is not None and not (0.0 < scale <= 1.0):
        raise EgovidError(f"scale {scale} must be in (0, 1]", "use e.g. 0.5 for half size")
    if bits not in I420_FORMATS:
        raise EgovidError(f"{bits} bits per sample are not supported", "use 8 or 10")
    container = open_video(path)
    try:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        rate = float(stream.average_rate or stream.guessed_rate or 30)
        nominal = 1.0 / rate if rate > 0 else 1.0 / 30
        tb = float(stream.time_base) if stream.time_base else None
        reorder = _Reorder(_REORDER_DEPTH)
        timeline = _Timeline(nominal)
        decoded = 0
        scaler = VideoReformatter()  # one swscale context for the whole video, not one per frame
        try:
            for frame in _decoded(container, stream, path):
                img = _picture(frame, gray, I420_FORMATS[bits] if i420 else None, scale, scaler)
                pts = frame.pts if frame.pts is not None else frame.dts
                t = float(pts * tb) if (pts is not None and tb) else decoded * nominal
                decoded += 1
                for item in reorder.push(t, img):
                    yield timeline.frame(*item)
                    if max_frames is not None and timeline.index >= max_frames:
                        return
        except av.error.FFmpegError as exc:
            raise EgovidError(
                f"{path} stops decoding at frame {decoded} ({ffmpeg_reason(exc)})",
                "the file is corrupt or truncated; re-export or repair it",
            ) from None
        for item in reorder.flush():
            yield timeline.frame(*item)
            if max_frames is not None and timeline.index >= max_frames:
                return
        if timeline.index == 0:
            raise EgovidError(f"video {path} has no frames", FIX_VIDEO)
    finally:
        container.close()


def _picture(
    frame: av.VideoFrame, gray: bool, i420: str | None, scale: float | None, scaler: VideoReformatter
) -> np.ndarray:
    """One decoded frame as :func:`iter_frames` yields its image: pixel format (``i420``: the
    4:2:0 format asked for, else grey or BGR), scale, display orientation. ``scaler`` is reused from
    frame to frame: ``VideoFrame.to_ndarray(format=...)`` would set up a new swscale context (and
    its threads) for every frame; the pixels are the same."""
    fmt = i420 or ("gray" if gray else "bgr24")
    if scale is not None and scale != 1.0:
        sw = max(2, round(frame.width * scale))
        sh = max(2, round(frame.height * scale))
        img = scaler.reformat(frame, sw, sh, fmt, interpolation="AREA").to_ndarray()
    else:
        img = scaler.reformat(frame, format=fmt).to_ndarray()
    rotation = rotation_of(frame)
    return rotate_i420(img, rotation) if i420 else to_display(img, rotation)


class _Timeline:
    """Numbers the frames leaving the reorder buffer and makes their times start at 0 and
    increase strictly (a repeated or backward time becomes the previous one plus ``nominal``)."""

    def __init__(self, nominal: float) -> None:
        self.nominal = nominal
        self.t0: float | None = None
        self.prev: float | None = None
        self.index = 0

    def frame(self, t: float, img: np.ndarray) -> Frame:
        if self.t0 is None:
            self.t0 = t
        t -= self.t0
        if self.prev is not None and t <= self.prev:
            t = self.prev + self.nominal
        self.prev = t
        frame = Frame(self.index, t, img)
        self.index += 1
        return frame


class _Reorder:
    """A small min-heap on presentation time: frames leave in time order, ``depth`` behind."""

    def __init__(self, depth: int) -> None:
        self.depth = depth
        self.heap: list = []
        self.seq = 0

    def push(self, t: float, img: np.ndarray):
        heapq.heappush(self.heap, (t, self.seq, img))
        self.seq += 1
        while len(self.heap) > self.depth:
            t, _, img = heapq.heappop(self.heap)
            yield t, img

    def flush(self):
        while self.heap:
            t, _, img = heapq.heappop(self.heap)
            yield t, img


def read_frames(path: str | os.PathLike, **kwargs) -> tuple[np.ndarray, np.ndarray]:
    """Decode a short video completely: ``(images (N,H,W[,3]) uint8, times (N,) seconds)``.

    Only for clips that fit in memory (tests, synthetic content); long videos use
    :func:`iter_frames`.
    """
    frames = list(iter_frames(path, **kwargs))
    return np.stack([f.image for f in frames]), np.array([f.time for f in frames])


def count_frames(path: str | os.PathLike) -> int:
    """Exact number of decodable frames (demuxes and decodes; no colour conversion)."""
    container = open_video(path)
    try:
        n = 0
        for _ in _decoded(container, container.streams.video[0], path):
            n += 1
        return n
    except av.error.FFmpegError as exc:
        raise EgovidError(f"{path} stops decoding at frame {n} ({ffmpeg_reason(exc)})", FIX_VIDEO) from None
    finally:
        container.close()


def read_ahead(items: Iterator[T], depth: int) -> Iterator[T]:
    """``items`` produced by a background thread up to ``depth`` ahead of the consumer: decoders
    (FFmpeg, libvpx) and OpenCV release the GIL, so decoding overlaps the consumer's own work on
    another core. An error raised by ``items`` is raised to the consumer when it reaches it;
    closing the returned generator (or dropping it) stops the thread and closes ``items``."""
    q: queue.Queue = queue.Queue(depth)
    stop = threading.Event()
    end = object()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def run() -> None:
        try:
            for item in items:
                if not put((item, None)):
                    return
            put((end, None))
        except BaseException as exc:  # handed to the consumer
            put((end, exc))
        finally:
            close = getattr(items, "close", None)
            if close is not None:
                close()

    worker = threading.Thread(target=run, name="egovid-read-ahead", daemon=True)
    worker.start()
    try:
        while True:
            item, exc = q.get()
            if item is end:
                if exc is not None:
                    raise exc
                return
            yield item
    finally:
        stop.set()
        worker.join()


@contextlib.contextmanager
def decoding_ahead(path: str | os.PathLike, depth: int, **kwargs) -> Iterator[Iterator[Frame]]:
    """:func:`iter_frames` of ``path`` (``kwargs`` as there) decoding from now on in a background
    thread, up to ``depth`` frames ahead of the consumer (:func:`read_ahead`): a caller that needs
    the frames only after other work (the stabiliser fits its path first) has them decoded
    meanwhile on another core. An unreadable video raises here, on entry; the decoder stops and
    its thread ends when the ``with`` block is left."""
    ahead = read_ahead(iter_frames(path, **kwargs), max(int(depth), 1))
    try:
        first = next(ahead, None)  # starts the thread
        yield iter(()) if first is None else _chain_first(first, ahead)
    finally:
        ahead.close()


def _chain_first(first: Frame, rest: Iterator[Frame]) -> Iterator[Frame]:
    yield first
    yield from rest
