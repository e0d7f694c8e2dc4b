"""Factor-based performance matrices (thesis §22.1–22.2).

From the absolute results ``E(i, CRF_j, m)`` (VO i, compression level j, scene m; E = pose error,
OITF or RITF) and the factor pairs (ideal scene, challenging scene):

* **relative influence** (eq. 22.2–22.4): ``(E(challenging) - E(ideal)) / ΔITF`` for the pose error
  and ``(E(ideal) - E(challenging)) / ΔITF`` for OITF/RITF (both positive when the factor hurts),
  with ``ΔITF = OITF - RITF`` of the scene named n in eq. 22.2, then divided by the largest
  magnitude over the factors of that VO and level. ΔITF near zero (a perfect or a totally failed
  estimate makes OITF = RITF) would blow the ratio up: it is floored at ``min_delta`` dB.
* **absolute influence** (eq. 22.5–22.6): the same differences unnormalised by ΔITF, divided by the
  largest magnitude over the VOs for that factor and level.
* **influence of compression** (Tables 22.1–22.3): the standard deviation over the compression
  levels of the eq. 22.5 difference, per VO and factor.
"""

from __future__ import annotations

import warnings

import numpy as np

from egovid.voeval.scenes import FACTORS

METRICS = ("pose_error", "oitf", "ritf")
LOWER_IS_BETTER = {"pose_error": True, "oitf": False, "ritf": False}
MIN_DELTA_DB = 0.5


def _normalise(a: np.ndarray, axis: int) -> np.ndarray:
    """Divide by the largest magnitude along ``axis``; missing values stay NaN."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        m = np.nanmax(np.abs(a), axis=axis, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.isfinite(a), np.where(m > 0, a / m, 0.0), np.nan)


def factor_matrices(results: dict, vos: list[str], crfs: list[str], min_delta: float = MIN_DELTA_DB) -> dict:
    """All matrices from ``results[(vo, scene, crf)] = {"pose_error": .., "oitf": .., "ritf": ..}``.

    Returns arrays indexed [vo, factor, crf] ("relative", "absolute", "difference") and
    [vo, factor] ("compression") per metric, plus the factor names.
    """
    factors = list(FACTORS)
    out: dict = {"factors": factors, "vos": vos, "crfs": crfs}
    shape = (len(vos), len(factors), len(crfs))
    for metric in METRICS:
        diff = np.full(shape, np.nan)
        rel = np.full(shape, np.nan)
        for i, vo in enumerate(vos):
            for k, f in enumerate(factors):
                ideal, hard = FACTORS[f]
                for j, c in enumerate(crfs):
                    a, b = results.get((vo, ideal, c)), results.get((vo, hard, c))
                    if a is None or b is None:
                        continue
                    if LOWER_IS_BETTER[metric]:
                        d = b[metric] - a[metric]  # scene n = ideal
                        ref = a
                    else:
                        d = a[metric] - b[metric]  # scene m = ideal
                        ref = b
                    delta = max(abs(ref["oitf"] - ref["ritf"]), min_delta)
                    diff[i, k, j] = d
                    rel[i, k, j] = d / delta
        out[metric] = {
            "difference": diff,
            "relative": _normalise(rel, axis=1),
            "absolute": _normalise(diff, axis=0),
            "compression": _nanstd(diff, axis=2),
        }
    return out


def _nanstd(a: np.ndarray, axis: int) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanstd(a, axis=axis)


def absolute_matrix(results: dict, vos: list[str], scenes: list[str], crfs: list[str], metric: str) -> np.ndarray:
    """E(vo, scene, crf) as an array (NaN where missing)."""
    a = np.full((len(vos), len(scenes), len(crfs)), np.nan)
    for i, vo in enumerate(vos):
        for m, s in enumerate(scenes):
            for j, c in enumerate(crfs):
                r = results.get((vo, s, c))
                if r is not None:
                    a[i, m, j] = r[metric]
    return a
