"""``gyro:VIDEO`` — a real video whose own embedded gyro is the reference orientation.

No dataset and no motion capture: the camera's gyroscope (GoPro GPMF, Sony, Insta360, DJI,
read by telemetry-parser) is integrated into per-frame orientations. The gyro and the picture are
lined up by the fpv motion code (:func:`egovid.core.motion.source.camera_motion`, the one sync of the
project): the time offset (correlation of angular speeds), the IMU-to-camera axes (a signed
permutation, or the least-squares rotation), a constant gyro bias and the focal length (the slope
of vision's rotations on the gyro's) are estimated against egovid's own vision estimate; the
reference rotations themselves are the gyro's, not vision's. Where the camera stabilised the
picture electronically and records the picture's orientation (GoPro CORI), that orientation is
the reference instead (the body gyro does not describe a stabilised picture).

Vision fixes only the time offset, the axis mapping and the focal length (the focal length is
the same for every odometer). The gyro bias is NOT taken from vision: the sync's bias is fitted to
egovid's own estimate, and removing it made the reference favour the ``egovid`` odometer (on the
GoPro Karma clip its margin over the next odometer was 6x with that bias, 1.9x without). The bias
comes from the clip's still parts instead (:func:`still_bias`: windows where the camera is at
rest, the gyro showing only its noise); a clip that never rests keeps its bias in the reference,
which then drifts by that rate for every odometer alike (docs/voeval.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.telemetry import read_camera_telemetry
from egovid.core.errors import EgovidError
from egovid.core.motion import gyro as gyro_mod
from egovid.core.motion.source import CameraMotion, camera_motion
from egovid.core.trajectory import Trajectory
from egovid.core.video import iter_frames, probe
from egovid.voeval.scenes import SceneTruth, lossless_writer

#: Motion sources whose trajectory is a camera's own sensor (not vision).
_SENSOR_SOURCES = ("gyro", "camera-orientation")
#: A camera at rest: in a window of STILL_WINDOW_S seconds no gyro axis varies by more than
#: STILL_STD_DEG_S (standard deviation, degrees per second: sensor noise, no hand or motor shake);
#: a bias needs at least MIN_STILL_S seconds of such windows.
STILL_WINDOW_S, STILL_STD_DEG_S, MIN_STILL_S = 0.5, 0.5, 1.0


def still_bias(times: np.ndarray, gyro: np.ndarray) -> tuple[np.ndarray, float]:
    """Gyro bias (3,) rad/s from the parts of a recording where the camera is at rest: the mean
    rate over the ``STILL_WINDOW_S`` windows whose per-axis standard deviation is below
    ``STILL_STD_DEG_S``; zero when those windows add up to less than ``MIN_STILL_S``. ``times``
    (N,) seconds, ``gyro`` (N, 3) rad/s. Returns (bias, seconds at rest).

    A perfectly smooth constant-rate pan also passes the test and would be read as bias; a
    camera held by hand, on a vehicle or a drone never does (its shake is far above 0.5°/s)."""
    times, gyro = np.asarray(times, float), np.asarray(gyro, float)
    if len(times) < 2:
        return np.zeros(3), 0.0
    window = np.floor((times - times[0]) / STILL_WINDOW_S).astype(int)
    still = np.zeros(len(times), bool)
    for k in np.unique(window):
        m = window == k
        if m.sum() >= 5 and np.all(np.degrees(gyro[m].std(axis=0)) < STILL_STD_DEG_S):
            still |= m
    seconds = float(np.sum(np.diff(times)[still[1:]]))
    if seconds < MIN_STILL_S:
        return np.zeros(3), seconds
    return gyro[still].mean(axis=0), seconds


def check_gyro_video(path: Path) -> None:
    """Raise :class:`EgovidError` unless ``path`` is a video with an embedded gyro."""
    probe(path)
    if not read_camera_telemetry(path).has_gyro:
        raise EgovidError(
            f"{path} has no embedded gyro that telemetry-parser can read",
            "give a GoPro, Sony, Insta360 or DJI video with gyro telemetry, or use another --sequence format",
        )


def import_gyro_sequence(spec, video: Path, max_frames: int | None = None) -> SceneTruth:
    """Store the first ``max_frames`` frames of the video of ``spec`` (a :class:`SequenceSpec`
    of format ``gyro``) as a lossless video at ``video``; return their reference (the synced,
    integrated gyro, frame 0 = identity; no positions) with the fitted camera. Raises
    :class:`EgovidError` when the gyro does not match the picture (sync correlation below the
    trusted level)."""
    motion = camera_motion(spec.path, "auto")
    if motion.source not in _SENSOR_SOURCES:
        raise EgovidError(
            f"{spec.path}: the camera's gyro cannot serve as the reference ({motion.reason})",
            "use a video whose gyro describes the picture (no electronic stabilisation, or one that records "
            "the image orientation), or another --sequence format",
        )
    traj, bias_meta = _reference(motion)
    n = len(traj) if max_frames is None else min(len(traj), max_frames)
    intr = motion.camera.intrinsics
    w, h = intr.width - intr.width % 2, intr.height - intr.height % 2
    times = np.asarray(traj.times[:n], float) - float(traj.times[0])
    fps = 1.0 / float(np.median(np.diff(times)))
    _store_frames(spec.path, video, times, w, h, fps)
    R = traj.R[:n]
    R = np.swapaxes(R[0], -1, -2)[None] @ R
    meta = {**_meta(spec, motion, traj, n), **bias_meta}
    scene_intr = Intrinsics(w, h, intr.fx, intr.fy, intr.cx, intr.cy)
    return SceneTruth(spec.name, R, scene_intr, fps, times=times, meta=meta)


def _reference(motion: CameraMotion) -> tuple[Trajectory, dict]:
    """The reference trajectory of a synced clip and what its bias was: for a body gyro, the gyro
    integrated again with the bias of its still parts (not vision's); a recorded picture
    orientation as it is."""
    traj = motion.trajectory
    if motion.source != "gyro":
        return traj, {}
    imu = motion.telemetry.imu
    bias, still_s = still_bias(imu.times, imu.gyro)
    track = gyro_mod.integrate(imu, bias=bias)
    traj = Trajectory(traj.times, gyro_mod.frame_rotations(track, motion.sync, traj.times))
    return traj, {
        "reference_bias": {
            "from": "still parts" if still_s >= MIN_STILL_S else "none (the camera never rests)",
            "deg_s": np.degrees(bias).round(4).tolist(),
            "still_seconds": round(still_s, 2),
            "vision_fitted_deg_s": np.degrees(motion.sync.bias).round(4).tolist(),
        }
    }


def _store_frames(source: Path, video: Path, times: np.ndarray, w: int, h: int, fps: float) -> None:
    """The first ``len(times)`` frames of ``source``, cropped to ``w`` x ``h``, losslessly at ``video``."""
    n, written = len(times), 0
    with lossless_writer(video, w, h, fps) as wr:
        for f in iter_frames(source, max_frames=n):
            wr.write(f.image[:h, :w], float(times[written]))
            written += 1
    if written != n:
        raise EgovidError(f"{source} decoded {written} frames, its motion has {n}", "the video is damaged")


def _meta(spec, motion: CameraMotion, traj: Trajectory, n: int) -> dict:
    """The scene description of a gyro sequence: where the reference came from and how it was synced."""
    return {
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
