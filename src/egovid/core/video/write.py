"""Encoding a video atomically (:class:`VideoWriter`): BGR or I420 frames in display orientation,
to a temporary file renamed into place only when everything succeeded, keeping what the camera
wrote when asked (colour tags, rotation flag, metadata, timecode, audio and telemetry streams)."""

from __future__ import annotations

import contextlib
import os
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.files import commit_temp, temp_sibling, track_temp, untrack_temp
from egovid.core.video.colour import ColourTags, HdrMetadata, bgr_to_i420
from egovid.core.video.orientation import to_coded
from egovid.core.video.passthrough import Passthrough
from egovid.core.video.probe import VideoInfo, probe
from egovid.core.video.read import I420_FORMATS


def _fps_fraction(fps: float) -> Fraction:
    """The frame rate as a fraction: the NTSC rates exactly (30000/1001 ...), others to 1/1001."""
    common = {23.976: Fraction(24000, 1001), 29.97: Fraction(30000, 1001), 59.94: Fraction(60000, 1001)}
    for k, v in common.items():
        if abs(fps - k) < 1e-3:
            return v
    return Fraction(fps).limit_denominator(1001)


def _encoder_options(
    codec: str, crf: int | None, preset: str | None, options: dict[str, str] | None, hdr: HdrMetadata | None = None
) -> dict[str, str]:
    """The encoder's options: ``crf`` and ``preset`` where the codec takes them (VP9 in constant
    quality mode), then the caller's ``options``; x265 also gets the HDR10 metadata ``hdr`` and
    logs errors only."""
    opts: dict[str, str] = {}
    if crf is not None and codec in ("libx264", "libx265", "libvpx-vp9", "libvpx"):
        opts["crf"] = str(crf)
    if preset is not None and codec in ("libx264", "libx265"):
        opts["preset"] = preset
    if codec == "libvpx-vp9":
        opts.setdefault("b", "0")
    if options:
        opts.update(options)
    if codec == "libx264":
        params = opts.get("x264-params", "")
        if "mbtree" not in params:
            opts["x264-params"] = f"{params}:{X264_REPEATABLE}" if params else X264_REPEATABLE
    if codec == "libx265":
        params = opts.get("x265-params", "")
        extra = [p for p in ("" if "log-level" in params else "log-level=error", hdr.x265_params() if hdr else "") if p]
        opts["x265-params"] = ":".join([params, *extra] if params else extra)
    return opts


#: x264 settings every libx264 output gets unless the caller sets them: the libx264 inside PyAV's
#: wheels gives different pictures from the same frames, run to run, with its macroblock tree
#: (measured 2026-12-05: 192x108, CRF 14, veryfast, one thread: 2-5 distinct streams in 5 runs;
#: the hero6 clip re-encoded at CRF 18: 2-4 in 6; with ``mbtree=0``: one in 20 at any thread
#: count; Debian's ffmpeg gives one stream with the tree). Same input, same output costs the
#: tree's bit saving (a few % at equal CRF).
X264_REPEATABLE = "mbtree=0"


class VideoWriter:
    """Encode frames to ``path``, atomically.

    Frames go to a hidden temporary file in the target's folder; :meth:`close` (or leaving the
    ``with`` block normally) renames it to ``path``. An exception inside the ``with`` block, or
    :meth:`abort`, deletes the temporary file and leaves ``path`` untouched.

    ``width``, ``height`` and the frames given to :meth:`write` / :meth:`write_i420` are in display
    orientation (as :func:`~egovid.core.video.read.iter_frames` yields them).

    Parameters
    ----------
    codec:
        ``libx264`` (default, MP4), ``libx265`` (HEVC; tagged ``hvc1`` in MP4/MOV, as phones and
        Apple's players want it), ``ffv1`` (lossless, use an ``.mkv`` path), ``libvpx-vp9``...
    crf:
        Constant rate factor for x264/x265/VP9 (lower = better quality).
    pix_fmt:
        The stored pixel format: default ``yuv420p`` (``yuv444p`` for an odd size; ``bgr0`` for
        FFV1); ``yuv420p10le`` stores 10 bits per sample (:attr:`bits`), e.g. with ``libx265``
        (HEVC Main10), and takes 10-bit I420 frames in :meth:`write_i420`.
    threads, thread_type:
        Encoder threads (0: as many as FFmpeg picks) and how they split the work: PyAV's default
        ``SLICE``, or ``AUTO`` (frame and slice threads, the ``ffmpeg`` command's default; x264
        then encodes several frames at once, faster for a whole video at a few frames' latency).
    colour:
        Colour tags written into the stream; :meth:`write` converts BGR with their matrix and
        range (BT.601 limited range where unknown), :meth:`write_i420` takes the planes as they are.
    rotation:
        Display rotation flag (degrees counter-clockwise, as :attr:`VideoInfo.rotation`): frames
        are stored turned back to the coded orientation and the flag is set, like the camera did.
    keep_from:
        A source video whose camera-written facts are kept: colour tags and rotation (unless given
        here), container and video-stream metadata (creation time, ...), the timecode (MP4/MOV
        write it as a ``tmcd`` track), every audio stream, and each data stream the output
        container can carry (GoPro GPMF telemetry in MP4/MOV), interleaved by timestamp, shifted
        like the video so that both start at 0. :attr:`kept` and :attr:`dropped` say what was
        and was not carried over. A ``libx265`` output also keeps the source's HDR10 mastering-display
        and content-light metadata (:attr:`VideoInfo.hdr`).
    audio_from:
        A source video whose audio streams (only) are copied.
    metadata_from:
        A source video whose container metadata (creation time, etc.) is copied.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        width: int,
        height: int,
        fps: float,
        *,
        codec: str = "libx264",
        crf: int | None = 18,
        preset: str | None = "veryfast",
        pix_fmt: str | None = None,
        threads: int = 0,
        thread_type: str | None = None,
        colour: ColourTags | None = None,
        rotation: int | None = None,
        keep_from: str | os.PathLike | None = None,
        audio_from: str | os.PathLike | None = None,
        metadata_from: str | os.PathLike | None = None,
        options: dict[str, str] | None = None,
    ) -> None:
        self.path = Path(path)
        if not self.path.parent.exists():
            raise EgovidError(f"output folder {self.path.parent} does not exist", "create it first")
        if fps <= 0 or not np.isfinite(fps):
            raise EgovidError(f"frame rate {fps} is not positive", "give a frame rate such as 30")
        src_info = probe(keep_from, allow_truncated=True) if keep_from is not None else None
        self.kept: list[str] = []
        self.dropped: list[str] = []
        if src_info is not None:
            if src_info.hdr is not None and codec == "libx265":
                self.kept.append("HDR10 metadata " + src_info.hdr.x265_params())
            colour = src_info.colour if colour is None else colour
            rotation = src_info.rotation if rotation is None else rotation
        self.colour = colour or ColourTags()
        self.rotation = int(rotation or 0) % 360
        if self.rotation % 90:
            raise EgovidError(f"rotation {rotation}° is not a multiple of 90", "use 0, 90, 180 or 270")
        self.width, self.height = int(width), int(height)
        self.fps = float(fps)
        self._tmp = track_temp(temp_sibling(self.path))
        mov = self.path.suffix.lower() in (".mp4", ".mov", ".m4v")
        # MP4/MOV keep only standard metadata keys unless told to write the others (e.g. firmware).
        muxer_opts = {"movflags": "use_metadata_tags"} if keep_from is not None and mov else {}
        self._container = av.open(str(self._tmp), mode="w", options=muxer_opts)
        self._stream = self._add_video_stream(
            codec,
            fps,
            pix_fmt,
            _encoder_options(codec, crf, preset, options, src_info.hdr if src_info is not None else None),
            threads,
            thread_type,
        )
        self._count = 0
        self._last_pts = -1
        self._passthrough: Passthrough | None = None
        self._closed = False
        try:
            if src_info is not None:
                self._keep(keep_from, src_info)
            else:
                if metadata_from is not None:
                    self._copy_metadata(metadata_from)
                if audio_from is not None:
                    self._passthrough = Passthrough(audio_from, self._container, data=False)
        except BaseException:
            self.abort()
            raise

    def _add_video_stream(
        self, codec: str, fps: float, pix_fmt: str | None, opts: dict[str, str], threads: int, thread_type: str | None
    ) -> av.video.stream.VideoStream:
        """The output's video stream: coded size, pixel format, colour tags, rotation flag, time
        base and encoder settings."""
        coded_w, coded_h = (self.height, self.width) if self.rotation in (90, 270) else (self.width, self.height)
        stream = self._container.add_stream(codec, rate=_fps_fraction(fps))
        stream.width = coded_w
        stream.height = coded_h
        if pix_fmt is None:
            pix_fmt = "bgr0" if codec == "ffv1" else "yuv420p"
            if pix_fmt == "yuv420p" and (self.width % 2 or self.height % 2):
                pix_fmt = "yuv444p"
        stream.pix_fmt = pix_fmt
        self._i420 = pix_fmt in I420_FORMATS.values()
        #: Bits per sample of the I420 frames :meth:`write_i420` takes (8: uint8, 10: uint16).
        self.bits = next((b for b, f in I420_FORMATS.items() if f == pix_fmt), 8)
        if self._i420:
            self.colour.apply(stream.codec_context)
        if codec == "libx265" and self._container.format.name.split(",")[0] in ("mov", "mp4", "m4a"):
            stream.codec_tag = "hvc1"
        if self.rotation:
            stream.set_display_rotation(self.rotation)
        # A fine time base keeps variable frame timing exactly (1/rate would round it).
        # Frames are stamped in this time base, kept here: a muxer may change the *stream's* time base
        # when it writes the header at the first packet (Matroska: 1/1000), after an encoder with a
        # frame delay has already taken frames (libx264 in .mkv came out at t = 0, 0.05, 4.501, ...).
        self._tb = Fraction(1, 90000)
        stream.time_base = self._tb
        stream.codec_context.time_base = self._tb
        stream.options = opts
        if threads:
            stream.codec_context.thread_count = threads
        if thread_type is not None:
            stream.codec_context.thread_type = thread_type
        return stream

    def _copy_metadata(self, source: str | os.PathLike) -> None:
        with contextlib.suppress(Exception), av.open(str(source)) as src:
            for k, v in src.metadata.items():
                if k.lower() not in ("encoder", "major_brand", "minor_version", "compatible_brands"):
                    self._container.metadata[k] = v

    def _keep(self, source: str | os.PathLike, info: VideoInfo) -> None:
        self._copy_metadata(source)
        with av.open(str(source)) as src:
            for k, v in src.streams.video[0].metadata.items():
                if k.lower() in ("creation_time", "language", "timecode"):
                    self._stream.metadata[k] = v
        if info.colour != ColourTags():
            self.kept.append("colour tags " + "/".join(v or "?" for v in info.colour.to_dict().values()))
        if info.rotation:
            self.kept.append(f"rotation {info.rotation}°")
        if info.creation_time:
            self.kept.append(f"creation time {info.creation_time}")
        fmt = self._container.format.name
        mov = any(f in fmt.split(",") for f in ("mp4", "mov"))
        if info.timecode:
            self._stream.metadata["timecode"] = info.timecode
            (self.kept if mov else self.dropped).append(f"timecode {info.timecode}")
        self._passthrough = Passthrough(source, self._container, data=True)
        self.kept += self._passthrough.kept
        self.dropped += self._passthrough.dropped

    @property
    def container(self) -> av.container.OutputContainer:
        """The output container, for a caller adding streams of its own (before the first frame)."""
        return self._container

    def _next_pts(self, time: float | None) -> tuple[int, float]:
        if time is None:
            time = self._count / self.fps
        pts = max(round(time / self._tb), self._last_pts + 1)
        self._last_pts = pts
        return pts, time

    def _encode(self, frame: av.VideoFrame, pts: int, time: float) -> None:
        frame.pts = pts
        frame.time_base = self._tb
        if self._i420:
            self.colour.apply(frame)
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self._count += 1
        if self._passthrough is not None:
            self._passthrough.feed_until(time)

    def write(self, image: np.ndarray, time: float | None = None) -> None:
        """Append one HxWx3 BGR uint8 frame shown at ``time`` seconds (default: index / fps); a
        10-bit writer stores its 8-bit samples times 4."""
        if image.shape[:2] != (self.height, self.width):
            raise EgovidError(
                f"frame of size {image.shape[1]}x{image.shape[0]} does not match the video's "
                f"{self.width}x{self.height}",
                "resize frames before writing",
            )
        pts, time = self._next_pts(time)
        if self._i420:
            yuv = to_coded(bgr_to_i420(image, self.colour), self.rotation, True)
            if self.bits > 8:
                yuv = yuv.astype(np.uint16) << (self.bits - 8)
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(yuv), format=I420_FORMATS[self.bits])
        else:
            frame = av.VideoFrame.from_ndarray(
                np.ascontiguousarray(to_coded(image, self.rotation, False)), format="bgr24"
            )
        self._encode(frame, pts, time)

    def write_i420(self, frame: np.ndarray, time: float | None = None) -> None:
        """Append one I420 frame ((h*3/2, w) uint8, or uint16 holding 0-1023 for a 10-bit writer:
        as :func:`~egovid.core.video.read.iter_frames` decodes it with ``bits=self.bits``) without
        any colour conversion, so a lossless codec (FFV1, or x264 at ``options={'qp': '0'}``) stores
        it bit for bit; the planes are read with the writer's :attr:`colour` tags (e.g. full range)."""
        dtype = np.uint8 if self.bits == 8 else np.uint16
        if frame.shape != (self.height * 3 // 2, self.width) or not self._i420 or frame.dtype != dtype:
            raise EgovidError(
                f"I420 frames need a {self.bits}-bit 4:2:0 writer of the same size and sample type",
                "check the frame size and bit depth",
            )
        pts, time = self._next_pts(time)
        yuv = np.ascontiguousarray(to_coded(frame, self.rotation, True))
        self._encode(av.VideoFrame.from_ndarray(yuv, format=I420_FORMATS[self.bits]), pts, time)

    def close(self) -> Path:
        """Flush the encoder, finish the file and move it to ``path``."""
        if self._closed:
            return self.path
        try:
            for packet in self._stream.encode():
                self._container.mux(packet)
            if self._passthrough is not None:
                self._passthrough.feed_until(float("inf"))
                self._passthrough.close()
            self._container.close()
        except BaseException:
            self.abort()
            raise
        self._closed = True
        if self._count == 0:
            self._tmp.unlink(missing_ok=True)
            untrack_temp(self._tmp)
            raise EgovidError("no frames were written", "the input produced no frames")
        try:
            commit_temp(self._tmp, self.path)
        except BaseException:
            self._tmp.unlink(missing_ok=True)
            untrack_temp(self._tmp)
            raise
        return self.path

    def abort(self) -> None:
        """Drop everything written; the target path is left as it was."""
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(Exception):
            if self._passthrough is not None:
                self._passthrough.close()
        with contextlib.suppress(Exception):
            self._container.close()
        self._tmp.unlink(missing_ok=True)
        untrack_temp(self._tmp)

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
