"""VE / SVE score of a camera motion (thesis §8.3): per-axis window curves, their minimum over
axes (eq. 8.12) and its root mean square (eq. 8.13).

Inputs are yaw, pitch and roll angles in degrees per frame (see :mod:`egovid.core.rotations`) and the
fields of view of the video. Motions at any frame rate are first brought to the model's 30 fps
(:mod:`egovid.fpv.perception.model`).

:func:`axis_windows` is the one implementation of the rule "intervals B(k) -> shift into world
coordinates B̃ -> VE/SVE windows" that the scores, the stabiliser's objective and the easing table
share: yaw and pitch intervals are shifted by their own angle (eq. 8.1); the roll interval is
shifted by yaw along the horizontal field of view and by pitch along the vertical one (eq.
8.2–8.3), and the roll VE is the smaller of the two, as eq. 8.12 takes the smaller over axes.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from egovid.core.errors import EgovidError
from egovid.fpv.perception.intervals import interval_kernel, roll_intervals, yaw_pitch_intervals
from egovid.fpv.perception.model import MODEL_FPS, ViewingModel, to_model_rate
from egovid.fpv.perception.ve import sve_window_kernel, sve_windows, ve_window_kernel, ve_windows

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


#: The components of B̃ (eq. 8.1–8.3): angle column, interval geometry, field of view, shift column.
_COMPONENTS = {
    "yaw": (0, "yaw", "h", 0),
    "pitch": (1, "yaw", "v", 1),
    "roll_h": (2, "roll", "h", 0),
    "roll_v": (2, "roll", "v", 1),
}
#: The components whose windows make up each axis's score (roll: the smaller of the two).
AXIS_COMPONENTS = {"yaw": ("yaw",), "pitch": ("pitch",), "roll": ("roll_h", "roll_v")}


def component_intervals(
    angles: np.ndarray, component: str, hfov: float, vfov: float, model: ViewingModel = ViewingModel()
) -> tuple[np.ndarray, float]:
    """B̃(n) of one component of an (K, 3) motion at the model's rate: ((K-2, 2) [lo, hi] in
    degrees, the field of view it lives in)."""
    col, geometry, side, shift = _COMPONENTS[component]
    fov = hfov if side == "h" else vfov
    thr = model.pe_threshold()
    a = np.asarray(angles, dtype=float)
    intervals = yaw_pitch_intervals if geometry == "yaw" else roll_intervals
    iv = intervals(a[:, col], fov, model.d_over_f, thr)
    iv += a[: len(iv), shift, None]
    return iv, fov


def world_intervals(
    angles: np.ndarray, fps: float, hfov: float, vfov: float, model: ViewingModel = ViewingModel()
) -> WorldIntervals:
    """B̃(n) for yaw, pitch and roll (horizontal and vertical) of an (K, 3) motion in degrees,
    on the model's 30 fps grid."""
    a, _ = to_model_rate(angles, fps)
    parts = {c: component_intervals(a, c, hfov, vfov, model)[0] for c in _COMPONENTS}
    return WorldIntervals(parts["yaw"], parts["pitch"], parts["roll_h"], parts["roll_v"], hfov, vfov)


def windows(iv: np.ndarray, fov: float, method: str, model: ViewingModel, sve_variant: str = "coverage") -> np.ndarray:
    """VE (eq. 8.8) or SVE (eq. 8.10) of every window of B̃ intervals (model rate)."""
    if method == "ve":
        return ve_windows(iv[:, 0], iv[:, 1], fov, model.window_frames, model.saccade_frames)
    return sve_windows(iv[:, 0], iv[:, 1], fov, model.window_frames, sve_variant)


class AxisGeometry(NamedTuple):
    """What the compiled rule needs for one axis: its angle column and, per component of
    :data:`AXIS_COMPONENTS`, interval kind (0 yaw/pitch, 1 roll), shift column, field of view
    (degrees), half field of view (radians) and ``p`` of eq. 8.1–8.3; the PE threshold (radians)."""

    col: int
    kinds: np.ndarray
    shifts: np.ndarray
    fovs: np.ndarray
    halfs: np.ndarray
    ps: np.ndarray
    thr: float


def axis_geometry(axis: str, hfov: float, vfov: float, model: ViewingModel = ViewingModel()) -> AxisGeometry:
    """The per-component constants of one axis's score (fields of view in degrees)."""
    comps = [_COMPONENTS[c] for c in AXIS_COMPONENTS[axis]]
    fovs = [hfov if side == "h" else vfov for _, _, side, _ in comps]
    kinds = np.array([0 if geometry == "yaw" else 1 for _, geometry, _, _ in comps], dtype=np.int64)
    return AxisGeometry(
        comps[0][0],
        kinds,
        np.array([shift for *_, shift in comps], dtype=np.int64),
        np.array(fovs, dtype=np.float64),
        np.array([math.radians(f) / 2.0 for f in fovs]),
        np.array([1.0 / model.d_over_f if k == 0 else model.d_over_f for k in kinds]),
        math.radians(model.pe_threshold()),
    )


@njit(cache=True)
def axis_windows_kernel(a, col, kinds, shifts, fovs, halfs, ps, thr, n1, sacc, sve, literal):  # pragma: no cover
    """Compiled body of :func:`axis_windows` for the (K, 3) motion ``a`` (degrees, model rate) and
    the constants of :func:`axis_geometry`: intervals of column ``col``, shifted by column
    ``shifts[c]``, VE (``sve`` False; saccade ``sacc`` frames) or SVE windows of ``n1`` intervals
    (``literal``: eq. 8.11 as written), the smaller over the components. The stabiliser's objective
    calls it in its inner loop."""
    theta = np.deg2rad(a[:, col])
    out = np.empty(0)
    for c in range(kinds.shape[0]):
        iv = np.rad2deg(interval_kernel(kinds[c], theta, halfs[c], ps[c], thr))
        m = iv.shape[0]
        lo = iv[:, 0] + a[:m, shifts[c]]
        hi = iv[:, 1] + a[:m, shifts[c]]
        w = sve_window_kernel(lo, hi, fovs[c], n1, literal) if sve else ve_window_kernel(lo, hi, fovs[c], n1, sacc)
        out = w if c == 0 else np.minimum(out, w)
    return out


def axis_windows(
    angles: np.ndarray,
    axis: str,
    hfov: float,
    vfov: float,
    model: ViewingModel = ViewingModel(),
    method: str = "ve",
    sve_variant: str = "coverage",
) -> np.ndarray:
    """Per-window VE/SVE of one axis of an (K, 3) motion already at the model's 30 fps (the one
    intervals -> shift -> windows rule; see the module docstring). Only the components this axis
    needs are computed."""
    if method not in METHODS or sve_variant not in ("coverage", "thesis"):
        raise EgovidError(f"unknown scoring method {method!r} / {sve_variant!r}", "use ve or sve (coverage or thesis)")
    g = axis_geometry(axis, hfov, vfov, model)
    a = np.ascontiguousarray(angles, dtype=np.float64)
    return axis_windows_kernel(
        a, g.col, g.kinds, g.shifts, g.fovs, g.halfs, g.ps, g.thr,
        model.window_frames, model.saccade_frames, method == "sve", sve_variant == "thesis",
    )  # fmt: skip


def check_angles(angles: np.ndarray, fps: float, model: ViewingModel) -> np.ndarray:
    """Validate an (K, 3) motion; raise :class:`EgovidError` with the fix otherwise."""
    a = np.asarray(angles, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise EgovidError("motion must have three columns: yaw, pitch, roll in degrees", "check the motion file")
    if not np.all(np.isfinite(a)):
        raise EgovidError("motion contains NaN or infinite angles", "re-estimate the motion")
    if not (fps > 0 and np.isfinite(fps)):
        raise EgovidError(f"frame rate {fps} is not positive", "give the video's frame rate")
    seconds = (model.window_frames + 2) / MODEL_FPS
    if (len(a) - 1) / fps < seconds - 1.0 / MODEL_FPS - 1e-9:
        raise EgovidError(
            f"motion has {len(a)} frames, fewer than one scoring window ({seconds:.2f} s)",
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
    times: np.ndarray | None = None,
) -> MotionScore:
    """VE or SVE of a motion: per-axis and combined window curves and the overall score.

    Parameters
    ----------
    angles:
        (K, 3) yaw, pitch, roll in degrees per frame.
    fps:
        Frame rate; motions not at 30 fps (±1 %) are resampled to 30 fps first (see
        :mod:`egovid.fpv.perception.model`), and ``resampled_from`` says so.
    hfov, vfov:
        Horizontal and vertical field of view of the video in degrees.
    times:
        Frame times in seconds, for a variable frame rate (default: ``index / fps``).
    """
    if method not in METHODS:
        raise EgovidError(f"unknown method {method!r}", f"choose one of {', '.join(METHODS)}")
    model.validate()
    a = check_angles(angles, fps, model)
    a, resampled_from = to_model_rate(a, fps, times)
    per_axis = {ax: axis_windows(a, ax, hfov, vfov, model, method, sve_variant) for ax in AXES}
    combined = np.minimum(np.minimum(per_axis["yaw"], per_axis["pitch"]), per_axis["roll"])
    params = {**asdict(model), "hfov_deg": hfov, "vfov_deg": vfov, "pe_threshold_deg": model.pe_threshold()}
    if method == "sve":
        params["sve_variant"] = sve_variant
    return MotionScore(
        method=method,
        score=rms(combined),
        axis_scores={k: rms(v) for k, v in per_axis.items()},
        combined=combined,
        per_axis=per_axis,
        window_times=np.arange(len(combined)) / MODEL_FPS,
        fps=MODEL_FPS,
        resampled_from=resampled_from,
        params=params,
    )
