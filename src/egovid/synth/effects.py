"""Image factors for visual-odometry evaluation (thesis §21.1–21.2), each controllable.

* few features: fog / low contrast (:func:`fog`);
* sensor distortion: noise, vignetting, over-exposure (:func:`sensor`);
* motion distortion: rolling shutter and motion blur are rendered by the scene itself
  (:mod:`egovid.voeval.scenes`), since they depend on the motion during the exposure.
"""

from __future__ import annotations

import cv2
import numpy as np


def fog(img: np.ndarray, density: float = 0.75, colour: tuple[int, int, int] = (200, 200, 200)) -> np.ndarray:
    """Blend towards a uniform fog colour: contrast drops by ``1 - density``, features vanish."""
    f = float(np.clip(density, 0.0, 1.0))
    out = img.astype(np.float32) * (1 - f) + np.array(colour, np.float32) * f
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def vignette_mask(width: int, height: int, strength: float = 0.5) -> np.ndarray:
    """Multiplicative cos⁴-like radial fall-off (1 at the centre, 1 - strength in the corners)."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    r = np.hypot((x - (width - 1) / 2) / (width / 2), (y - (height - 1) / 2) / (height / 2)) / np.sqrt(2)
    return (1.0 - strength * r**2).astype(np.float32)


def sensor(
    img: np.ndarray, rng: np.random.Generator, *, noise: float = 8.0, vignetting: float = 0.5, exposure: float = 1.6
) -> np.ndarray:
    """Over-exposure (gain then clipping), vignetting and Gaussian read noise (8-bit levels)."""
    h, w = img.shape[:2]
    out = img.astype(np.float32) * exposure * vignette_mask(w, h, vignetting)[..., None]
    out += rng.normal(0.0, noise, out.shape).astype(np.float32)
    return np.clip(out, 0, 255).astype(np.uint8)


def blur_average(frames: list[np.ndarray]) -> np.ndarray:
    """Motion blur: the mean of sub-frame renders over the exposure."""
    acc = np.zeros(frames[0].shape, np.float32)
    for f in frames:
        acc += f
    return cv2.convertScaleAbs(acc, alpha=1.0 / len(frames))
