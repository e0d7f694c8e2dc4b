"""Peak signal-to-noise ratio of 8-bit pictures: the one PSNR rule of egovid.

``PSNR = 10 log10(255² / MSE)`` dB, capped at ``cap_db``: identical pictures (MSE 0) have an
infinite PSNR, and a perfect result must not dominate an average. :func:`masked_psnr` takes the
MSE over the pixels of a mask (content in both pictures); :func:`psnr_db` turns an MSE that was
accumulated elsewhere (e.g. over a whole segment) into dB by the same rule.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

#: The cap (dB) of ITF and the codec's figures (docs/voeval.md).
DEFAULT_CAP_DB = 100.0


def psnr_db(mse: float, cap_db: float = DEFAULT_CAP_DB) -> float:
    """PSNR (dB) of 8-bit pictures whose mean squared error is ``mse`` (grey levels²), at most
    ``cap_db``."""
    if mse <= 255.0**2 * 10 ** (-cap_db / 10):
        return cap_db
    return 10.0 * math.log10(255.0**2 / mse)


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None, cap_db: float = DEFAULT_CAP_DB) -> float:
    """PSNR (dB) of two 8-bit luma images over ``mask`` (bool, True = content); NaN if it is empty."""
    if mask is not None:
        m8 = mask.view(np.uint8) if mask.dtype == bool else mask
        n = int(cv2.countNonZero(m8))
        if n == 0:
            return float("nan")
        mse = cv2.norm(a, b, cv2.NORM_L2SQR, m8) / n
    else:
        mse = cv2.norm(a, b, cv2.NORM_L2SQR) / a.size
    return psnr_db(mse, cap_db)
