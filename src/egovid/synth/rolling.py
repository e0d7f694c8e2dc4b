"""Synthetic rolling-shutter clips: each image row exposed at its own time, with known readout.

A rolling-shutter sensor reads its rows one after the other: row ``y`` of frame ``k`` (of an
``H``-row picture) is exposed at ``t_k + (y / (H - 1) - 1/2) · readout`` (the middle row at the
frame's time stamp, the top row half a readout earlier; a negative readout reads bottom to
top). :func:`render_rolling_fpv` renders each frame in ``bands`` horizontal bands, each with the
camera orientation at its rows' time (spherical interpolation of the per-frame motion, a
smooth cubic in the Euler angles between frames), so a fast shake shows the wobble and skew a
real action camera shows. The ground truth is the orientation at each frame's time stamp (its
middle row), written beside the video like :func:`egovid.synth.fpv.render_fpv` does.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.rotations import matrix_from_euler
from egovid.core.trajectory import Trajectory, write_motion_csv, write_tum
from egovid.core.video import VideoWriter
from egovid.synth.fpv import SynthResult, ground_truth_paths, scene_panorama
from egovid.synth.render import SphereRenderer


def row_times(height: int, readout_s: float, bands: int) -> np.ndarray:
    """Exposure time offsets (seconds, relative to the frame's time stamp) of the centres of
    ``bands`` equal bands of a ``height``-row picture read out in ``readout_s`` seconds."""
    edges = np.linspace(0, height, bands + 1)
    centre = 0.5 * (edges[:-1] + edges[1:]) - 0.5
    return (centre / (height - 1) - 0.5) * readout_s


def render_rolling_fpv(
    out: str | os.PathLike,
    angles_deg: np.ndarray,
    readout_s: float,
    *,
    width: int = 640,
    height: int = 360,
    fps: float = 30.0,
    intrinsics: Intrinsics | None = None,
    scene: str = "panorama",
    bands: int = 60,
    seed: int = 0,
    crf: int = 16,
) -> SynthResult:
    """Render a rolling-shutter first-person clip of the motion ``angles_deg`` ((N, 3) yaw, pitch,
    roll in degrees at the frame times) with frame readout ``readout_s`` seconds (0: global
    shutter). The ground truth is the orientation at each frame's time stamp."""
    angles = np.asarray(angles_deg, dtype=float)
    if angles.ndim != 2 or angles.shape[1] != 3 or len(angles) < 2:
        raise EgovidError("angles must be an (N, 3) array of yaw, pitch, roll, N >= 2", "check the motion")
    if abs(readout_s) >= 1.0 / fps * 1.5:
        raise EgovidError(f"readout {readout_s:g} s is longer than a frame at {fps:g} fps", "give a shorter readout")
    intr = intrinsics or Intrinsics.default(width, height)
    pano_w = int(np.clip(round(360.0 / intr.hfov_deg * width / 1024.0) * 1024, 2048, 8192))
    renderer = SphereRenderer(scene_panorama(scene, pano_w, seed), intr)
    times = np.arange(len(angles)) / fps
    spline = CubicSpline(times, angles, axis=0, bc_type="natural")
    offsets = row_times(height, readout_s, bands)
    truth = Trajectory.from_euler(times, angles)
    out = Path(out)
    codec = "ffv1" if out.suffix.lower() == ".mkv" else "libx264"
    with VideoWriter(out, width, height, fps, codec=codec, crf=crf, preset="veryfast") as writer:
        for t in times:
            a = spline(np.clip(t + offsets, times[0], times[-1]))
            Rs = [matrix_from_euler(*row) for row in a]
            writer.write(renderer.render_rolling(Rs), t)
    csv_path, tum_path = ground_truth_paths(out)
    write_motion_csv(csv_path, truth)
    write_tum(tum_path, truth)
    return SynthResult(out, csv_path, tum_path, truth)
