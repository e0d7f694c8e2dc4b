"""Streaming video input and output on PyAV (FFmpeg).

* :func:`probe` opens a video, checks that it decodes and that it holds the frames its container
  lists (a file cut short while copying or recording is reported with how many frames it really
  has, unless the caller accepts it with ``allow_truncated``), and describes it (:class:`VideoInfo`).
* :func:`iter_frames` decodes frame by frame (never the whole video), with the exact frame count,
  presentation times in seconds, and the container's rotation flag applied, so frames come out in
  display orientation (unlike ``cv2.VideoCapture``, egovid reports the flag and the camera
  intrinsics are those of the rotated frame).
* :class:`VideoWriter` encodes frames to a temporary file next to the target and renames it into
  place only when everything succeeded, so an error or an interruption never leaves a
  half-written video at the target path. Given ``keep_from=`` a source video, it keeps what the
  camera wrote: colour tags (primaries, transfer, matrix, range), the rotation flag, creation time
  and other metadata, the timecode, every audio stream, and the data (telemetry) streams the
  output container can carry (GoPro GPMF ``gpmd`` in MP4/MOV); see :class:`VideoWriter`.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.files import commit_temp, temp_sibling, track_temp, untrack_temp

_FIX_VIDEO = "give a video file FFmpeg can decode (e.g. MP4/H.264, MKV, WebM)"
_TRUNCATED_OK: dict[Path, int] = {}  # truncated videos a caller accepted -> frames they really have
_PROBED: dict[tuple, VideoInfo] = {}  # recent probe() results by file identity and state (see probe)
_PROBED_LOCK = threading.Lock()  # probe() runs in worker threads too (dashcam ingest, voeval cells)


# FFmpeg's enum values (libavutil/pixfmt.h) by the names ffprobe prints.
# fmt: off
_PRIMARIES = {"bt709": 1, "bt470m": 4, "bt470bg": 5, "smpte170m": 6, "smpte240m": 7, "film": 8, "bt2020": 9,
              "smpte428": 10, "smpte431": 11, "smpte432": 12, "ebu3213": 22}
_TRANSFER = {"bt709": 1, "gamma22": 4, "gamma28": 5, "smpte170m": 6, "smpte240m": 7, "linear": 8, "log100": 9,
             "log316": 10, "iec61966-2-4": 11, "bt1361e": 12, "iec61966-2-1": 13, "bt2020-10": 14,
             "bt2020-12": 15, "smpte2084": 16, "smpte428": 17, "arib-std-b67": 18}
_MATRIX = {"gbr": 0, "bt709": 1, "fcc": 4, "bt470bg": 5, "smpte170m": 6, "smpte240m": 7, "ycgco": 8,
           "bt2020nc": 9, "bt2020c": 10, "smpte2085": 11, "chroma-derived-nc": 12, "chroma-derived-c": 13,
           "ictcp": 14}
_RANGE = {"tv": 1, "pc": 2}
# Luma weights (Kr, Kb) of the Y'CbCr matrices, for the writer's BGR -> YUV conversion.
_KR_KB = {"bt709": (0.2126, 0.0722), "bt2020nc": (0.2627, 0.0593), "bt2020c": (0.2627, 0.0593),
          "smpte240m": (0.212, 0.087), "fcc": (0.30, 0.11)}
# fmt: on


def _name_of(table: dict[str, int], value) -> str | None:
    for name, v in table.items():
        if v == int(value or 0):
            return name
    return None


@dataclass(frozen=True)
class ColourTags:
    """How a video's pixel values are to be read: FFmpeg's names (as ffprobe prints them), ``None``
    where the file does not say.

    ``primaries`` (e.g. ``bt709``), ``transfer`` (``bt709``, ``smpte2084`` for HDR10 PQ,
    ``arib-std-b67`` for HLG), ``matrix`` (the Y'CbCr matrix: ``bt709``, ``smpte170m``, ``bt2020nc``)
    and ``range``: ``tv`` (limited, luma 16-235) or ``pc`` (full, 0-255; GoPro and many phones).
    """

    primaries: str | None = None
    transfer: str | None = None
    matrix: str | None = None
    range: str | None = None

    @classmethod
    def of(cls, obj) -> ColourTags:
        """The tags of a PyAV codec context or frame (anything with ``color_primaries``, ``color_trc``,
        ``colorspace`` and ``color_range``)."""
        rng = _name_of(_RANGE, obj.color_range)
        fmt = getattr(getattr(obj, "format", None), "name", None) or getattr(obj, "pix_fmt", None) or ""
        if rng is None and str(fmt).startswith("yuvj"):
            rng = "pc"  # the deprecated yuvj formats are full range by definition
        return cls(
            _name_of(_PRIMARIES, obj.color_primaries),
            _name_of(_TRANSFER, obj.color_trc),
            _name_of(_MATRIX, obj.colorspace),
            rng,
        )

    @property
    def full_range(self) -> bool:
        """True when luma spans 0-255 (``range == "pc"``)."""
        return self.range == "pc"

    def apply(self, target) -> None:
        """Write the known tags into a PyAV codec context or frame (unknown ones stay unspecified)."""
        for attr, table, name in (
            ("color_primaries", _PRIMARIES, self.primaries),
            ("color_trc", _TRANSFER, self.transfer),
            ("colorspace", _MATRIX, self.matrix),
            ("color_range", _RANGE, self.range),
        ):
            if name in table:
                setattr(target, attr, table[name])

    def to_dict(self) -> dict[str, str | None]:
        """JSON-ready form."""
        return {"primaries": self.primaries, "transfer": self.transfer, "matrix": self.matrix, "range": self.range}


@dataclass(frozen=True)
class VideoInfo:
    """What a video is, as needed by the rest of egovid.

    ``width`` and ``height`` are in display orientation (after the rotation flag), in pixels.
    ``frame_count`` is the container's claim (or an estimate from the duration); the exact count
    comes from decoding, see :func:`iter_frames`. ``rotation`` is the container's display rotation
    in degrees counter-clockwise. ``colour`` holds the colour tags of the video stream,
    ``pix_fmt`` its decoded pixel format (e.g. ``yuvj420p``), ``timecode`` the SMPTE start
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
    colour: ColourTags = ColourTags()
    pix_fmt: str = ""
    timecode: str | None = None
    audio_streams: int = 0
    data_streams: tuple[str, ...] = ()
    truncated: bool = False  # cut short; frame_count and duration are then what is really there


@dataclass
class Frame:
    """One decoded frame: ``image`` is HxWx3 BGR uint8 (or HxW grey), ``time`` in seconds."""

    index: int
    time: float
    image: np.ndarray


def _open(path: str | os.PathLike) -> av.container.InputContainer:
    p = Path(path)
    if not p.exists():
        raise EgovidError(f"video not found: {p}", "check the path")
    if p.is_dir():
        raise EgovidError(f"{p} is a folder, not a video", _FIX_VIDEO)
    if p.stat().st_size == 0:
        raise EgovidError(f"video {p} is empty (0 bytes)", _FIX_VIDEO)
    try:
        container = av.open(str(p), mode="r")
    except av.error.FFmpegError as exc:
        if _is_mp4_without_index(p):
            raise EgovidError(
                f"{p} is an MP4/MOV file without its index (moov box): it was cut short while recording or copying",
                "copy it again from the camera, or rebuild the index with a recovery tool such as untrunc",
            ) from None
        raise EgovidError(f"{p} is not a readable video ({_ffmpeg_reason(exc)})", _FIX_VIDEO) from None
    if not container.streams.video:
        container.close()
        raise EgovidError(f"{p} has no video stream", _FIX_VIDEO)
    return container


def _is_mp4_without_index(p: Path) -> bool:
    """An ISO-BMFF file (ftyp box first) whose top-level boxes hold no ``moov``."""
    try:
        with open(p, "rb") as fh:
            if fh.read(12)[4:8] != b"ftyp":
                return False
            fh.seek(0)
            size = p.stat().st_size
            pos = 0
            while pos + 8 <= size:
                fh.seek(pos)
                head = fh.read(16)
                n, kind = int.from_bytes(head[:4], "big"), head[4:8]
                if kind == b"moov":
                    return False
                if n == 1 and len(head) == 16:
                    n = int.from_bytes(head[8:16], "big")
                if n < 8:
                    break
                pos += n
            return True
    except OSError:
        return False


def _ffmpeg_reason(exc: Exception) -> str:
    text = getattr(exc, "strerror", None) or str(exc)
    return " ".join(str(text).split())[:120]


def _rotation_of(frame: av.VideoFrame) -> int:
    try:
        rot = frame.rotation
    except Exception:  # pragma: no cover - very old PyAV
        return 0
    return round(rot / 90.0) * 90 % 360 if rot else 0


def _apply_rotation(image: np.ndarray, rotation: int) -> np.ndarray:
    """Turn a decoded image into display orientation (``rotation`` degrees counter-clockwise)."""
    k = (rotation // 90) % 4
    return np.ascontiguousarray(np.rot90(image, k)) if k else image


def _rotate_i420(img: np.ndarray, rotation: int) -> np.ndarray:
    k = (rotation // 90) % 4
    if not k:
        return img
    h = img.shape[0] * 2 // 3
    w = img.shape[1]
    flat = img.reshape(-1)
    y = flat[: w * h].reshape(h, w)
    u = flat[w * h : w * h + (w // 2) * (h // 2)].reshape(h // 2, w // 2)
    v = flat[w * h + (w // 2) * (h // 2) :].reshape(h // 2, w // 2)
    y, u, v = (np.rot90(p, k) for p in (y, u, v))
    out = np.empty((y.shape[0] * 3 // 2, y.shape[1]), np.uint8)
    o = out.reshape(-1)
    o[: y.size] = y.ravel()
    o[y.size : y.size + u.size] = u.ravel()
    o[y.size + u.size :] = v.ravel()
    return out


def probe(path: str | os.PathLike, *, allow_truncated: bool = False) -> VideoInfo:
    """Open ``path``, decode its first frame, check its end, and describe the video.

    Raises :class:`EgovidError` for a missing, empty, corrupt or frameless file, and for a
    truncated one (its last frames are missing although the container lists them) unless
    ``allow_truncated``: then ``frame_count`` is the number of frames really there, and
    :func:`iter_frames` and :func:`count_frames` stop quietly after them for the rest of the
    process.

    A file probed again unchanged (same inode, size, modification and change times) gives the
    remembered answer without opening it: one job probes its input several times (~0.1 s each).
    """
    try:
        st = os.stat(path)
        real = Path(path).resolve()
        key = (real, st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
        key += (allow_truncated, real in _TRUNCATED_OK)
    except OSError:
        key = None  # _open() says what is wrong
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
    container = _open(path)
    try:
        stream = container.streams.video[0]
        rate = stream.average_rate or stream.guessed_rate or stream.base_rate
        fps = float(rate) if rate else 0.0
        first = None
        try:
            first = next(iter(container.decode(stream)), None)
        except av.error.FFmpegError as exc:
            raise EgovidError(f"{path} does not decode ({_ffmpeg_reason(exc)})", _FIX_VIDEO) from None
        if first is None:
            raise EgovidError(f"video {path} has no frames", _FIX_VIDEO)
        rotation = _rotation_of(first)
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
            if not allow_truncated and Path(path).resolve() not in _TRUNCATED_OK:
                raise EgovidError(
                    f"{path} is truncated: it holds {real} frames ({real_s:.1f} s) of the {claimed} "
                    "its container lists",
                    f"copy the file again, or pass --allow-truncated to process the {real} frames there are",
                )
            _TRUNCATED_OK[Path(path).resolve()] = real
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


def _packet_cut(packet: av.Packet, size: int) -> bool:
    """True for a packet whose data the file does not hold in full (the file ends inside it)."""
    return bool(packet.is_corrupt) or (packet.pos is not None and packet.pos >= 0 and packet.pos + packet.size > size)


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
            if _packet_cut(packet, size):
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
                if _packet_cut(packet, size):
                    break
                n += 1
                if packet.pts is not None:
                    last = max(last, float((packet.pts - start + (packet.duration or 0)) * stream.time_base))
        except av.error.FFmpegError:
            pass
    return n, last


def _decoded(container: av.container.InputContainer, stream: av.video.VideoStream, path: str | os.PathLike):
    """Decode ``stream``; for a truncated file the caller accepted, stop at the cut and flush."""
    accepted = Path(path).resolve() in _TRUNCATED_OK
    if not accepted:
        yield from container.decode(stream)
        return
    size = Path(path).stat().st_size
    try:
        for packet in container.demux(stream):
            if packet.size and _packet_cut(packet, size):
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
    container = _open(path)
    try:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        rate = float(stream.average_rate or stream.guessed_rate or 30)
        nominal = 1.0 / rate if rate > 0 else 1.0 / 30
        tb = float(stream.time_base) if stream.time_base else None
        reorder = _Reorder(_REORDER_DEPTH)
        state = {"t0": None, "prev": None, "index": 0}

        def emit(item) -> Frame:
            t, img = item
            if state["t0"] is None:
                state["t0"] = t
            t -= state["t0"]
            if state["prev"] is not None and t <= state["prev"]:
                t = state["prev"] + nominal
            state["prev"] = t
            frame = Frame(state["index"], t, img)
            state["index"] += 1
            return frame

        decoded = 0
        try:
            for frame in _decoded(container, stream, path):
                rotation = _rotation_of(frame)
                if scale is not None and scale != 1.0:
                    sw = max(2, round(frame.width * scale))
                    sh = max(2, round(frame.height * scale))
                    img = frame.to_ndarray(format=_pixel_format(gray, i420), width=sw, height=sh, interpolation="AREA")
                else:
                    img = frame.to_ndarray(format=_pixel_format(gray, i420))
                img = _rotate_i420(img, rotation) if i420 else _apply_rotation(img, rotation)
                pts = frame.pts if frame.pts is not None else frame.dts
                t = float(pts * tb) if (pts is not None and tb) else decoded * nominal
                decoded += 1
                for item in reorder.push(t, img):
                    yield emit(item)
                    if max_frames is not None and state["index"] >= max_frames:
                        return
        except av.error.FFmpegError as exc:
            raise EgovidError(
                f"{path} stops decoding at frame {decoded} ({_ffmpeg_reason(exc)})",
                "the file is corrupt or truncated; re-export or repair it",
            ) from None
        for item in reorder.flush():
            yield emit(item)
            if max_frames is not None and state["index"] >= max_frames:
                return
        if state["index"] == 0:
            raise EgovidError(f"video {path} has no frames", _FIX_VIDEO)
    finally:
        container.close()


#: Frames held back to put a decoder's output into presentation order.
_REORDER_DEPTH = 4


def _pixel_format(gray: bool, i420: bool) -> str:
    """PyAV pixel format of :func:`iter_frames`' options."""
    return "yuv420p" if i420 else ("gray" if gray else "bgr24")


class _Reorder:
    """A small min-heap on presentation time: frames leave in time order, ``depth`` behind."""

    def __init__(self, depth: int) -> None:
        self.depth = depth
        self.heap: list = []
        self.seq = 0

    def push(self, t: float, img: np.ndarray):
        import heapq

        heapq.heappush(self.heap, (t, self.seq, img))
        self.seq += 1
        while len(self.heap) > self.depth:
            t, _, img = heapq.heappop(self.heap)
            yield t, img

    def flush(self):
        import heapq

        while self.heap:
            t, _, img = heapq.heappop(self.heap)
            yield t, img


def frame_times(path: str | os.PathLike) -> np.ndarray:
    """Presentation times (N,) in seconds of every frame, from the first, without decoding
    (demuxing only; sorted, so B-frames are in presentation order; repeated or backward times
    follow :func:`iter_frames`' rule)."""
    container = _open(path)
    try:
        stream = container.streams.video[0]
        rate = float(stream.average_rate or stream.guessed_rate or 30)
        nominal = 1.0 / rate if rate > 0 else 1.0 / 30
        tb = float(stream.time_base) if stream.time_base else nominal
        pts = []
        cut = Path(path).resolve() in _TRUNCATED_OK  # a truncated file the caller accepted
        size = Path(path).stat().st_size
        for packet in container.demux(stream):
            if packet.size == 0:
                continue
            if cut and _packet_cut(packet, size):
                break
            p = packet.pts if packet.pts is not None else packet.dts
            pts.append(len(pts) * nominal / tb if p is None else p)
    except av.error.FFmpegError as exc:
        raise EgovidError(f"{path} cannot be read ({_ffmpeg_reason(exc)})", _FIX_VIDEO) from None
    finally:
        container.close()
    t = np.sort(np.asarray(pts, float)) * tb
    if len(t) == 0:
        raise EgovidError(f"video {path} has no frames", _FIX_VIDEO)
    t -= t[0]
    for k in range(1, len(t)):
        if t[k] <= t[k - 1]:
            t[k] = t[k - 1] + nominal
    return t


def read_frames(path: str | os.PathLike, **kwargs) -> tuple[np.ndarray, np.ndarray]:
    """Decode a short video completely: ``(images (N,H,W[,3]) uint8, times (N,) seconds)``.

    Only for clips that fit in memory (tests, synthetic content); long videos use
    :func:`iter_frames`.
    """
    frames = list(iter_frames(path, **kwargs))
    return np.stack([f.image for f in frames]), np.array([f.time for f in frames])


def count_frames(path: str | os.PathLike) -> int:
    """Exact number of decodable frames (demuxes and decodes; no colour conversion)."""
    container = _open(path)
    try:
        n = 0
        for _ in _decoded(container, container.streams.video[0], path):
            n += 1
        return n
    except av.error.FFmpegError as exc:
        raise EgovidError(f"{path} stops decoding at frame {n} ({_ffmpeg_reason(exc)})", _FIX_VIDEO) from None
    finally:
        container.close()


def _fps_fraction(fps: float) -> Fraction:
    common = {23.976: Fraction(24000, 1001), 29.97: Fraction(30000, 1001), 59.94: Fraction(60000, 1001)}
    for k, v in common.items():
        if abs(fps - k) < 1e-3:
            return v
    return Fraction(fps).limit_denominator(1001)


def _bgr_to_i420(image: np.ndarray, colour: ColourTags) -> np.ndarray:
    """BGR uint8 -> one (H*3/2, W) I420 array with the Y'CbCr matrix and range of ``colour``
    (BT.601 limited range where the tags do not say, as FFmpeg assumes)."""
    kr_kb = _KR_KB.get(colour.matrix or "")
    if kr_kb is None and not colour.full_range:
        # OpenCV's BT.601 limited-range conversion matches swscale's to ±1 and is ~10x faster.
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2YUV_I420)
    kr, kb = kr_kb or (0.299, 0.114)
    kg = 1.0 - kr - kb
    ys, cs, off = (255.0, 255.0, 0.0) if colour.full_range else (219.0, 224.0, 16.0)
    y = np.array([kb, kg, kr]) * ys / 255.0
    cb = (np.array([1.0, 0.0, 0.0]) - np.array([kb, kg, kr])) / (2 * (1 - kb)) * cs / 255.0
    cr = (np.array([0.0, 0.0, 1.0]) - np.array([kb, kg, kr])) / (2 * (1 - kr)) * cs / 255.0
    m = np.array([[*y, off], [*cb, 128.0], [*cr, 128.0]], np.float32)
    ycc = cv2.transform(np.ascontiguousarray(image), m)  # uint8, rounded and saturated
    h, w = image.shape[:2]
    out = np.empty((h * 3 // 2, w), np.uint8)
    out[:h] = ycc[..., 0]
    half = cv2.resize(ycc, (w // 2, h // 2), interpolation=cv2.INTER_AREA)  # 2x2 means
    flat = out[h:].reshape(-1)
    flat[: half.shape[0] * half.shape[1]] = half[..., 1].ravel()
    flat[half.shape[0] * half.shape[1] :] = half[..., 2].ravel()
    return out


def _rotate_back(image: np.ndarray, rotation: int, i420: bool) -> np.ndarray:
    """Display orientation -> the coded orientation of a video whose rotation flag is ``rotation``."""
    return _rotate_i420(image, -rotation) if i420 else _apply_rotation(image, -rotation)


class VideoWriter:
    """Encode frames to ``path``, atomically.

    Frames go to a hidden temporary file in the target's folder; :meth:`close` (or leaving the
    ``with`` block normally) renames it to ``path``. An exception inside the ``with`` block, or
    :meth:`abort`, deletes the temporary file and leaves ``path`` untouched.

    ``width``, ``height`` and the frames given to :meth:`write` / :meth:`write_i420` are in display
    orientation (as :func:`iter_frames` yields them).

    Parameters
    ----------
    codec:
        ``libx264`` (default, MP4), ``ffv1`` (lossless, use an ``.mkv`` path), ``libvpx-vp9``...
    crf:
        Constant rate factor for x264/VP9 (lower = better quality).
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
        and was not carried over.
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
        if src_info is not None:
            colour = src_info.colour if colour is None else colour
            rotation = src_info.rotation if rotation is None else rotation
        self.colour = colour or ColourTags()
        self.rotation = int(rotation or 0) % 360
        if self.rotation % 90:
            raise EgovidError(f"rotation {rotation}° is not a multiple of 90", "use 0, 90, 180 or 270")
        self.kept: list[str] = []
        self.dropped: list[str] = []
        self.width, self.height = int(width), int(height)
        coded_w, coded_h = (self.height, self.width) if self.rotation in (90, 270) else (self.width, self.height)
        self.fps = float(fps)
        self._tmp = track_temp(temp_sibling(self.path))
        mov = self.path.suffix.lower() in (".mp4", ".mov", ".m4v")
        # MP4/MOV keep only standard metadata keys unless told to write the others (e.g. firmware).
        muxer_opts = {"movflags": "use_metadata_tags"} if keep_from is not None and mov else {}
        self._container = av.open(str(self._tmp), mode="w", options=muxer_opts)
        rate = _fps_fraction(fps)
        self._stream = self._container.add_stream(codec, rate=rate)
        self._stream.width = coded_w
        self._stream.height = coded_h
        if pix_fmt is None:
            pix_fmt = "bgr0" if codec == "ffv1" else "yuv420p"
            if pix_fmt == "yuv420p" and (self.width % 2 or self.height % 2):
                pix_fmt = "yuv444p"
        self._stream.pix_fmt = pix_fmt
        self._i420 = pix_fmt == "yuv420p"
        if self._i420:
            self.colour.apply(self._stream.codec_context)
        if self.rotation:
            self._stream.set_display_rotation(self.rotation)
        # A fine time base keeps variable frame timing exactly (1/rate would round it).
        # Frames are stamped in this time base, kept here: a muxer may change the *stream's* time base
        # when it writes the header at the first packet (Matroska: 1/1000), after an encoder with a
        # frame delay has already taken frames (libx264 in .mkv came out at t = 0, 0.05, 4.501, ...).
        self._tb = Fraction(1, 90000)
        self._stream.time_base = self._tb
        self._stream.codec_context.time_base = self._tb
        opts: dict[str, str] = {}
        if crf is not None and codec in ("libx264", "libx265", "libvpx-vp9", "libvpx"):
            opts["crf"] = str(crf)
        if preset is not None and codec in ("libx264", "libx265"):
            opts["preset"] = preset
        if codec == "libvpx-vp9":
            opts.setdefault("b", "0")
        if options:
            opts.update(options)
        self._stream.options = opts
        if threads:
            self._stream.codec_context.thread_count = threads
        if thread_type is not None:
            self._stream.codec_context.thread_type = thread_type
        self._count = 0
        self._last_pts = -1
        self._passthrough: _Passthrough | None = None
        self._closed = False
        try:
            if src_info is not None:
                self._keep(keep_from, src_info)
            else:
                if metadata_from is not None:
                    self._copy_metadata(metadata_from)
                if audio_from is not None:
                    self._passthrough = _Passthrough(audio_from, self._container, data=False)
        except BaseException:
            self.abort()
            raise

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
        self._passthrough = _Passthrough(source, self._container, data=True)
        self.kept += self._passthrough.kept
        self.dropped += self._passthrough.dropped

    @property
    def container(self) -> av.container.OutputContainer:
        """The output container, for a caller adding streams of its own (before the first frame)."""
        return self._container

    @property
    def frames_written(self) -> int:
        """Number of frames written so far."""
        return self._count

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
        """Append one HxWx3 BGR uint8 frame shown at ``time`` seconds (default: index / fps)."""
        if image.shape[:2] != (self.height, self.width):
            raise EgovidError(
                f"frame of size {image.shape[1]}x{image.shape[0]} does not match the video's "
                f"{self.width}x{self.height}",
                "resize frames before writing",
            )
        pts, time = self._next_pts(time)
        if self._i420:
            yuv = _rotate_back(_bgr_to_i420(image, self.colour), self.rotation, True)
            frame = av.VideoFrame.from_ndarray(yuv, format="yuv420p")
        else:
            frame = av.VideoFrame.from_ndarray(
                np.ascontiguousarray(_rotate_back(image, self.rotation, False)), format="bgr24"
            )
        self._encode(frame, pts, time)

    def write_i420(self, frame: np.ndarray, time: float | None = None) -> None:
        """Append one I420 frame ((h*3/2, w) uint8, as decoded) without any colour conversion, so a
        lossless codec (FFV1, or x264 at ``options={'qp': '0'}``) stores it bit for bit; the
        planes are read with the writer's :attr:`colour` tags (e.g. full range)."""
        if frame.shape != (self.height * 3 // 2, self.width) or not self._i420:
            raise EgovidError("I420 frames need a yuv420p writer of the same size", "check the frame size")
        pts, time = self._next_pts(time)
        yuv = np.ascontiguousarray(_rotate_back(frame, self.rotation, True))
        self._encode(av.VideoFrame.from_ndarray(yuv, format="yuv420p"), pts, time)

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


def _muxable(stream: av.stream.Stream, fmt: str, packet: av.Packet | None) -> bool:
    """Whether a container of format ``fmt`` can carry a copy of ``stream`` (tried in memory)."""
    import io

    buf = io.BytesIO()
    try:
        with av.open(buf, "w", format=fmt) as out:
            o = out.add_stream_from_template(stream)
            if packet is not None:
                packet.stream = o
                out.mux(packet)
        return True
    except Exception:
        return False


class _Passthrough:
    """Copies the audio (and, with ``data=True``, the data) packets of a source file into an output
    container, interleaved by time and shifted by the source video's start time."""

    def __init__(self, source: str | os.PathLike, out: av.container.OutputContainer, *, data: bool) -> None:
        self.kept: list[str] = []
        self.dropped: list[str] = []
        self._src = av.open(str(source))
        self._out = out
        self._map: dict[int, av.stream.Stream] = {}
        fmt = out.format.name.split(",")[0]
        for s in self._src.streams:
            if s.type == "audio":
                self._map[s.index] = out.add_stream_from_template(s)
                self.kept.append(f"audio ({s.codec_context.name})")
            elif s.type == "data" and data:
                what = (s.metadata.get("handler_name") or "").strip() or getattr(s, "name", None) or "data"
                first = next((p for p in self._src.demux(s) if p.size), None)
                self._src.seek(0)
                if first is not None and _muxable(s, fmt, first):
                    o = out.add_stream_from_template(s)
                    for k, v in s.metadata.items():
                        o.metadata[k] = v
                    self._map[s.index] = o
                    self.kept.append(f"data stream {what!r}")
                elif not s.metadata.get("timecode"):  # a timecode track is rewritten from the video's tag
                    self.dropped.append(f"data stream {what!r} ({fmt} cannot carry it)" if first else f"empty {what!r}")
        streams = [s for s in self._src.streams if s.index in self._map]
        self._packets = self._src.demux(*streams) if streams else iter(())
        self._pending: av.Packet | None = None
        self._done = not streams
        self._t0 = 0.0
        vs = self._src.streams.video
        if vs and vs[0].start_time is not None and vs[0].time_base is not None:
            self._t0 = float(vs[0].start_time * vs[0].time_base)

    def feed_until(self, t: float) -> None:
        """Mux source packets up to ``t`` + 0.5 seconds (output time)."""
        while not self._done:
            pkt = self._pending
            self._pending = None
            if pkt is None:
                try:
                    pkt = next(self._packets)
                except StopIteration:
                    self._done = True
                    return
            if (pkt.dts is None and pkt.pts is None) or pkt.stream.index not in self._map:
                continue
            pts = pkt.pts if pkt.pts is not None else pkt.dts
            if float(pts * pkt.time_base) - self._t0 > t + 0.5:
                self._pending = pkt
                return
            shift = round(self._t0 / pkt.time_base)
            if shift:
                if pkt.pts is not None:
                    pkt.pts -= shift
                if pkt.dts is not None:
                    pkt.dts -= shift
            pkt.stream = self._map[pkt.stream.index]
            self._out.mux(pkt)

    def close(self) -> None:
        self._src.close()
