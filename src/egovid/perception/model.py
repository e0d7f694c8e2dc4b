"""Parameters of the smooth-pursuit eye-movement (SPEM) model, thesis ch. 7.

A target can be pursued from frame k through k+2 without a catch-up saccade when its position
error ``PE`` (second difference of its observation angle, degrees) satisfies condition (7.8)

    0.04 s <= (|PE| + b) / |ω| <= 0.18 s,   with retinal slip ω = FPS · PE (eq. 7.7)

or condition (7.9), ``|PE| < MAR``. For ``x = |PE| > 0`` condition (7.8) is the band
``b / (0.18 FPS - 1) <= x <= b / (0.04 FPS - 1)``, so the trackable set of ``|PE|`` is
``[0, MAR) ∪ [x_lo, x_hi]``. With the thesis' values at 30 fps (b = 0.0183°, MAR = 0.02°) that
is simply ``|PE| <= 5b = 0.0915°``.

Two consequences of ω = FPS · PE that the thesis, written for 30 fps, does not spell out:

* at 25 fps or less, ``0.04 FPS - 1 <= 0`` and the upper bound disappears (every motion would be
  trackable), and below 5.6 fps condition (7.8) can never hold. egovid therefore scores motions
  recorded at 25 fps or less after resampling them to 30 fps (:func:`resample_angles`);
* a bias so large that ``x_lo > MAR`` splits the trackable set in two; egovid refuses such biases
  (``b > MAR (0.18 FPS - 1)``, 0.088° at 30 fps), far above the thesis' 0.0183° and 0.038°.

Durations (saccade, window) are given in frames at 30 fps, as in the thesis, and scaled to the
motion's frame rate.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from egovid.errors import EgovidError

#: Frame rates at or below this are resampled to 30 fps before scoring (see module docstring).
MIN_MODEL_FPS = 25.0
MODEL_FPS = 30.0


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
        Frames lost to a catch-up saccade, at 30 fps (6 for 3D; the 2D model uses 5).
    window_frames:
        Frames per VE/SVE window ``N + 1`` at 30 fps (10; 2D-VE uses ``N`` = 30).
    t_min_s, t_max_s:
        Eye-crossing time range of condition (7.8), seconds.
    """

    d_over_f: float = 4.0
    mar_deg: float = 0.02
    bias_deg: float = 0.0183
    saccade_frames: int = 6
    window_frames: int = 10
    t_min_s: float = 0.04
    t_max_s: float = 0.18

    @classmethod
    def model_2d(cls) -> ViewingModel:
        """The 2D-VE defaults: b = 0.038°, 5-frame saccade, N = 30-frame segments."""
        return cls(bias_deg=0.038, saccade_frames=5, window_frames=30)

    def with_(self, **changes) -> ViewingModel:
        """A copy with some parameters changed (validated)."""
        m = replace(self, **changes)
        m.validate()
        return m

    def validate(self, fps: float = MODEL_FPS) -> None:
        """Raise :class:`EgovidError` for parameters outside the model's domain."""
        checks = [
            (self.d_over_f > 0.1 and self.d_over_f < 100, f"d/f = {self.d_over_f} (use 1–20; thesis 4)"),
            (0 < self.mar_deg < 1, f"MAR = {self.mar_deg}° (thesis 0.02°)"),
            (0 <= self.bias_deg < 1, f"bias b = {self.bias_deg}° (thesis 0.0183°)"),
            (self.saccade_frames >= 1, f"saccade of {self.saccade_frames} frames"),
            (self.window_frames >= 3, f"window of {self.window_frames} frames"),
            (0 < self.t_min_s < self.t_max_s, f"eye-crossing range {self.t_min_s}–{self.t_max_s} s"),
        ]
        for ok, what in checks:
            if not ok:
                raise EgovidError(f"viewing-model parameter out of range: {what}", "see `egovid fpv score --help`")
        _, x_lo, _ = self.pe_bounds(max(fps, MODEL_FPS))
        if x_lo > self.mar_deg:
            raise EgovidError(
                f"bias b = {self.bias_deg}° is so large that condition (7.8) no longer overlaps |PE| < MAR",
                f"use b <= {self.mar_deg * (self.t_max_s * max(fps, MODEL_FPS) - 1):.3f}°",
            )

    def pe_bounds(self, fps: float) -> tuple[float, float, float]:
        """``(MAR, x_lo, x_hi)`` in degrees: trackable iff ``|PE| < MAR`` or ``x_lo <= |PE| <= x_hi``."""
        a = self.t_max_s * fps - 1.0
        c = self.t_min_s * fps - 1.0
        x_lo = self.bias_deg / a if a > 0 else np.inf
        x_hi = self.bias_deg / c if c > 0 else np.inf
        return self.mar_deg, x_lo, x_hi

    def pe_threshold(self, fps: float) -> float:
        """Largest trackable ``|PE|`` in degrees (the trackable set is ``[0, threshold]``)."""
        mar, x_lo, x_hi = self.pe_bounds(fps)
        return max(mar, x_hi) if x_lo <= mar else mar

    def frames(self, n_at_30: int, fps: float) -> int:
        """A duration given in frames at 30 fps, in frames at ``fps``."""
        return max(1, round(n_at_30 * fps / MODEL_FPS))


def resample_angles(angles: np.ndarray, fps: float, target_fps: float = MODEL_FPS) -> np.ndarray:
    """Resample an (K, ...) angle sequence from ``fps`` to ``target_fps`` (cubic interpolation)."""
    from scipy.interpolate import CubicSpline

    a = np.asarray(angles, dtype=float)
    t = np.arange(len(a)) / fps
    t_new = np.arange(0.0, t[-1] + 1e-9, 1.0 / target_fps)
    if len(a) < 4:
        return np.stack([np.interp(t_new, t, a[:, k]) for k in range(a.shape[1])], axis=1)
    return CubicSpline(t, a, axis=0)(t_new)
