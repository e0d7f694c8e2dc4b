"""Streaming video input and output on PyAV (FFmpeg), one module per job.

* :mod:`~egovid.core.video.probe` — :func:`probe` opens a video, checks that it decodes and that it
  holds the frames its container lists (a file cut short while copying or recording is reported
  with how many frames it really has, unless the caller accepts it with ``allow_truncated``), and
  describes it (:class:`VideoInfo`); :func:`frame_times` gives every frame's time by demuxing.
* :mod:`~egovid.core.video.read` — :func:`iter_frames` decodes frame by frame (never the whole
  video), with the exact frame count, presentation times in seconds, and the container's rotation
  flag applied, so frames come out in display orientation (unlike ``cv2.VideoCapture``, egovid
  reports the flag and the camera intrinsics are those of the rotated frame); :func:`count_frames`.
* :mod:`~egovid.core.video.write` — :class:`VideoWriter` encodes frames to a temporary file next to
  the target and renames it into place only when everything succeeded, so an error or an
  interruption never leaves a half-written video at the target path. Given ``keep_from=`` a
  source video, it keeps what the camera wrote: colour tags (primaries, transfer, matrix, range),
  the rotation flag, creation time and other metadata, the timecode, every audio stream, and the
  data (telemetry) streams the output container can carry (GoPro GPMF ``gpmd`` in MP4/MOV).
* :mod:`~egovid.core.video.colour` (colour tags, BGR -> I420), :mod:`~egovid.core.video.orientation`
  (the rotation flag), :mod:`~egovid.core.video.passthrough` (stream copy) and
  :mod:`~egovid.core.video.container` (opening a file, cut files) serve them.

The names below are the public API; import them from here.
"""

from egovid.core.video.colour import ColourTags
from egovid.core.video.probe import VideoInfo, frame_times, probe
from egovid.core.video.read import Frame, count_frames, iter_frames, read_frames
from egovid.core.video.write import VideoWriter

__all__ = [
    "ColourTags",
    "Frame",
    "VideoInfo",
    "VideoWriter",
    "count_frames",
    "frame_times",
    "iter_frames",
    "probe",
    "read_frames",
]
