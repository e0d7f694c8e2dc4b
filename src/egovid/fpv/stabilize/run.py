"""``egovid fpv stabilize`` as one function: the camera and its motion resolved the way every fpv
command resolves them, the stabiliser run (:func:`egovid.fpv.stabilize.pipeline.stabilize`), and
the outputs asked for written (the input and rendered motion CSVs, the JSON summary, the HTML
report)."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from egovid.core.camera.resolve import resolve_camera
from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_text
from egovid.core.motion import gyro as gyro_mod
from egovid.core.motion.source import CameraMotion, camera_motion
from egovid.core.trajectory import Trajectory, read_motion_csv, write_motion_csv
from egovid.core.video import count_frames, probe
from egovid.fpv.stabilize.horizon import down_from_accelerometer
from egovid.fpv.stabilize.optimize import OptimizeOptions, kernels_loading
from egovid.fpv.stabilize.pipeline import StabilizeResult, check_options, stabilize
from egovid.fpv.stabilize.report import write_report

__all__ = ["check_options", "gravity_down", "saved_motion_paths", "stabilize_video"]


def saved_motion_paths(prefix: str | os.PathLike) -> tuple[Path, Path]:
    """Where ``--save-motion PREFIX`` writes the input and the rendered motion CSVs:
    ``PREFIX.input.csv`` and ``PREFIX.output.csv``."""
    p = Path(prefix)
    return p.with_name(p.name + ".input.csv"), p.with_name(p.name + ".output.csv")


def stabilize_video(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    *,
    source: str = "auto",
    focal: float | None = None,
    hfov: float | None = None,
    motion: str | os.PathLike | Trajectory | None = None,
    strength: float = 1.0,
    borders: str = "crop",
    max_zoom: float = 1.10,
    keep_roll: bool = False,
    method: str = "ve",
    anchor_threshold: float = 0.5,
    crf: int = 18,
    bit_depth: str = "auto",
    measure: bool = True,
    visible: bool = True,
    horizon_lock: bool = False,
    readout_ms: float | None = None,
    save_motion: str | os.PathLike | None = None,
    json_out: str | os.PathLike | None = None,
    report: str | os.PathLike | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> StabilizeResult:
    """Stabilise ``src`` into ``dst`` keeping its intentional motion.

    The camera motion comes from ``motion``, a motion CSV or a trajectory (one row per frame,
    with the file's intrinsics or ``focal`` pixels / ``hfov`` degrees), else from ``source`` (see
    :func:`~egovid.core.motion.source.camera_motion`). ``strength``, ``borders``, ``max_zoom``,
    ``keep_roll``, ``method``, ``anchor_threshold`` (degrees), ``crf``, ``bit_depth``, ``measure``,
    ``visible`` and ``horizon_lock`` go to :func:`~egovid.fpv.stabilize.pipeline.stabilize`; the horizon is
    levelled against the accelerometer's gravity where the motion came from a synced gyro that
    logged one, else against the path's mean down axis. Writes the motion CSVs of
    :func:`saved_motion_paths` (``save_motion``), the deterministic JSON summary (``json_out``) and
    the HTML report (``report``) when given. Frames are warped through the camera's lens
    (:attr:`~egovid.core.camera.resolve.CameraModel.lens`: a GoPro's fisheye modes) and, where the
    frame readout time is known (``readout_ms`` milliseconds, else the file's GoPro ``SROT`` or the
    lens profile's: :attr:`~egovid.core.camera.resolve.CameraModel.readout_ms`; 0 turns it off),
    every row band from the orientation of its own readout time (rolling shutter).
    ``progress(stage, done, total)`` reports the stages.
    """
    fps = probe(src).fps
    traj = motion if isinstance(motion, Trajectory) or motion is None else _motion_of(src, motion)
    cm = None
    if traj is None:  # the motion source resolves the camera itself (one ExifTool run per job)
        with kernels_loading():  # the planner's compiled objective, ~0.5 s, beside the motion stage
            cm = camera_motion(src, source, focal=focal, hfov=hfov, progress=progress)
        traj, camera = cm.trajectory, cm.camera
    else:
        camera = resolve_camera(src, focal, hfov)
    intr = camera.intrinsics
    res = stabilize(
        src,
        dst,
        intrinsics=intr,
        motion=traj,
        strength=strength,
        borders=borders,
        max_zoom=max_zoom,
        keep_roll=keep_roll,
        method=method,
        opts=OptimizeOptions(anchor_threshold=anchor_threshold, method=method),
        crf=crf,
        bit_depth=bit_depth,
        measure=measure,
        visible=visible,
        horizon_lock=horizon_lock,
        down_world=gravity_down(cm) if horizon_lock and cm is not None else None,
        lens=camera.lens,
        readout_s=(camera.readout_ms or 0.0) / 1000.0 if readout_ms is None else readout_ms / 1000.0,
        progress=progress,
    )
    res.camera_motion = cm
    if save_motion is not None:
        before, after = saved_motion_paths(save_motion)
        write_motion_csv(before, Trajectory.from_euler(res.times, res.original))
        write_motion_csv(after, Trajectory.from_euler(res.times, res.path))
    if json_out is not None:
        atomic_write_text(json_out, json.dumps(res.summary(), indent=1, default=float))
    if report is not None:
        write_report(report, res, str(src), intr, fps)
    return res


def gravity_down(cm: CameraMotion) -> np.ndarray | None:
    """(3,) the world's down direction in the frame of ``cm``'s trajectory (frame 0 = identity),
    from the accelerometer of its synced gyro (:func:`egovid.fpv.stabilize.horizon.down_from_accelerometer`);
    None without a synced gyro or an accelerometer."""
    imu = cm.telemetry.imu if cm.telemetry is not None else None
    if cm.sync is None or imu is None or imu.accel is None or imu.accel_times is None or len(imu.accel) < 2:
        return None
    track = gyro_mod.integrate(imu, bias=cm.sync.bias)
    t_video = np.asarray(imu.accel_times, float) - cm.sync.offset_s
    inside = (t_video >= cm.trajectory.times[0]) & (t_video <= cm.trajectory.times[-1])
    if inside.sum() < 2:
        return None
    R = gyro_mod.frame_rotations(track, cm.sync, np.concatenate([cm.trajectory.times[:1], t_video[inside]]))[1:]
    accel_cam = np.asarray(imu.accel, float)[inside] @ cm.sync.axes.T
    return down_from_accelerometer(R, accel_cam)


def _motion_of(src: str | os.PathLike, motion: str | os.PathLike) -> Trajectory:
    """The motion CSV ``motion``, refused unless it has one row per frame of ``src``."""
    traj = read_motion_csv(motion)
    if len(traj) != probe(src).frame_count:
        n = count_frames(src)
        if len(traj) != n:
            raise EgovidError(
                f"motion {motion} has {len(traj)} frames but {src} has {n}", "estimate the motion of this video again"
            )
    return traj
