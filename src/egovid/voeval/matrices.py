"""Factor-based performance matrices (thesis §22.1–22.2).

From the absolute results ``E(i, CRF_j, m)`` (VO i, compression level j, scene m; E = pose error,
OITF or RITF; averaged over seeds) and the factor pairs (ideal scene, challenging scene):

* **relative influence** (eq. 22.2–22.4)::

      E_factor = (E(m) - E(n)) / ΔITF(n),   ΔITF = OITF - RITF                    (22.2, 22.3)
      E_factor = E_factor / |max_k E_factor|                                       (22.4)

  with n = the ideal scene for the pose error and m = the ideal scene for OITF/RITF (so a factor
  that hurts gives a positive value). ΔITF is zero for a perfect or a totally failed estimate
  (OITF = RITF) and may be slightly negative for jitter without drift; eq. 22.2 would then divide
  by zero or flip the sign, so ΔITF is floored at ``min_delta`` (0.5 dB). The maximum of eq. 22.4
  runs over the factors of one source (the synthetic factors, or the factors of one real
  sequence), per VO and level. As the equation says, it is the magnitude of the largest value,
  not the largest magnitude: when no factor hurts (every value ≤ 0) the values fall below -1.
* **absolute influence** (eq. 22.5–22.6): ``E(m) - E(n)`` divided by ``|max_i|`` over the VOs.
* **influence of compression** (Tables 22.1–22.3): the standard deviation over the compression
  levels of the eq. 22.5 difference, per VO and factor.

``norm="max_abs"`` reproduces what egovid did before (ΔITF as ``|OITF - RITF|``, normalisers
``max |E|``), so the effect of the choice can be measured (docs/voeval.md).
"""

from __future__ import annotations

import warnings

import numpy as np

from egovid.voeval.layout import Factor

METRICS = ("pose_error", "oitf", "ritf")
LOWER_IS_BETTER = {"pose_error": True, "oitf": False, "ritf": False}
MIN_DELTA_DB = 0.5
NORMS = ("thesis", "max_abs")


def normalise(a: np.ndarray, axis: int, norm: str = "thesis") -> np.ndarray:
    """Divide by ``|max a|`` (thesis) or ``max |a|`` along ``axis``; NaN stays NaN, and a slice whose
    normaliser is zero gives NaN (no difference to normalise)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        m = (
            np.abs(np.nanmax(a, axis=axis, keepdims=True))
            if norm == "thesis"
            else np.nanmax(np.abs(a), axis=axis, keepdims=True)
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.isfinite(a) & (m > 0), a / np.where(m > 0, m, 1.0), np.nan)


def mean_over_seeds(cells: dict) -> dict:
    """``{(vo, scene, level): {metric: mean over seeds}}`` from ``{(vo, scene, level, seed): cell}``."""
    groups: dict = {}
    for (vo, scene, level, _seed), c in cells.items():
        groups.setdefault((vo, scene, level), []).append(c)
    return {k: {m: float(np.mean([c[m] for c in v])) for m in METRICS} for k, v in groups.items()}


def factor_matrices(
    results: dict,
    vos: list[str],
    levels: list[str],
    factors: list[Factor],
    *,
    norm: str = "thesis",
    min_delta: float = MIN_DELTA_DB,
) -> dict:
    """All matrices from ``results[(vo, scene, level)] = {"pose_error", "oitf", "ritf"}``.

    Returns, per metric, arrays indexed [vo, factor, level] ("difference", "relative",
    "absolute") and [vo, factor] ("compression").
    """
    if norm not in NORMS:
        raise ValueError(f"unknown normalisation {norm!r}")
    shape = (len(vos), len(factors), len(levels))
    sources = list(dict.fromkeys(f.source for f in factors))
    out: dict = {"factors": [f.label for f in factors], "vos": vos, "levels": levels, "norm": norm}
    for metric in METRICS:
        diff = np.full(shape, np.nan)
        rel = np.full(shape, np.nan)
        for i, vo in enumerate(vos):
            for k, f in enumerate(factors):
                for j, lv in enumerate(levels):
                    a, b = results.get((vo, f.ideal, lv)), results.get((vo, f.hard, lv))
                    if a is None or b is None:
                        continue
                    if LOWER_IS_BETTER[metric]:
                        d, n_scene = b[metric] - a[metric], a  # scene n = ideal
                    else:
                        d, n_scene = a[metric] - b[metric], b  # scene m = ideal, n = challenging
                    delta = n_scene["oitf"] - n_scene["ritf"]
                    delta = max(delta if norm == "thesis" else abs(delta), min_delta)
                    diff[i, k, j] = d
                    rel[i, k, j] = d / delta
        relative = np.full(shape, np.nan)
        for src in sources:
            idx = [k for k, f in enumerate(factors) if f.source == src]
            relative[:, idx, :] = normalise(rel[:, idx, :], axis=1, norm=norm)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            ic = np.nanstd(diff, axis=2)
        out[metric] = {
            "difference": diff,
            "relative": relative,
            "absolute": normalise(diff, axis=0, norm=norm),
            "compression": ic,
        }
    return out


def absolute_matrix(results: dict, vos: list[str], scenes: list[str], levels: list[str], metric: str) -> np.ndarray:
    """E(vo, scene, level) as an array (NaN where missing)."""
    a = np.full((len(vos), len(scenes), len(levels)), np.nan)
    for i, vo in enumerate(vos):
        for m, s in enumerate(scenes):
            for j, lv in enumerate(levels):
                r = results.get((vo, s, lv))
                if r is not None:
                    a[i, m, j] = r[metric]
    return a


def seed_spread(cells: dict, vos: list[str], scenes: list[str], levels: list[str], metric: str) -> np.ndarray:
    """Standard deviation over seeds of E(vo, scene, level) (0 with one seed, NaN where missing)."""
    groups: dict = {}
    for (vo, scene, level, _seed), c in cells.items():
        groups.setdefault((vo, scene, level), []).append(c[metric])
    a = np.full((len(vos), len(scenes), len(levels)), np.nan)
    for i, vo in enumerate(vos):
        for m, s in enumerate(scenes):
            for j, lv in enumerate(levels):
                v = groups.get((vo, s, lv))
                if v:
                    a[i, m, j] = float(np.std(v))
    return a
