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

**What is left out.** A pair whose ideal or challenging cell did not run (outcome ``partial`` or
``failed``, :func:`egovid.voeval.cell.outcome`) gives no value: its scores would be those of "no
motion", not of the odometer under the factor. Such pairs are NaN in every matrix and listed in
``left_out`` (odometer, factor, level, which scene and why), which the report prints.
"""

from __future__ import annotations

import warnings

import numpy as np

from egovid.voeval.evo_errors import EVO_METRICS
from egovid.voeval.layout import Factor
from egovid.voeval.outcome import outcome, worst

#: The thesis' three metrics (the factor matrices and the recommendation use these).
METRICS = ("pose_error", "oitf", "ritf")
#: Every metric of a cell: the thesis' and the standard ATE / RPE.
ALL_METRICS = (*METRICS, *EVO_METRICS)
LOWER_IS_BETTER = {"pose_error": True, "oitf": False, "ritf": False, **dict.fromkeys(EVO_METRICS, True)}

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


def _mean(values: list) -> float:
    """Mean of a metric over seeds; NaN when any seed has no value (None)."""
    return float("nan") if any(v is None for v in values) else float(np.mean(values))


def mean_over_seeds(cells: dict) -> dict:
    """``{(vo, scene, level): {metric: mean over seeds, "outcome": worst over seeds, "tracked_share":
    mean}}`` from ``{(vo, scene, level, seed): cell}`` (a metric a cell lacks is NaN)."""
    groups: dict = {}
    for (vo, scene, level, _seed), c in cells.items():
        groups.setdefault((vo, scene, level), []).append(c)
    out = {}
    for k, v in groups.items():
        out[k] = {m: _mean([c.get(m, float("nan")) for c in v]) for m in ALL_METRICS}
        out[k]["outcome"] = worst(c.get("outcome") or outcome(c) for c in v)
        out[k]["tracked_share"] = float(np.mean([c["tracked"] / max(c["frames"], 1) for c in v]))
    return out


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
    "absolute") and [vo, factor] ("compression"), and ``left_out``: the (vo, factor, level) pairs
    without a value because a cell did not run.
    """
    if norm not in NORMS:
        raise ValueError(f"unknown normalisation {norm!r}")
    shape = (len(vos), len(factors), len(levels))
    sources = list(dict.fromkeys(f.source for f in factors))
    out: dict = {"factors": [f.label for f in factors], "vos": vos, "levels": levels, "norm": norm}
    out["left_out"] = left_out(results, vos, levels, factors)
    skip = {(d["vo"], d["factor"], d["level"]) for d in out["left_out"]}
    for metric in METRICS:
        diff = np.full(shape, np.nan)
        rel = np.full(shape, np.nan)
        for i, vo in enumerate(vos):
            for k, f in enumerate(factors):
                for j, lv in enumerate(levels):
                    a, b = results.get((vo, f.ideal, lv)), results.get((vo, f.hard, lv))
                    if a is None or b is None or (vo, f.label, lv) in skip:
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


def left_out(results: dict, vos: list[str], levels: list[str], factors: list[Factor]) -> list[dict]:
    """Factor pairs with a cell that did not run: ``{"vo", "factor", "level", "scene", "outcome",
    "tracked_share"}`` (the first such scene of the pair), in the matrices' order."""
    out = []
    for vo in vos:
        for f in factors:
            for lv in levels:
                for scene in (f.ideal, f.hard):
                    r = results.get((vo, scene, lv))
                    if r is not None and r.get("outcome", "ran") != "ran":
                        share = r.get("tracked_share", 0.0)
                        out.append(
                            {
                                "vo": vo,
                                "factor": f.label,
                                "level": lv,
                                "scene": scene,
                                "outcome": r["outcome"],
                                "tracked_share": share,
                            }
                        )
                        break
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
        v = c.get(metric)
        groups.setdefault((vo, scene, level), []).append(np.nan if v is None else v)
    a = np.full((len(vos), len(scenes), len(levels)), np.nan)
    for i, vo in enumerate(vos):
        for m, s in enumerate(scenes):
            for j, lv in enumerate(levels):
                v = groups.get((vo, s, lv))
                if v:
                    a[i, m, j] = float(np.std(v))
    return a
