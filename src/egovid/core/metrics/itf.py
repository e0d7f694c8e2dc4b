"""Inter-frame transformation fidelity with masks (thesis eq. 10.9–10.11 and 21.13–21.19).

ITF is the mean PSNR between consecutive frames; the higher, the steadier the video. The masked
version computes each MSE only over pixels that carry image content in both frames (eq. 10.11,
21.18–21.19). The mask comes from the homography that produced the frame, never from pixel
colour: a dark scene is not a black border.

PSNR (:mod:`egovid.core.metrics.psnr`) is taken on the 8-bit luma (BT.601 weights). Two identical
masked frames have an infinite PSNR; ``cap_db`` bounds it (default 100 dB, documented in
docs/voeval.md): a perfect result must not dominate an average.
"""

from __future__ import annotations

import cv2
import numpy as np

from egovid.core.metrics.psnr import DEFAULT_CAP_DB, masked_psnr


def luma(image: np.ndarray) -> np.ndarray:
    """8-bit luma (uint8) of a BGR or grey image."""
    if image.ndim == 2:
        return image
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


class ITFAccumulator:
    """Streaming ITF: feed frames (and masks) in order, read :attr:`value` (dB)."""

    def __init__(self, cap_db: float = DEFAULT_CAP_DB) -> None:
        self.cap_db = cap_db
        self._prev: tuple[np.ndarray, np.ndarray | None] | None = None
        self._sum = 0.0
        self._n = 0

    def add(self, image: np.ndarray, mask: np.ndarray | None = None) -> None:
        y = luma(image)
        if self._prev is not None:
            py, pm = self._prev
            both = None
            if mask is not None or pm is not None:
                both = (mask if mask is not None else True) & (pm if pm is not None else True)
            p = masked_psnr(py, y, both, self.cap_db)
            if np.isfinite(p):
                self._sum += p
                self._n += 1
        self._prev = (y, mask)

    @property
    def value(self) -> float:
        """Mean PSNR over consecutive pairs (eq. 10.9), dB."""
        return self._sum / self._n if self._n else float("nan")


def itf(frames: list[np.ndarray] | np.ndarray, masks=None, order=None, cap_db: float = DEFAULT_CAP_DB) -> float:
    """ITF of a frame sequence (eq. 21.13 with the masks of eq. 21.18); ``order`` re-orders the
    frames first (RITF uses a random permutation)."""
    idx = range(len(frames)) if order is None else order
    acc = ITFAccumulator(cap_db)
    for i in idx:
        acc.add(frames[i], None if masks is None else masks[i])
    return acc.value
