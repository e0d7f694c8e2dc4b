"""Opening a video for reading, and the facts about its file every reader shares: why it cannot
be opened, where a cut file ends (a packet the file does not hold in full), and which truncated
files a caller accepted (:func:`egovid.core.video.probe` with ``allow_truncated``)."""

from __future__ import annotations

import mmap
import os
from pathlib import Path

import av

from egovid.core.errors import EgovidError
from egovid.core.video.isobmff import iter_boxes

FIX_VIDEO = "give a video file FFmpeg can decode (e.g. MP4/H.264, MKV, WebM)"
_ACCEPTED_CUTS: set[Path] = set()  # truncated videos a caller accepted (see probe(allow_truncated=True))


def accept_cut(path: str | os.PathLike) -> None:
    """Remember that a caller accepted the truncated video ``path``: from now on, in this process,
    it is read up to its cut (only :func:`egovid.core.video.probe` calls this)."""
    _ACCEPTED_CUTS.add(Path(path).resolve())


def cut_accepted(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a truncated video a caller accepted (read it up to the cut)."""
    return Path(path).resolve() in _ACCEPTED_CUTS


def forget_accepted_cuts() -> None:
    """Forget every accepted truncated video (tests that run several commands in one process)."""
    _ACCEPTED_CUTS.clear()


def open_video(path: str | os.PathLike) -> av.container.InputContainer:
    """Open ``path`` for reading; :class:`EgovidError` naming the problem (missing, a folder, empty,
    an MP4 without its index, not a video, no video stream) and the fix otherwise."""
    p = Path(path)
    if not p.exists():
        raise EgovidError(f"video not found: {p}", "check the path")
    if p.is_dir():
        raise EgovidError(f"{p} is a folder, not a video", FIX_VIDEO)
    if p.stat().st_size == 0:
        raise EgovidError(f"video {p} is empty (0 bytes)", FIX_VIDEO)
    try:
        container = av.open(str(p), mode="r")
    except av.error.FFmpegError as exc:
        if _is_mp4_without_index(p):
            raise EgovidError(
                f"{p} is an MP4/MOV file without its index (moov box): it was cut short while recording or copying",
                "copy it again from the camera, or rebuild the index with a recovery tool such as untrunc",
            ) from None
        raise EgovidError(f"{p} is not a readable video ({ffmpeg_reason(exc)})", FIX_VIDEO) from None
    if not container.streams.video:
        container.close()
        raise EgovidError(f"{p} has no video stream", FIX_VIDEO)
    return container


def _is_mp4_without_index(p: Path) -> bool:
    """An ISO-BMFF file (ftyp box first) whose top-level boxes hold no ``moov``."""
    try:
        with open(p, "rb") as fh:
            if fh.read(12)[4:8] != b"ftyp":
                return False
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return all(kind != "moov" for kind, *_ in iter_boxes(data))
    except (OSError, ValueError):
        return False


def ffmpeg_reason(exc: Exception) -> str:
    """FFmpeg's reason for an error, on one line of at most 120 characters."""
    text = getattr(exc, "strerror", None) or str(exc)
    return " ".join(str(text).split())[:120]


def packet_cut(packet: av.Packet, size: int) -> bool:
    """True for a packet whose data the file does not hold in full (the file ends inside it)."""
    return bool(packet.is_corrupt) or (packet.pos is not None and packet.pos >= 0 and packet.pos + packet.size > size)
