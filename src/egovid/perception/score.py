"""VE / SVE score of a camera motion (thesis §8.3): per-axis window curves, their minimum over
axes (eq. 8.12) and its root mean square (eq. 8.13).

Inputs are yaw, pitch and roll angles in degrees per frame (see :mod:`egovid.geometry`) and the
fields of view of the video. The roll component uses the roll interval B(n) shifted by yaw in the
horizontal direction and by pitch in the vertical direction (eq. 8.2–8.3); its VE is the smaller
of the two, as eq. 8.12 takes the smaller over axes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from egovid.errors import EgovidError
from egovid.perception.intervals import roll_intervals, yaw_pitch_intervals
from egovid.perception.model import MIN_MODEL_FPS, MODEL_FPS, ViewingModel, resample_angles
from egovid.perception.ve import sve_windows, ve_windows

AXES = ("yaw", "pitch", "roll")
METHODS = ("ve", "sve")


@dataclass
class WorldIntervals:
    """B̃(n) = B(n) + θ(n) per component: (M, 2) arrays of [lo, hi] in degrees, M = K - 2."""

    yaw: np.ndarray
    pitch: np.ndarray
    roll_h: np.ndarray
    roll_v: np.ndarray
    hfov: float
    vfov: float


@dataclass
class MotionScore:
    """Score of one motion with one method.

    ``per_axis[axis]`` and ``combined`` are per-window curves (window i covers frames
    ``i .. i + N + 2``; ``window_times`` are their start times in seconds); ``axis_scores`` and
    ``score`` are their root mean squares (eq. 8.13).
    """

    method: str
    score: float
    axis_scores: dict[str, float]
    combined: np.ndarray
    per_axis: dict[str, np.ndarray]
    window_times: np.ndarray
    fps: float
    resampled_from: float | None
    params: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready summary with the curves."""
        return {
            "method": self.method,
            "score": self.score,
            "axis_scores": self.axis_scores,
            "fps": self.fps,
            "resampled_from_fps": self.resampled_from,
            "params": self.params,
            "window_times_s": self.window_times.round(4).tolist(),
            "combined": self.combined.round(6).tolist(),
            "per_axis": {k: v.round(6).tolist() for k, v in self.per_axis.items()},
        }


def rms(x: np.ndarray) -> float:
    """Root mean square (eq. 8.13 read as RMS, like eq. 8.18 and 10.1)."""
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def world_intervals(
    angles: np.ndarray, fps: float, hfov: float, vfov: float, model: ViewingModel = ViewingModel()
) -> WorldIntervals:
    """B̃(n) for yaw, pitch and roll (horizontal and vertical) of an (K, 3) motion in degrees."""
    a = np.asarray(angles, dtype=float)
    thr = model.pe_threshold(fps)
    yaw = yaw_pitch_intervals(a[:, 0], hfov, model.d_over_f, thr)
    pitch = yaw_pitch_intervals(a[:, 1], vfov, model.d_over_f, thr)
    roll_h = roll_intervals(a[:, 2], hfov, model.d_over_f, thr)
    roll_v = roll_intervals(a[:, 2], vfov, model.d_over_f, thr)
    m = len(a) - 2
    yaw += a[:m, 0, None]
    pitch += a[:m, 1, None]
    roll_h += a[:m, 0, None]
    roll_v += a[:m, 1, None]
    return WorldIntervals(yaw, pitch, roll_h, roll_v, hfov, vfov)


def _windows(iv: np.ndarray, fov: float, method: str, model: ViewingModel, fps: float, variant: str) -> np.ndarray:
    n1 = model.frames(model.window_frames, fps)
    if method == "ve":
        return ve_windows(iv[:, 0], iv[:, 1], fov, n1, model.frames(model.saccade_frames, fps))
    return sve_windows(iv[:, 0], iv[:, 1], fov, n1, variant)


def check_angles(angles: np.ndarray, fps: float, model: ViewingModel) -> np.ndarray:
    """Validate an (K, 3) motion; raise :class:`EgovidError` with the fix otherwise."""
    a = np.asarray(angles, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise EgovidError("motion must have three columns: yaw, pitch, roll in degrees", "check the motion file")
    if not np.all(np.isfinite(a)):
        raise EgovidError("motion contains NaN or infinite angles", "re-estimate the motion")
    if not (fps > 0 and np.isfinite(fps)):
        raise EgovidError(f"frame rate {fps} is not positive", "give the video's frame rate")
    need = model.frames(model.window_frames, max(fps, MODEL_FPS)) + 2
    if len(a) < need:
        raise EgovidError(
            f"motion has {len(a)} frames, fewer than one scoring window ({need} frames)",
            "score a longer clip",
        )
    return a


def score_angles(
    angles: np.ndarray,
    fps: float,
    hfov: float,
    vfov: float,
    *,
    model: ViewingModel = ViewingModel(),
    method: str = "ve",
    sve_variant: str = "coverage",
    intervals: WorldIntervals | None = None,
) -> MotionScore:
    """VE or SVE of a motion: per-axis and combined window curves and the overall score.

    Parameters
    ----------
    angles:
        (K, 3) yaw, pitch, roll in degrees per frame.
    fps:
        Frame rate; at 25 fps or less the motion is resampled to 30 fps first (see
        :mod:`egovid.perception.model`).
    hfov, vfov:
        Horizontal and vertical field of view of the video in degrees.
    """
    if method not in METHODS:
        raise EgovidError(f"unknown method {method!r}", f"choose one of {', '.join(METHODS)}")
    model.validate(fps)
    a = check_angles(angles, fps, model)
    resampled_from = None
    if fps <= MIN_MODEL_FPS:
        a, resampled_from, fps = resample_angles(a, fps), fps, MODEL_FPS
        intervals = None
    iv = intervals or world_intervals(a, fps, hfov, vfov, model)
    per_axis = {
        "yaw": _windows(iv.yaw, hfov, method, model, fps, sve_variant),
        "pitch": _windows(iv.pitch, vfov, method, model, fps, sve_variant),
        "roll": np.minimum(
            _windows(iv.roll_h, hfov, method, model, fps, sve_variant),
            _windows(iv.roll_v, vfov, method, model, fps, sve_variant),
        ),
    }
    combined = np.minimum(np.minimum(per_axis["yaw"], per_axis["pitch"]), per_axis["roll"])
    params = {**asdict(model), "hfov_deg": hfov, "vfov_deg": vfov, "pe_threshold_deg": model.pe_threshold(fps)}
    if method == "sve":
        params["sve_variant"] = sve_variant
    return MotionScore(
        method=method,
        score=rms(combined),
        axis_scores={k: rms(v) for k, v in per_axis.items()},
        combined=combined,
        per_axis=per_axis,
        window_times=np.arange(len(combined)) / fps,
        fps=fps,
        resampled_from=resampled_from,
        params=params,
    )
