"""A camera's own motion samples, whoever read them (telemetry-parser: :mod:`telemetry`; a
CAMM track: :mod:`camm`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ImuSamples:
    """IMU samples of a file.

    ``times`` (N,) seconds on the video clock (telemetry-parser's, before any sync);
    ``gyro`` (N, 3) angular rate in radians per second; ``accel`` (M, 3) m/s² at ``accel_times``
    (M,) seconds, or ``None``. Axes are telemetry-parser's normalised IMU axes (a CAMM track's
    are the camera's, :mod:`egovid.core.camera.camm`); the sync maps them to the camera's.
    """

    times: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray | None = None
    accel_times: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.times)

    @property
    def rate_hz(self) -> float:
        """Median gyro sample rate in Hz."""
        return float(1.0 / np.median(np.diff(self.times))) if len(self.times) > 1 else 0.0


@dataclass(frozen=True)
class OrientationSamples:
    """Orientation quaternions recorded by the camera: ``times`` (N,) seconds on the video clock,
    ``quaternions`` (N, 4) unit quaternions ``(w, x, y, z)`` in telemetry-parser's axes."""

    times: np.ndarray
    quaternions: np.ndarray

    def __len__(self) -> int:
        return len(self.times)
