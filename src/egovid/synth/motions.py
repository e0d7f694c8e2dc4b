"""Camera rotation sequences (yaw, pitch, roll in degrees per frame) for synthetic videos.

All functions return an (N, 3) float array; add them to compose motions, e.g.
``running(...) + jitter(...)``. :class:`MotionSpec` names one of the :data:`MOTIONS` with its
parameters (what ``egovid synth fpv --motion`` takes) and builds it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from egovid.core.errors import EgovidError


def running(
    n_frames: int,
    yaw_amp: float = 10.0,
    pitch_amp: float = 2.5,
    period: float = 24.0,
    roll_amp: float = 0.0,
    phase_deg: float = 0.0,
) -> np.ndarray:
    """First-person running (thesis §10.1.1): yaw and pitch sine waves, pitch at twice the rate.

    ``period`` is the yaw period in frames (one stride); pitch bobs once per step (period / 2);
    roll, if any, sways at the stride rate with a quarter-period lag.
    """
    n = np.arange(n_frames, dtype=float)
    ph = np.deg2rad(phase_deg)
    w = 2 * np.pi / period
    return np.stack(
        [
            yaw_amp * np.sin(w * n + ph),
            pitch_amp * np.sin(2 * w * n + 2 * ph),
            roll_amp * np.sin(w * n + ph - np.pi / 2),
        ],
        axis=1,
    )


def pan(n_frames: int, yaw_total: float = 40.0, start: float = 0.25, end: float = 0.75) -> np.ndarray:
    """A pure, intentional yaw pan of ``yaw_total`` degrees, eased in and out (smoothstep),
    between the fractions ``start`` and ``end`` of the clip; still before and after."""
    n = np.arange(n_frames, dtype=float) / max(n_frames - 1, 1)
    u = np.clip((n - start) / max(end - start, 1e-9), 0.0, 1.0)
    s = u * u * (3 - 2 * u)
    out = np.zeros((n_frames, 3))
    out[:, 0] = yaw_total * s
    return out


def random_walk(
    n_frames: int, step_deg: tuple[float, float, float] = (0.4, 0.25, 0.1), smooth: int = 5, seed: int = 0
) -> np.ndarray:
    """A random walk: Gaussian steps per axis (standard deviations in degrees per frame), smoothed
    by a moving average of ``smooth`` frames so it looks like a wandering head, not noise."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(0.0, 1.0, (n_frames, 3)) * np.asarray(step_deg)
    if smooth > 1:
        kernel = np.ones(smooth) / smooth
        steps = np.stack([np.convolve(steps[:, k], kernel, mode="same") for k in range(3)], axis=1)
    out = np.cumsum(steps, axis=0)
    return out - out[0]


def jitter(n_frames: int, std_deg: tuple[float, float, float] = (0.3, 0.3, 0.2), seed: int = 0) -> np.ndarray:
    """High-frequency hand/body shake: white Gaussian noise (degrees) on each axis."""
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, 1.0, (n_frames, 3)) * np.asarray(std_deg)


@dataclass(frozen=True)
class MotionSpec:
    """A named motion of ``frames`` frames (degrees, frames): ``kind`` one of :data:`MOTIONS`;
    ``running``: yaw and pitch sine amplitudes, the yaw ``period`` in frames, roll sway; ``pan``: a
    yaw pan of ``pan_deg`` with roll sway ``roll_amp`` at the period; ``random-walk``: seeded by
    ``seed``; ``still``: none. White shake of ``jitter_deg`` (std per axis, one value or yaw, pitch,
    roll) is added on top, seeded by ``seed``."""

    kind: str = "running"
    frames: int = 300
    yaw_amp: float = 10.0
    pitch_amp: float = 2.5
    period: float = 24.0
    roll_amp: float = 1.5
    pan_deg: float = 40.0
    jitter_deg: float | tuple[float, float, float] = 0.1
    seed: int = 0

    def angles(self) -> np.ndarray:
        """The (frames, 3) yaw, pitch, roll in degrees."""
        if self.kind not in _BUILDERS:
            raise EgovidError(f"unknown motion {self.kind!r}", f"choose one of {', '.join(MOTIONS)}")
        angles = _BUILDERS[self.kind](self)
        std = (self.jitter_deg,) * 3 if np.isscalar(self.jitter_deg) else tuple(self.jitter_deg)
        if max(std) > 0:
            angles = angles + jitter(self.frames, std, seed=self.seed)
        return angles


def _pan_with_sway(s: MotionSpec) -> np.ndarray:
    angles = pan(s.frames, s.pan_deg)
    angles[:, 2] += s.roll_amp * np.sin(2 * np.pi * np.arange(s.frames) / s.period)
    return angles


#: How each named motion is built from its :class:`MotionSpec`.
_BUILDERS: dict[str, Callable[[MotionSpec], np.ndarray]] = {
    "running": lambda s: running(s.frames, s.yaw_amp, s.pitch_amp, s.period, s.roll_amp),
    "pan": _pan_with_sway,
    "random-walk": lambda s: random_walk(s.frames, seed=s.seed),
    "still": lambda s: np.zeros((s.frames, 3)),
}
#: The named motions.
MOTIONS = tuple(_BUILDERS)
