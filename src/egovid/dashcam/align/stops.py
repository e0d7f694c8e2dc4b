"""Stop detection (thesis §15.1): frames where the car stands still are not aligned.

A frame is "stopped" when the speed is below ``min_speed`` and the bearing is not turning faster
than ``turn_rate`` (turning on the spot changes the view, so alignment must still run). Stops
shorter than ``min_duration`` are ignored. The encoder then keeps the last aligned reference frame
for them (the "default reference"): the car is still where that frame was matched.
"""

from __future__ import annotations

import numpy as np


def stopped_frames(
    speed: np.ndarray,
    bearing: np.ndarray,
    fps: float,
    *,
    min_speed: float = 0.8,
    turn_rate: float = 8.0,
    min_duration: float = 0.5,
) -> np.ndarray:
    """(N,) bool: stopped frames, from per-frame speed (m/s) and bearing (degrees)."""
    speed = np.asarray(speed, dtype=float)
    b = np.unwrap(np.radians(np.asarray(bearing, dtype=float)))
    rate = np.degrees(np.abs(np.gradient(b))) * fps if len(b) > 1 else np.zeros(len(b))
    raw = (speed < min_speed) & (rate < turn_rate)
    out = raw.copy()
    n = round(min_duration * fps)
    i = 0
    while i < len(raw):
        if raw[i]:
            j = i
            while j < len(raw) and raw[j]:
                j += 1
            if j - i < n:
                out[i:j] = False
            i = j
        else:
            i += 1
    return out
