"""Image-level factors applied to recorded frames (``--real-factors``).

The structural factors of the thesis (features, learned content, motion distortion) need a scene
built for them and stay synthetic (:mod:`egovid.voeval.scenes`). What happens to a picture after
the scene was captured can be applied to real frames, one factor at a time, each frame keeping
its reference orientation:

* ``noise`` — sensor read noise, Gaussian, σ = 8 levels (factor 3, sensor);
* ``blur`` — motion blur along the camera's own reference rotation: the mean of 5 views rotated
  over the first half of the frame interval (``K Qᵀ K⁻¹`` warps; exact for rotation, approximate
  where the camera also translates near objects) (factor 4, motion);
* ``illumination`` — low light with auto-exposure hunting: gain 0.35 × (1 ± 0.3 sin) over a 2 s
  period, quantised to 8 bits (fewer grey levels, and no brightness constancy between frames)
  (factor 3, sensor / illumination).

The compression ladder (factor 5) applies to every scene, original or degraded.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.rotations import so3_exp, so3_log
from egovid.core.video import iter_frames
from egovid.synth import effects
from egovid.voeval.scenes import SceneTruth, lossless_writer


def rotation_blur(image: np.ndarray, K: np.ndarray, Q: np.ndarray, *, exposure: float = 0.5, samples: int = 5):
    """Motion blur of a frame whose camera turns by ``Q`` (3x3, camera k to k+1) per frame
    interval: the mean of ``samples`` views over ``exposure`` of the interval."""
    w = so3_log(Q)
    h, wd = image.shape[:2]
    Ki = np.linalg.inv(K)
    views = []
    for s in np.linspace(0.0, exposure, samples):
        Qs = so3_exp(w * s)
        H = K @ Qs.T @ Ki  # pixel in frame k -> pixel seen after turning by Qs
        views.append(cv2.warpPerspective(image, H, (wd, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT))
    return effects.blur_average(views)


def illumination_gain(t: np.ndarray, phase: float, *, level: float = 0.35, hunt: float = 0.3, period: float = 2.0):
    """Exposure gain at times ``t`` (seconds): low light with a sinusoidal auto-exposure hunt."""
    return level * (1.0 + hunt * np.sin(2 * math.pi * np.asarray(t) / period + phase))


def _noise(img, k, ctx):
    return effects.sensor(img, ctx["rng"], noise=8.0, vignetting=0.0, exposure=1.0)


def _blur(img, k, ctx):
    R = ctx["R"]
    a, b = (k, k + 1) if k + 1 < len(R) else (k - 1, k)
    return rotation_blur(img, ctx["K"], R[a].T @ R[b])


def _illumination(img, k, ctx):
    g = float(illumination_gain(np.array([ctx["time"]]), ctx["phase"])[0])
    return np.clip(img.astype(np.float32) * g + 0.5, 0, 255).astype(np.uint8)


#: What each real-frame factor does to frame k (image, index, context).
DEGRADE = {"noise": _noise, "blur": _blur, "illumination": _illumination}
REAL_FACTORS = tuple(DEGRADE)


def degrade_scene(src: Path, truth: SceneTruth, factor: str, seed: int, dst: Path) -> SceneTruth:
    """Write ``dst`` (lossless): the frames of ``src`` with one image-level ``factor``; same truth."""
    if factor not in DEGRADE:
        raise EgovidError(f"unknown real-frame factor {factor!r}", f"choose from {', '.join(REAL_FACTORS)}")
    rng = np.random.default_rng([seed, 7])
    ctx = {"rng": rng, "phase": float(rng.uniform(0, 2 * math.pi)), "K": truth.intrinsics.K, "R": truth.R}
    with lossless_writer(dst, truth.intrinsics.width, truth.intrinsics.height, truth.fps) as wr:
        for f in iter_frames(src):
            ctx["time"] = f.time
            img = DEGRADE[factor](f.image, f.index, ctx)
            wr.write(img, float(truth.times[f.index]) if f.index < len(truth.times) else f.time)
    meta = {**truth.meta, "kind": "derived", "base": truth.name, "factor": factor, "seed": seed}
    return SceneTruth(f"{truth.name}+{factor}", truth.R, truth.intrinsics, truth.fps, truth.times, meta, truth.t)
