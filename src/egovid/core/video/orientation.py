"""The rotation flag of a video: frames come out of the readers in display orientation and go
into the writer turned back to the coded orientation (BGR or grey images, and I420 pictures plane
by plane)."""

from __future__ import annotations

import av
import numpy as np


def rotation_of(frame: av.VideoFrame) -> int:
    """The display rotation flag of a decoded frame, degrees counter-clockwise (0, 90, 180 or 270)."""
    try:
        rot = frame.rotation
    except Exception:  # pragma: no cover - very old PyAV
        return 0
    return round(rot / 90.0) * 90 % 360 if rot else 0


def to_display(image: np.ndarray, rotation: int) -> np.ndarray:
    """Turn a decoded HxW[x3] image into display orientation (``rotation`` degrees counter-clockwise)."""
    k = (rotation // 90) % 4
    return np.ascontiguousarray(np.rot90(image, k)) if k else image


def rotate_i420(img: np.ndarray, rotation: int) -> np.ndarray:
    """Turn one I420 picture ((H*3/2, W) uint8, or uint16 for 10 bits: Y, then U, then V) by
    ``rotation`` degrees counter-clockwise, plane by plane."""
    k = (rotation // 90) % 4
    if not k:
        return img
    h = img.shape[0] * 2 // 3
    w = img.shape[1]
    flat = img.reshape(-1)
    y = flat[: w * h].reshape(h, w)
    u = flat[w * h : w * h + (w // 2) * (h // 2)].reshape(h // 2, w // 2)
    v = flat[w * h + (w // 2) * (h // 2) :].reshape(h // 2, w // 2)
    y, u, v = (np.rot90(p, k) for p in (y, u, v))
    out = np.empty((y.shape[0] * 3 // 2, y.shape[1]), img.dtype)
    o = out.reshape(-1)
    o[: y.size] = y.ravel()
    o[y.size : y.size + u.size] = u.ravel()
    o[y.size + u.size :] = v.ravel()
    return out


def to_coded(image: np.ndarray, rotation: int, i420: bool) -> np.ndarray:
    """Display orientation -> the coded orientation of a video whose rotation flag is ``rotation``."""
    return rotate_i420(image, -rotation) if i420 else to_display(image, -rotation)
