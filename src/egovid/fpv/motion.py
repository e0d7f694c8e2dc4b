"""The camera rotation of every frame, written out: ``egovid fpv motion`` as one function.

:func:`save_motion` estimates the camera motion of a video from the source asked for
(:func:`egovid.core.motion.source.camera_motion`) and writes the motion CSV
(frame,time,yaw,pitch,roll in degrees,confidence), a TUM trajectory, a summary JSON (source and
why, intrinsics and their source, gyro sync) and, when asked, a plot of yaw, pitch and roll beside
the other sources that ran.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from egovid.core.files import atomic_write_text
from egovid.core.motion import gyro as gyro_mod
from egovid.core.motion.estimate import MotionOptions
from egovid.core.motion.source import CameraMotion, camera_motion
from egovid.core.plots import plot_angles
from egovid.core.trajectory import Trajectory, write_motion_csv, write_tum

__all__ = ["MotionOptions", "motion_curves", "save_motion", "sidecar_paths"]


def sidecar_paths(csv: str | os.PathLike) -> tuple[Path, Path]:
    """Where the summary JSON and the TUM file of a motion CSV go by default: next to it,
    ``<stem>.json`` and ``<stem>.tum``."""
    p = Path(csv)
    return p.parent / (p.stem + ".json"), p.parent / (p.stem + ".tum")


def save_motion(
    video: str | os.PathLike,
    csv: str | os.PathLike,
    *,
    json_out: str | os.PathLike | None = None,
    tum: str | os.PathLike | None = None,
    plot: str | os.PathLike | None = None,
    source: str = "auto",
    focal: float | None = None,
    hfov: float | None = None,
    options: MotionOptions | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> CameraMotion:
    """Estimate the camera motion of ``video`` and write it: the CSV ``csv``, the JSON ``json_out``
    and TUM file ``tum`` (default :func:`sidecar_paths`), and the PNG ``plot`` when given.

    ``source``, ``focal`` (pixels), ``hfov`` (degrees), ``options`` and ``progress(stage, done,
    total)`` go to :func:`~egovid.core.motion.source.camera_motion`."""
    default_json, default_tum = sidecar_paths(csv)
    cm = camera_motion(video, source, focal=focal, hfov=hfov, options=options, progress=progress)
    write_motion_csv(csv, cm.trajectory, cm.confidence)
    write_tum(tum or default_tum, cm.trajectory)
    doc = {"input": str(video), **cm.to_dict()}
    atomic_write_text(json_out or default_json, json.dumps(doc, indent=1))
    if plot is not None:
        plot_angles(plot, cm.trajectory.times, motion_curves(cm), f"Camera rotation of {Path(video).name}")
    return cm


def motion_curves(cm: CameraMotion) -> dict[str, np.ndarray]:
    """(N, 3) yaw, pitch, roll in degrees at the frame times of every source that ran: the one
    used, and vision and the synced gyro beside it where they ran too."""
    curves = {cm.source: cm.trajectory.euler()}
    if cm.vision is not None and cm.source != "vision":
        curves["vision"] = cm.vision.trajectory.euler()
    if cm.sync is not None and cm.vision is not None and cm.source != "gyro" and cm.telemetry.has_gyro:
        R = gyro_mod.frame_rotations(
            gyro_mod.integrate(cm.telemetry.imu, bias=cm.sync.bias), cm.sync, cm.trajectory.times
        )
        curves["gyro"] = Trajectory(cm.trajectory.times, R).euler()
    return curves
