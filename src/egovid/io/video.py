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
  half-written video at the target path. It can copy the audio stream of a source video through.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from egovid.errors import EgovidError
from egovid.io.files import commit_temp, temp_sibling, track_temp, untrack_temp

_FIX_VIDEO = "give a video file FFmpeg can decode (e.g. MP4/H.264, MKV, WebM)"
_TRUNCATED_OK: dict[Path, int] = {}  # truncated videos a caller accepted -> frames they really have


@dataclass(frozen=True)
class VideoInfo:
    """What a video is, as needed by the rest of egovid.

    ``width`` and ``height`` are in display orientation (after the rotation flag), in pixels.
    ``frame_count`` is the container's claim (or an estimate from the duration); the exact count
    comes from decoding, see :func:`iter_frames`. ``rotation`` is the container's display rotation
    in degrees counter-clockwise.
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
    """
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
            truncated=truncated is not None,
        )
    finally:
        container.close()


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


class VideoWriter:
    """Encode BGR frames to ``path``, atomically.

    Frames go to a hidden temporary file in the target's folder; :meth:`close` (or leaving the
    ``with`` block normally) renames it to ``path``. An exception inside the ``with`` block, or
    :meth:`abort`, deletes the temporary file and leaves ``path`` untouched.

    Parameters
    ----------
    codec:
        ``libx264`` (default, MP4), ``ffv1`` (lossless, use an ``.mkv`` path), ``libvpx-vp9``...
    crf:
        Constant rate factor for x264/VP9 (lower = better quality).
    audio_from:
        A source video whose audio stream (if any) is copied into the output unchanged,
        interleaved by timestamp.
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
        audio_from: str | os.PathLike | None = None,
        metadata_from: str | os.PathLike | None = None,
        options: dict[str, str] | None = None,
    ) -> None:
        self.path = Path(path)
        if not self.path.parent.exists():
            raise EgovidError(f"output folder {self.path.parent} does not exist", "create it first")
        if fps <= 0 or not np.isfinite(fps):
            raise EgovidError(f"frame rate {fps} is not positive", "give a frame rate such as 30")
        self.width, self.height = int(width), int(height)
        self.fps = float(fps)
        self._tmp = track_temp(temp_sibling(self.path))
        self._container = av.open(str(self._tmp), mode="w")
        rate = _fps_fraction(fps)
        self._stream = self._container.add_stream(codec, rate=rate)
        self._stream.width = self.width
        self._stream.height = self.height
        if pix_fmt is None:
            pix_fmt = "bgr0" if codec == "ffv1" else "yuv420p"
            if pix_fmt == "yuv420p" and (self.width % 2 or self.height % 2):
                pix_fmt = "yuv444p"
        self._stream.pix_fmt = pix_fmt
        self._i420 = pix_fmt == "yuv420p"
        # A fine time base keeps variable frame timing exactly (1/rate would round it).
        self._stream.time_base = Fraction(1, 90000)
        self._stream.codec_context.time_base = Fraction(1, 90000)
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
        self._count = 0
        self._last_pts = -1
        self._audio = None
        self._closed = False
        if metadata_from is not None:
            with contextlib.suppress(Exception), av.open(str(metadata_from)) as src:
                for k, v in src.metadata.items():
                    if k.lower() not in ("encoder", "major_brand", "minor_version", "compatible_brands"):
                        self._container.metadata[k] = v
        if audio_from is not None:
            self._audio = _AudioPassthrough(audio_from, self._container)

    @property
    def frames_written(self) -> int:
        """Number of frames written so far."""
        return self._count

    def write(self, image: np.ndarray, time: float | None = None) -> None:
        """Append one HxWx3 BGR uint8 frame shown at ``time`` seconds (default: index / fps)."""
        if image.shape[:2] != (self.height, self.width):
            raise EgovidError(
                f"frame of size {image.shape[1]}x{image.shape[0]} does not match the video's "
                f"{self.width}x{self.height}",
                "resize frames before writing",
            )
        if time is None:
            time = self._count / self.fps
        tb = self._stream.time_base
        pts = round(time / tb)
        if pts <= self._last_pts:
            pts = self._last_pts + 1
        self._last_pts = pts
        if self._i420:
            # OpenCV's BT.601 limited-range conversion matches swscale's to ±1 and is ~10x faster.
            yuv = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2YUV_I420)
            frame = av.VideoFrame.from_ndarray(yuv, format="yuv420p")
        else:
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="bgr24")
        frame.pts = pts
        frame.time_base = tb
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self._count += 1
        if self._audio is not None:
            self._audio.feed_until(time)

    def write_i420(self, frame: np.ndarray, time: float | None = None) -> None:
        """Append one I420 frame ((h*3/2, w) uint8, as decoded) without any colour conversion, so a
        lossless codec (FFV1, or x264 at ``options={'qp': '0'}``) stores it bit for bit."""
        if frame.shape != (self.height * 3 // 2, self.width) or not self._i420:
            raise EgovidError("I420 frames need a yuv420p writer of the same size", "check the frame size")
        if time is None:
            time = self._count / self.fps
        tb = self._stream.time_base
        pts = max(round(time / tb), self._last_pts + 1)
        self._last_pts = pts
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="yuv420p")
        vf.pts = pts
        vf.time_base = tb
        for packet in self._stream.encode(vf):
            self._container.mux(packet)
        self._count += 1

    def close(self) -> Path:
        """Flush the encoder, finish the file and move it to ``path``."""
        if self._closed:
            return self.path
        try:
            for packet in self._stream.encode():
                self._container.mux(packet)
            if self._audio is not None:
                self._audio.feed_until(float("inf"))
                self._audio.close()
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
            if self._audio is not None:
                self._audio.close()
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


class _AudioPassthrough:
    """Copies the audio packets of a source file into an output container, interleaved by time."""

    def __init__(self, source: str | os.PathLike, out: av.container.OutputContainer) -> None:
        self._src = av.open(str(source))
        self._in = self._src.streams.audio[0] if self._src.streams.audio else None
        self._out_stream = out.add_stream_from_template(self._in) if self._in is not None else None
        self._out = out
        self._packets = self._src.demux(self._in) if self._in is not None else iter(())
        self._pending = None
        self._t0 = None
        vs = self._src.streams.video
        if vs and vs[0].start_time is not None and vs[0].time_base is not None:
            self._t0 = float(vs[0].start_time * vs[0].time_base)

    def feed_until(self, t: float) -> None:
        if self._in is None:
            return
        while True:
            pkt = self._pending
            self._pending = None
            if pkt is None:
                try:
                    pkt = next(self._packets)
                except StopIteration:
                    self._in = None
                    return
            if pkt.dts is None and pkt.pts is None:
                continue
            shift = round((self._t0 or 0.0) / pkt.time_base)
            pts = pkt.pts if pkt.pts is not None else pkt.dts
            if float(pts * pkt.time_base) - (self._t0 or 0.0) > t + 0.5:
                self._pending = pkt
                return
            if shift:
                if pkt.pts is not None:
                    pkt.pts -= shift
                if pkt.dts is not None:
                    pkt.dts -= shift
            pkt.stream = self._out_stream
            self._out.mux(pkt)

    def close(self) -> None:
        self._src.close()
