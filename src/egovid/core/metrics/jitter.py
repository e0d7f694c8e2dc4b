"""High-frequency jitter of a video, measured from its pixels alone (no camera model).

Consecutive frames are registered by phase correlation (OpenCV ``phaseCorrelate`` on a grey
copy ``width`` pixels wide, Hann-windowed): the dominant image shift between them, in pixels of
that copy. Accumulated, the shifts give the image path; the jitter is the root mean square of
that path after a zero-phase 4th-order Butterworth high-pass at ``cutoff_hz`` (default 3 Hz:
hand tremor, footsteps and vibration, above the head bob and pans a stabiliser keeps), over both
directions. It is independent of egovid's motion estimator, the stabiliser's own plan and any
stabiliser's zoom model, so it can compare egovid with vid.stab on equal terms; a zoomed output
is measured in its own (magnified) pixels, as a viewer sees it.

:func:`shake_rms` is the visible-shake figure of the acceptance measure (``shake.py``): the same
image path minus its centred 15-frame moving average (edge-padded), RMS per axis, x + y. It counts
everything above about 1.5 Hz at 30 fps in full, a walking bob as much as hand tremor, and the
start and stop of a pan by their acceleration; a zoomed output's shifts are divided by its zoom
(original pixels at the measuring width).
"""

from __future__ import annotations

import cv2
import numpy as np


def high_pass_rms(path: np.ndarray, fps: float, cutoff_hz: float = 3.0) -> float:
    """RMS (same units as ``path``, (K, D)) of a path after a zero-phase Butterworth high-pass."""
    from scipy.signal import butter, sosfiltfilt

    p = np.asarray(path, dtype=float)
    if len(p) < 16 or cutoff_hz >= fps / 2:
        return float("nan")
    sos = butter(4, cutoff_hz, btype="highpass", fs=fps, output="sos")
    hp = sosfiltfilt(sos, p, axis=0, padtype="odd", padlen=min(len(p) - 1, 3 * 12))
    return float(np.sqrt(np.mean(np.sum(hp * hp, axis=1))))


#: Frames of the centred moving average that :func:`shake_rms` measures against (``shake.py``'s).
SHAKE_WINDOW = 15


def shake_rms(path: np.ndarray, window: int = SHAKE_WINDOW) -> float:
    """x + y RMS (units of ``path``, (K, 2)) of the path minus its centred ``window``-frame moving
    average, the ends padded with the first and last value."""
    p = np.asarray(path, dtype=float)
    if len(p) < 2:
        return float("nan")
    h = window // 2
    pad = np.pad(p, ((h, h), (0, 0)), mode="edge")
    c = np.concatenate([np.zeros((1, p.shape[1])), np.cumsum(pad, axis=0)])
    ma = (c[window:] - c[:-window]) / window
    return float(np.sqrt(np.mean((p - ma[: len(p)]) ** 2, axis=0)).sum())


def unzoomed(path: np.ndarray, zoom: np.ndarray | float) -> np.ndarray:
    """The image path (K, 2) of a video zoomed by ``zoom`` ((K,) or scalar) in unzoomed pixels:
    each frame's shift from the previous divided by that frame's zoom."""
    p = np.asarray(path, dtype=float)
    z = np.broadcast_to(np.asarray(zoom, dtype=float), (len(p),))
    d = np.diff(p, axis=0) / z[1:, None]
    return np.concatenate([p[:1], p[:1] + np.cumsum(d, axis=0)])


class ShiftPath:
    """Streaming image path by phase correlation: feed grey frames in order (any size; they are
    reduced to ``width`` pixels), read :attr:`path` ((K, 2) pixels of the reduced copy)."""

    def __init__(self, width: int = 480, crop: float = 1.0) -> None:
        self.width = width
        self.crop = crop
        self._prev: np.ndarray | None = None
        self._win: np.ndarray | None = None
        self._shifts = [np.zeros(2)]
        self.scale = 1.0

    def add(self, grey: np.ndarray) -> None:
        h, w = grey.shape[:2]
        self.scale = min(1.0, self.width / w)
        img = grey
        if self.scale < 1.0:
            img = cv2.resize(grey, (round(w * self.scale), round(h * self.scale)), interpolation=cv2.INTER_AREA)
        if self.crop < 1.0:
            hh, ww = img.shape
            dy, dx = round(hh * (1 - self.crop) / 2), round(ww * (1 - self.crop) / 2)
            img = img[dy : hh - dy, dx : ww - dx]
        cur = img.astype(np.float32)
        if self._win is None:
            self._win = cv2.createHanningWindow((cur.shape[1], cur.shape[0]), cv2.CV_32F)
        if self._prev is not None:
            (sx, sy), _ = cv2.phaseCorrelate(self._prev, cur, self._win)
            self._shifts.append(np.array([sx, sy]))
        self._prev = cur

    @property
    def path(self) -> np.ndarray:
        return np.cumsum(np.array(self._shifts), axis=0)
