"""Synthetic first-person videos with ground truth (thesis §10.1.1, §21.4).

A camera at the centre of a panorama sphere follows a rotation sequence, optionally walking
slowly forward (parallax) with sensor noise. The video is written together with its ground
truth: a motion CSV (frame, time, yaw, pitch, roll in degrees) and a TUM trajectory.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics, resolve_intrinsics
from egovid.core.errors import EgovidError
from egovid.core.trajectory import Trajectory, write_motion_csv, write_tum
from egovid.core.video import VideoWriter
from egovid.synth.motions import MOTIONS, MotionSpec
from egovid.synth.panorama import build_panorama
from egovid.synth.photos import ALL, photo
from egovid.synth.render import SphereRenderer

__all__ = [
    "ALL",
    "MOTIONS",
    "MotionSpec",
    "SynthResult",
    "ground_truth_paths",
    "render_fpv",
    "scene_panorama",
    "synth_fpv",
]


@dataclass
class SynthResult:
    """Paths written by :func:`render_fpv` and the ground truth it used."""

    video: Path
    motion_csv: Path
    tum: Path
    truth: Trajectory


def scene_panorama(scene: str = "panorama", width: int = 4096, seed: int = 0) -> np.ndarray:
    """The equirectangular texture of a scene: the photo mosaic, or one photo tiled around."""
    if scene == "panorama":
        return build_panorama(width, seed)
    if scene not in ALL:
        raise EgovidError(f"unknown scene {scene!r}", f"use 'panorama' or a photo: {', '.join(ALL)}")
    img = photo(scene)
    tile = np.concatenate([img, img[:, ::-1]], axis=1)
    tile = np.concatenate([tile, tile[::-1]], axis=0)
    reps = (2, 4)
    big = np.tile(tile, (reps[0], reps[1], 1))
    return cv2.resize(big, (width, width // 2), interpolation=cv2.INTER_AREA)


def ground_truth_paths(video: str | os.PathLike) -> tuple[Path, Path]:
    """Where the ground truth of a synthetic video lives: ``<stem>.gt.csv`` and ``<stem>.gt.tum``."""
    v = Path(video)
    return v.with_name(v.stem + ".gt.csv"), v.with_name(v.stem + ".gt.tum")


def render_fpv(
    out: str | os.PathLike,
    angles_deg: np.ndarray,
    *,
    width: int = 1280,
    height: int = 720,
    fps: float = 30.0,
    intrinsics: Intrinsics | None = None,
    scene: str = "panorama",
    noise_std: float = 0.0,
    forward_speed: float = 0.0,
    seed: int = 0,
    crf: int = 16,
    progress=None,
) -> SynthResult:
    """Render and write a synthetic first-person video.

    Parameters
    ----------
    angles_deg:
        (N, 3) yaw, pitch, roll in degrees per frame (camera-to-world convention).
    noise_std:
        Standard deviation of additive Gaussian sensor noise, in 8-bit grey levels.
    forward_speed:
        Forward walking speed in metres per frame (the sphere has a 10 m radius), e.g. 0.02.
    crf:
        H.264 quality for ``.mp4``; a ``.mkv`` path is written losslessly (FFV1).
    progress:
        Optional callable ``progress(done_frames)``.
    """
    angles = np.asarray(angles_deg, dtype=float)
    if angles.ndim != 2 or angles.shape[1] != 3 or len(angles) < 1:
        raise EgovidError("angles must be an (N, 3) array of yaw, pitch, roll", "check the motion")
    if width < 16 or height < 16 or width % 2 or height % 2:
        raise EgovidError(f"size {width}x{height} is not usable", "give even width and height of at least 16 px")
    intr = intrinsics or Intrinsics.default(width, height)
    pano_w = int(np.clip(round(360.0 / intr.hfov_deg * width / 1024.0) * 1024, 2048, 8192))
    renderer = SphereRenderer(scene_panorama(scene, pano_w, seed), intr)
    truth = Trajectory.from_euler(np.arange(len(angles)) / fps, angles)
    # Walk forward along the initial viewing direction (world +z).
    truth.t = np.zeros((len(angles), 3))
    truth.t[:, 2] = forward_speed * np.arange(len(angles))
    cv2.setRNGSeed(seed + 1)
    noise = np.empty((height, width, 3), np.float32)
    out = Path(out)
    codec = "ffv1" if out.suffix.lower() == ".mkv" else "libx264"
    with VideoWriter(out, width, height, fps, codec=codec, crf=crf, preset="veryfast") as writer:
        for i in range(len(angles)):
            img = renderer.render(truth.R[i], truth.t[i])
            if noise_std > 0:
                cv2.randn(noise, 0.0, float(noise_std))
                img = cv2.add(img, noise, dtype=cv2.CV_8U)
            writer.write(img, truth.times[i])
            if progress is not None:
                progress(i + 1)
    csv_path, tum_path = ground_truth_paths(out)
    write_motion_csv(csv_path, truth)
    write_tum(tum_path, truth)
    return SynthResult(out, csv_path, tum_path, truth)


def synth_fpv(
    out: str | os.PathLike,
    motion: MotionSpec,
    *,
    width: int = 1280,
    height: int = 720,
    fps: float = 30.0,
    focal: float | None = None,
    hfov: float | None = None,
    scene: str = "panorama",
    noise_std: float = 0.0,
    forward_speed: float = 0.0,
    seed: int = 0,
    progress=None,
) -> SynthResult:
    """``egovid synth fpv``: render the named ``motion`` (:class:`~egovid.synth.motions.MotionSpec`)
    with the camera of ``focal`` pixels or ``hfov`` degrees across the long side (default: 830 px
    at 1920 px width); the other parameters are :func:`render_fpv`'s."""
    intr = resolve_intrinsics(width, height, focal, hfov)
    return render_fpv(
        out,
        motion.angles(),
        width=width,
        height=height,
        fps=fps,
        intrinsics=intr,
        scene=scene,
        noise_std=noise_std,
        forward_speed=forward_speed,
        seed=seed,
        progress=progress,
    )
