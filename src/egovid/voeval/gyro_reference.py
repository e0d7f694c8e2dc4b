"""``gyro:VIDEO`` — a real video whose own embedded gyro is the reference orientation.

No dataset and no motion capture: the camera's gyroscope (GoPro GPMF, Sony, Insta360, DJI,
read by telemetry-parser) is integrated into per-frame orientations. The gyro and the picture are
lined up by the fpv motion code (:func:`egovid.motion.source.camera_motion`, the one sync of the
project): the time offset (correlation of angular speeds), the IMU-to-camera axes (a signed
permutation, or the least-squares rotation), a constant gyro bias and the focal length (the slope
of vision's rotations on the gyro's) are estimated against egovid's own vision estimate; the
reference rotations themselves are the gyro's, not vision's. Where the camera stabilised the
picture electronically and records the picture's orientation (GoPro CORI), that orientation is
the reference instead (the body gyro does not describe a stabilised picture).

Vision fixes only these few constants (one offset, one axis mapping, three bias rates, one focal
length), so the reference is not vision's trajectory; but the ``egovid`` odometer is the same
estimator, and a bias or focal length fitted to it favours it slightly (docs/voeval.md measures
how much the sync changed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egovid.errors import EgovidError
from egovid.io.camera import Intrinsics
from egovid.io.video import iter_frames
from egovid.voeval.scenes import SceneTruth, lossless_writer

#: Motion sources whose trajectory is a camera's own sensor (not vision).
_SENSOR_SOURCES = ("gyro", "camera-orientation")


def check_gyro_video(path: Path) -> None:
    """Raise :class:`EgovidError` unless ``path`` is a video with an embedded gyro."""
    from egovid.io.telemetry import read_camera_telemetry
    from egovid.io.video import probe

    probe(path)
    if not read_camera_telemetry(path).has_gyro:
        raise EgovidError(
            f"{path} has no embedded gyro that telemetry-parser can read",
            "give a GoPro, Sony, Insta360 or DJI video with gyro telemetry, or use another --sequence format",
        )


def import_gyro_sequence(spec, video: Path, max_frames: int | None = None) -> SceneTruth:
    """Store the first ``max_frames`` frames of the video of ``spec`` (a :class:`SequenceSpec`
    of format ``gyro``) as a lossless video at ``video``; return their reference (the synced,
    integrated gyro, frame 0 = identity) with the fitted camera. Raises :class:`EgovidError`
    when the gyro does not match the picture (sync correlation below the trusted level)."""
    from egovid.motion.source import camera_motion

    motion = camera_motion(spec.path, "auto")
    if motion.source not in _SENSOR_SOURCES:
        raise EgovidError(
            f"{spec.path}: the camera's gyro cannot serve as the reference ({motion.reason})",
            "use a video whose gyro describes the picture (no electronic stabilisation, or one that records "
            "the image orientation), or another --sequence format",
        )
    traj = motion.trajectory
    n = len(traj) if max_frames is None else min(len(traj), max_frames)
    intr = motion.camera.intrinsics
    w, h = intr.width - intr.width % 2, intr.height - intr.height % 2
    times = np.asarray(traj.times[:n], float) - float(traj.times[0])
    fps = 1.0 / float(np.median(np.diff(times)))
    written = 0
    with lossless_writer(video, w, h, fps) as wr:
        for f in iter_frames(spec.path, max_frames=n):
            wr.write(f.image[:h, :w], float(times[written]))
            written += 1
    if written != n:
        raise EgovidError(f"{spec.path} decoded {written} frames, its motion has {n}", "the video is damaged")
    R = traj.R[:n]
    R = np.swapaxes(R[0], -1, -2)[None] @ R
    meta = {
        "kind": "real",
        "format": "gyro",
        "source": str(spec.path),
        "motion": "general",
        "frames_in_sequence": len(traj),
        "frames_matched": int(np.sum(motion.confidence[:n] > 0)),
        "first_frame": 0,
        "reference": motion.source,
        "reference_reason": motion.reason,
        "reference_rate_hz": motion.to_dict()["camera"]["gyro_rate_hz"],
        "camera": motion.camera.to_dict(),
        "undistorted": False,
        **({"gyro_sync": motion.sync.to_dict()} if motion.sync is not None else {}),
        **({"focal_fit": motion.focal_fit.to_dict()} if motion.focal_fit is not None else {}),
        **({"vision_vs_gyro": motion.comparison.to_dict()} if motion.comparison is not None else {}),
    }
    scene_intr = Intrinsics(w, h, intr.fx, intr.fy, intr.cx, intr.cy)
    return SceneTruth(spec.name, R, scene_intr, fps, times=times, meta=meta)
