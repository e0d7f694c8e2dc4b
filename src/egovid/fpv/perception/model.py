"""Parameters of the smooth-pursuit eye-movement (SPEM) model, thesis ch. 7.

A target can be pursued from frame k through k+2 without a catch-up saccade when its position
error ``PE`` (second difference of its observation angle, degrees) satisfies condition (7.8)

    0.04 s <= (|PE| + b) / |ω| <= 0.18 s,   with retinal slip ω = FPS · PE (eq. 7.7)

or condition (7.9), ``|PE| < MAR``. For ``x = |PE| > 0`` condition (7.8) is the band
``b / (0.18 FPS - 1) <= x <= b / (0.04 FPS - 1)``, so the trackable set of ``|PE|`` is
``[0, MAR) ∪ [x_lo, x_hi]``. With the thesis' values at 30 fps (b = 0.0183°, MAR = 0.02°) that
is simply ``|PE| <= 5b = 0.0915°``.

**Frame rate.** The model is defined, and its bias b calibrated, at the 30 fps of the thesis'
subjective tests: PE is a second difference over two frame steps, and with ω = FPS · PE the band
of (7.8) depends on the rate (at 25 fps or less ``0.04 FPS - 1 <= 0`` and it has no upper bound,
so every motion would be trackable; at 60 fps it is 7x narrower). The same motion must score
the same whatever rate it was filmed at, so egovid evaluates the model at its own rate: every
motion, 3D angles and 2D target tracks alike, is resampled in time to 30 fps
(:func:`to_model_rate`, cubic through the samples, no anti-alias filter: shake above 15 Hz is
folded into the model's band rather than dropped) and then scored with the thesis' frame counts
(saccade 6 frames, VE window N + 1 = 10, 2D-VE segment N = 30). Rates within 1 % of 30 fps
(29.97) are used as they are. This is the one place the rule lives; the scores, the stabiliser's
objective and the easing table all go through it.

A bias so large that ``x_lo > MAR`` splits the trackable set in two; egovid refuses such biases
(``b > MAR (0.18 · 30 - 1) = 0.088°``), far above the thesis' 0.0183° and 0.038°.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from egovid.core.errors import EgovidError

#: The frame rate at which the model is evaluated (see the module docstring).
MODEL_FPS = 30.0
#: Frame rates within this relative distance of MODEL_FPS are scored without resampling.
SAME_RATE_TOLERANCE = 0.01
#: The thesis' bias ``b`` of position-error estimation, degrees: the 3D model (VE, SVE) and 2D-VE.
BIAS_3D_DEG = 0.0183
BIAS_2D_DEG = 0.038


@dataclass(frozen=True)
class ViewingModel:
    """SPEM model parameters (thesis defaults).

    d_over_f:
        Viewing distance over the video's focal length, both in pixels (thesis: 4).
    mar_deg:
        Minimum angular resolution of the eye, degrees (0.02°).
    bias_deg:
        Bias of position-error estimation ``b``, degrees: 0.0183° for the 3D model, 0.038° for 2D.
    saccade_frames:
        Frames lost to a catch-up saccade at the model's 30 fps (6 for 3D; the 2D model uses 5).
    window_frames:
        Frames per VE/SVE window ``N + 1`` at 30 fps (10; 2D-VE uses ``N`` = 30).
    t_min_s, t_max_s:
        Eye-crossing time range of condition (7.8), seconds.
    """

    d_over_f: float = 4.0
    mar_deg: float = 0.02
    bias_deg: float = BIAS_3D_DEG
    saccade_frames: int = 6
    window_frames: int = 10
    t_min_s: float = 0.04
    t_max_s: float = 0.18

    @classmethod
    def model_2d(cls) -> ViewingModel:
        """The 2D-VE defaults: b = 0.038°, 5-frame saccade, N = 30-frame segments."""
        return cls(bias_deg=BIAS_2D_DEG, saccade_frames=5, window_frames=30)

    def with_(self, **changes) -> ViewingModel:
        """A copy with some parameters changed (validated)."""
        m = replace(self, **changes)
        m.validate()
        return m

    def validate(self) -> None:
        """Raise :class:`EgovidError` for parameters outside the model's domain."""
        checks = [
            (self.d_over_f > 0.1 and self.d_over_f < 100, f"d/f = {self.d_over_f} (use 1–20; thesis 4)"),
            (0 < self.mar_deg < 1, f"MAR = {self.mar_deg}° (thesis 0.02°)"),
            (0 <= self.bias_deg < 1, f"bias b = {self.bias_deg}° (thesis {BIAS_3D_DEG}°)"),
            (self.saccade_frames >= 1, f"saccade of {self.saccade_frames} frames"),
            (self.window_frames >= 3, f"window of {self.window_frames} frames"),
            (0 < self.t_min_s < self.t_max_s, f"eye-crossing range {self.t_min_s}–{self.t_max_s} s"),
        ]
        for ok, what in checks:
            if not ok:
                raise EgovidError(f"viewing-model parameter out of range: {what}", "see `egovid fpv score --help`")
        if self.t_min_s * MODEL_FPS <= 1.0:
            raise EgovidError(
                f"eye-crossing time {self.t_min_s} s is at most one frame at {MODEL_FPS:g} fps",
                "condition (7.8) then has no upper bound; use the thesis' 0.04 s",
            )
        _, x_lo, _ = self.pe_bounds()
        if x_lo > self.mar_deg:
            raise EgovidError(
                f"bias b = {self.bias_deg}° is so large that condition (7.8) no longer overlaps |PE| < MAR",
                f"use b <= {self.mar_deg * (self.t_max_s * MODEL_FPS - 1):.3f}°",
            )

    def pe_bounds(self, fps: float = MODEL_FPS) -> tuple[float, float, float]:
        """``(MAR, x_lo, x_hi)`` in degrees: trackable iff ``|PE| < MAR`` or ``x_lo <= |PE| <= x_hi``.

        Every score evaluates this at the model's 30 fps; other rates are only for study, and a rate
        at which (7.8) has no upper bound (``t_min · fps <= 1``, 25 fps with the thesis' values) is
        refused instead of returning an infinite bound."""
        a = self.t_max_s * fps - 1.0
        c = self.t_min_s * fps - 1.0
        if a <= 0 or c <= 0:
            raise EgovidError(
                f"condition (7.8) has no upper bound at {fps:g} fps",
                f"resample the motion to {MODEL_FPS:g} fps first (perception.model.to_model_rate)",
            )
        return self.mar_deg, self.bias_deg / a, self.bias_deg / c

    def pe_threshold(self, fps: float = MODEL_FPS) -> float:
        """Largest trackable ``|PE|`` in degrees (the trackable set is ``[0, threshold]``)."""
        mar, x_lo, x_hi = self.pe_bounds(fps)
        return max(mar, x_hi) if x_lo <= mar else mar


def is_model_rate(fps: float) -> bool:
    """True when ``fps`` is within 1 % of the model's 30 fps (scored without resampling)."""
    return abs(fps / MODEL_FPS - 1.0) <= SAME_RATE_TOLERANCE


def model_times(duration: float) -> np.ndarray:
    """Sample times (seconds) of the model's 30 fps grid from 0 to ``duration`` inclusive."""
    return np.arange(0.0, duration + 1e-9, 1.0 / MODEL_FPS)


def resample(samples: np.ndarray, times: np.ndarray, new_times: np.ndarray) -> np.ndarray:
    """Cubic interpolation of (K, ...) ``samples`` taken at ``times`` (s) to ``new_times`` (s);
    linear for fewer than 4 samples."""
    from scipy.interpolate import CubicSpline, interp1d

    a = np.asarray(samples, dtype=float)
    t = np.asarray(times, dtype=float)
    if len(a) < 4:
        return interp1d(t, a, axis=0, fill_value="extrapolate")(new_times)
    return CubicSpline(t, a, axis=0)(new_times)


def to_model_rate(samples: np.ndarray, fps: float, times: np.ndarray | None = None) -> tuple[np.ndarray, float | None]:
    """(K, ...) samples at ``fps`` (or at the given ``times``, seconds, for variable frame rate) ->
    ``(samples on the model's 30 fps grid, the original rate or None if used as they are)``."""
    a = np.asarray(samples, dtype=float)
    if times is None and is_model_rate(fps):
        return a, None
    t = np.arange(len(a)) / fps if times is None else np.asarray(times, dtype=float) - float(times[0])
    return resample(a, t, model_times(t[-1])), float(fps)


def from_model_rate(samples: np.ndarray, fps: float, n: int, times: np.ndarray | None = None) -> np.ndarray:
    """Inverse of :func:`to_model_rate`: 30 fps samples back to ``n`` frames at ``fps`` (or at
    ``times``)."""
    a = np.asarray(samples, dtype=float)
    if times is None and is_model_rate(fps):
        return a[:n]
    t = np.arange(n) / fps if times is None else np.asarray(times, dtype=float) - float(times[0])
    return resample(a, np.arange(len(a)) / MODEL_FPS, t)
