"""What a video is, without decoding it all: :func:`probe` (size, rate, rotation, colour, streams;
a check that it decodes and holds the frames its container lists, with a cache of recent answers)
and :func:`frame_times` (every frame's presentation time, by demuxing)."""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass, replace
from pathlib import Path

import av
import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.video.colour import ColourTags, HdrMetadata, sample_bits
from egovid.core.video.container import FIX_VIDEO, accept_cut, cut_accepted, ffmpeg_reason, open_video, packet_cut
from egovid.core.video.orientation import rotation_of

_PROBED: dict[tuple, VideoInfo] = {}  # recent probe() results by file identity and state (see probe)
_PROBED_LOCK = threading.Lock()  # probe() runs in worker threads too (dashcam ingest, voeval cells)


@dataclass(frozen=True)
class VideoInfo:
    """What a video is, as needed by the rest of egovid.

    ``width`` and ``height`` are in display orientation (after the rotation flag), in pixels.
    ``frame_count`` is the container's claim (or an estimate from the duration); the exact count
    comes from decoding, see :func:`~egovid.core.video.read.count_frames`. ``rotation`` is the
    container's display rotation in degrees counter-clockwise. ``colour`` holds the colour tags of the video stream,
    ``pix_fmt`` its decoded pixel format (e.g. ``yuvj420p``; :attr:`bit_depth` its bits per sample),
    ``hdr`` the HDR10 mastering-display and content-light metadata of its first frame (None where it
    has none), ``timecode`` the SMPTE start
    timecode (``HH:MM:SS:FF``) where the camera wrote one, ``audio_streams`` the number of audio
    streams and ``data_streams`` a description (handler name or codec) of each data stream, e.g.
    ``("GoPro TCD", "GoPro MET", "GoPro SOS")`` for a GoPro's timecode, GPMF telemetry and
    recovery tracks.
    """

    path: Path
    width: int
    height: int
    fps: float
    frame_count: int
    duration: float
    rotation: int
    codec: str
    has_audio: bool
    creation_time: str | None = None
    colour: ColourTags = ColourTags()  # noqa: RUF009 (frozen, so one shared default is safe)
    pix_fmt: str = ""
    timecode: str | None = None
    audio_streams: int = 0
    data_streams: tuple[str, ...] = ()
    truncated: bool = False  # cut short; frame_count and duration are then what is really there
    hdr: HdrMetadata | None = None

    @property
    def bit_depth(self) -> int:
        """Bits per sample of the decoded pictures (8; 10 for a phone's HDR HEVC, ``yuv420p10le``)."""
        return sample_bits(self.pix_fmt)


def probe(path: str | os.PathLike, *, allow_truncated: bool = False) -> VideoInfo:
    """Open ``path``, decode its first frame, check its end, and describe the video.

    Raises :class:`EgovidError` for a missing, empty, corrupt or frameless file, and for a
    truncated one (its last frames are missing although the container lists them) unless
    ``allow_truncated``: then ``frame_count`` is the number of frames really there, and
    the readers (:mod:`egovid.core.video.read`, :func:`frame_times`) stop quietly after them for the rest of the
    process.

    A file probed again unchanged (same inode, size, modification and change times) gives the
    remembered answer without opening it: one job probes its input several times (~0.1 s each).
    """
    try:
        st = os.stat(path)
        real = Path(path).resolve()
        key = (real, st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
        key += (allow_truncated, cut_accepted(real))
    except OSError:
        key = None  # open_video() says what is wrong
    with _PROBED_LOCK:
        info = _PROBED.get(key) if key is not None else None
    if info is not None:
        return replace(info, path=Path(path))  # as this caller named it
    info = _probe(path, allow_truncated)
    if key is not None:
        with _PROBED_LOCK:
            _PROBED[key] = info
            while len(_PROBED) > 32:
                del _PROBED[next(iter(_PROBED))]
    return info


def _probe(path: str | os.PathLike, allow_truncated: bool) -> VideoInfo:
    container = open_video(path)
    try:
        stream = container.streams.video[0]
        rate = stream.average_rate or stream.guessed_rate or stream.base_rate
        fps = float(rate) if rate else 0.0
        first = None
        try:
            first = next(iter(container.decode(stream)), None)
        except av.error.FFmpegError as exc:
            raise EgovidError(f"{path} does not decode ({ffmpeg_reason(exc)})", FIX_VIDEO) from None
        if first is None:
            raise EgovidError(f"video {path} has no frames", FIX_VIDEO)
        rotation = rotation_of(first)
        w, h = first.width, first.height
        if rotation in (90, 270):
            w, h = h, w
        duration = 0.0
        if stream.duration is not None and stream.time_base is not None:
            duration = float(stream.duration * stream.time_base)
        elif container.duration is not None:
            duration = container.duration / av.time_base
        frames = int(stream.frames or 0)
        if frames <= 0 and duration > 0 and fps > 0:
            frames = round(duration * fps)
        if fps <= 0:
            fps = 30.0
        truncated = _truncated_end(container, stream, Path(path))
        if truncated is not None:
            real, real_s = truncated
            claimed = f"{frames} frames, {duration:.1f} s" if frames else f"{duration:.1f} s"
            if not allow_truncated and not cut_accepted(path):
                raise EgovidError(
                    f"{path} is truncated: it holds {real} frames ({real_s:.1f} s) of the {claimed} "
                    "its container lists",
                    f"copy the file again, or pass --allow-truncated to process the {real} frames there are",
                )
            accept_cut(path)
            frames, duration = real, real_s
        return VideoInfo(
            path=Path(path),
            width=w,
            height=h,
            fps=fps,
            frame_count=max(frames, 1),
            duration=duration,
            rotation=rotation,
            codec=stream.codec_context.name,
            has_audio=bool(container.streams.audio),
            creation_time=container.metadata.get("creation_time") or stream.metadata.get("creation_time"),
            **_stream_facts(container, stream, first),
            truncated=truncated is not None,
        )
    finally:
        container.close()


def _stream_facts(container, stream, first: av.VideoFrame) -> dict:
    """The :class:`VideoInfo` fields a writer needs to keep what the camera wrote."""
    colour = ColourTags.of(first)
    if colour == ColourTags():
        colour = ColourTags.of(stream.codec_context)
    timecode = stream.metadata.get("timecode") or container.metadata.get("timecode")
    for s in container.streams.data:
        timecode = timecode or s.metadata.get("timecode")
    data = tuple(
        (s.metadata.get("handler_name") or "").strip() or getattr(s, "name", None) or "data"
        for s in container.streams.data
    )
    return {
        "colour": colour,
        "pix_fmt": first.format.name,
        "hdr": HdrMetadata.of(first),
        "timecode": timecode,
        "audio_streams": len(container.streams.audio),
        "data_streams": data,
    }


def _claimed_duration(container: av.container.InputContainer, stream: av.video.VideoStream) -> float | None:
    """Seconds of video the container says the stream has (None when it does not say)."""
    if stream.duration is not None and stream.time_base is not None and stream.duration > 0:
        return float(stream.duration * stream.time_base)
    tag = stream.metadata.get("DURATION") or stream.metadata.get("duration")
    if tag:
        try:
            h, m, sec = tag.split(":")
            return int(h) * 3600 + int(m) * 60 + float(sec)
        except ValueError:
            pass
    if container.duration is not None and len(container.streams) == 1:
        return container.duration / av.time_base
    return None


def _truncated_end(
    container: av.container.InputContainer, stream: av.video.VideoStream, path: Path
) -> tuple[int, float] | None:
    """Check the end of the video stream against what the container claims.

    Demuxes (no decoding) from about a second before the claimed end. Returns None when the end
    is there, else ``(frames, seconds)`` really in the file, counted by demuxing it all (only
    then). A cut of less than half a second (or 2 %) is not flagged here; decoding reports it.
    """
    claimed = _claimed_duration(container, stream)
    size = path.stat().st_size
    tb = stream.time_base
    start = stream.start_time or 0
    fps = float(stream.average_rate or stream.guessed_rate or 30)
    last_end = None
    cut = False
    try:
        if claimed is not None and claimed > 1.0:
            container.seek(start + int((claimed - 1.0) / tb), stream=stream, backward=True)
        for packet in container.demux(stream):
            if not packet.size or packet.pts is None:
                continue
            if packet_cut(packet, size):
                cut = True
                break
            end = float((packet.pts - start + (packet.duration or 0)) * tb)
            last_end = end if last_end is None else max(last_end, end)
    except av.error.FFmpegError:
        cut = True
    if not cut:
        if claimed is None or last_end is None:
            return None
        if last_end >= claimed - max(0.5, 0.02 * claimed, 2.5 / fps):
            return None
    frames, seconds = _complete_packets(path)
    return frames, seconds


def _complete_packets(path: Path) -> tuple[int, float]:
    """Frames (packets with all their data) at the start of a cut file, and their seconds."""
    size = path.stat().st_size
    n = 0
    last = 0.0
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        start = stream.start_time or 0
        try:
            for packet in container.demux(stream):
                if not packet.size:
                    continue
                if packet_cut(packet, size):
                    break
                n += 1
                if packet.pts is not None:
                    last = max(last, float((packet.pts - start + (packet.duration or 0)) * stream.time_base))
        except av.error.FFmpegError:
            pass
    return n, last


def frame_times(path: str | os.PathLike) -> np.ndarray:
    """Presentation times (N,) in seconds of every frame, from the first, without decoding
    (demuxing only; sorted, so B-frames are in presentation order; repeated or backward times
    follow :func:`~egovid.core.video.read.iter_frames`' rule)."""
    container = open_video(path)
    try:
        stream = container.streams.video[0]
        rate = float(stream.average_rate or stream.guessed_rate or 30)
        nominal = 1.0 / rate if rate > 0 else 1.0 / 30
        tb = float(stream.time_base) if stream.time_base else nominal
        pts = []
        cut = cut_accepted(path)  # a truncated file the caller accepted
        size = Path(path).stat().st_size
        for packet in container.demux(stream):
            if packet.size == 0:
                continue
            if cut and packet_cut(packet, size):
                break
            p = packet.pts if packet.pts is not None else packet.dts
            pts.append(len(pts) * nominal / tb if p is None else p)
    except av.error.FFmpegError as exc:
        raise EgovidError(f"{path} cannot be read ({ffmpeg_reason(exc)})", FIX_VIDEO) from None
    finally:
        container.close()
    t = np.sort(np.asarray(pts, float)) * tb
    if len(t) == 0:
        raise EgovidError(f"video {path} has no frames", FIX_VIDEO)
    t -= t[0]
    for k in range(1, len(t)):
        if t[k] <= t[k - 1]:
            t[k] = t[k - 1] + nominal
    return t
