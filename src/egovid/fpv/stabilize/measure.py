"""Measure a video the way a viewer gets it: decoded from the file, never from a plan.

For the stabiliser's before/after: the camera motion is re-estimated from the decoded pixels
(:func:`egovid.core.motion.estimate.estimate_motion`), and from it VE, SVE and the VE of the pure
first-person motion (the FPMI measure, thesis §9.2); 2D-VE comes from the optical flow of the
decoded frames; ITF (eq. 10.9–10.11) from their luma, masked by geometry where the stabiliser
left borders; high-frequency jitter and the visible shake (``shake.py``'s figure) from phase
correlation (:mod:`egovid.core.metrics.jitter`).
The same functions score the plan (:func:`motion_scores`), so the report can show planned and
measured side by side.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.metrics.itf import ITFAccumulator
from egovid.core.metrics.jitter import ShiftPath, high_pass_rms, shake_rms, unzoomed
from egovid.core.motion.estimate import estimate_motion
from egovid.core.video import iter_frames, probe
from egovid.fpv.perception.model import ViewingModel, to_model_rate
from egovid.fpv.perception.score import score_angles
from egovid.fpv.perception.ve2d import ve2d_video
from egovid.fpv.stabilize.fpm import motion_anchors, pure_fpm


def pure_motion(angles: np.ndarray, threshold: float = 0.5) -> np.ndarray:
    """The pure FPM (zigzag through the anchors) of every axis of a (K, 3) motion, same sampling."""
    out = np.empty_like(np.asarray(angles, dtype=float))
    for k in range(angles.shape[1]):
        a = motion_anchors(angles[:, k], threshold)
        out[:, k] = pure_fpm(a, angles[a, k], len(angles))
    return out


#: FPMI (1 - VE of the pure FPM) below which a motion carries no first-person motion worth
#: keeping (its anchors' turn-backs are too small or too few to be seen): the plans of the test
#: bed's drives and steady pans score 0.001-0.015, a hand-held pan's 0.27. Below it the share of
#: FPMI a path keeps is a ratio of two near-zero scores (0.17-5.9 on those drives and pans), not a
#: measure, so nothing there can be lost. Also the benchmarks' "n/a" for an intended motion.
FPMI_NONE = 0.05


@dataclass
class MotionScores:
    """Scores of a camera motion: VE, SVE and the VE of its pure FPM (lower = more first-person
    motion information)."""

    ve: float
    sve: float
    pure_fpm_ve: float


def motion_scores(
    angles: np.ndarray,
    fps: float,
    intr: Intrinsics,
    *,
    model: ViewingModel | None = None,
    anchor_threshold: float = 0.5,
    times: np.ndarray | None = None,
) -> MotionScores:
    """VE, SVE and pure-FPM VE of an (K, 3) motion in degrees (at the model's 30 fps; the pure
    FPM is drawn there too, so its zigzag is not smoothed by resampling)."""
    model = model or ViewingModel()
    h, v = intr.hfov_deg, intr.vfov_deg
    a30, _ = to_model_rate(angles, fps, times)
    return MotionScores(
        ve=score_angles(a30, 30.0, h, v, model=model, method="ve").score,
        sve=score_angles(a30, 30.0, h, v, model=model, method="sve").score,
        pure_fpm_ve=score_angles(pure_motion(a30, anchor_threshold), 30.0, h, v, model=model).score,
    )


@dataclass
class VideoMeasures:
    """Everything measured on a decoded video (see the module docstring); ``jitter_px`` above
    3 Hz and ``shake_px`` (``shake.py``'s x + y, unzoomed) in pixels at 480 px width; ``motion``
    is the re-estimated (K, 3) motion in degrees (None when it was given)."""

    ve: float
    sve: float
    pure_fpm_ve: float
    ve2d: float
    itf_db: float
    jitter_px: float
    shake_px: float = float("nan")
    motion: np.ndarray | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("motion")
        return d


def pixel_measures(
    video: str | os.PathLike,
    masks: Callable[[int], np.ndarray | None] | None = None,
    *,
    jitter_width: int = 480,
    cutoff_hz: float = 3.0,
    zoom: np.ndarray | float = 1.0,
) -> tuple[float, float, float]:
    """(masked ITF in dB, high-frequency jitter, visible shake) in one decode, both in pixels at
    ``jitter_width``, the shake with each frame's shift divided by its ``zoom`` ((K,) or scalar);
    ``masks(k)`` gives frame k's content mask (None: all content)."""
    info = probe(video)
    itf = ITFAccumulator()
    shifts = ShiftPath(jitter_width)
    for f in iter_frames(video, gray=True):
        itf.add(f.image, None if masks is None else masks(f.index))
        shifts.add(f.image)
    path = shifts.path
    return itf.value, high_pass_rms(path, info.fps, cutoff_hz), shake_rms(unzoomed(path, zoom))


def measure_video(
    video: str | os.PathLike,
    intr: Intrinsics,
    *,
    motion: np.ndarray | None = None,
    masks: Callable[[int], np.ndarray | None] | None = None,
    model: ViewingModel | None = None,
    anchor_threshold: float = 0.5,
    zoom: np.ndarray | float = 1.0,
    progress: Callable[[str, int, int], None] | None = None,
) -> VideoMeasures:
    """Measure a decoded video: motion (re-estimated unless given as (K, 3) degrees), VE, SVE,
    pure-FPM VE, 2D-VE, masked ITF, jitter and the visible shake (``zoom``: the video's zoom
    against its source, per frame or one)."""
    info = probe(video)
    estimated = None
    times = None
    if motion is None:
        cb = (lambda d, t: progress("measure motion", d, t)) if progress else None
        traj = estimate_motion(video, intr, progress=cb).trajectory
        estimated = motion = traj.euler()
        times = traj.times
    scores = motion_scores(motion, info.fps, intr, model=model, anchor_threshold=anchor_threshold, times=times)
    cb = (lambda d, t: progress("measure 2D-VE", d, t)) if progress else None
    ve2d = ve2d_video(video, intr, progress=cb).score
    itf, jitter, shake = pixel_measures(video, masks, zoom=zoom)
    return VideoMeasures(scores.ve, scores.sve, scores.pure_fpm_ve, ve2d, itf, jitter, shake, estimated)
