"""Which odometer for my application and my main factor (thesis §22.1.3), as one table.

Applications are the thesis' three (§21.5): robotic navigation scored by the pose error,
video stabilisation by OITF, augmented reality by RITF. For each factor of a run (the synthetic
factors, the image-level factors of every real sequence, and compression) the recommended
odometer is the one with the best score *in the challenging condition* — the challenging scene
of the pair at no compression, or for compression the ideal scene at the strongest level — with
its margin over the next one.

This departs from the example of §22.1.3, which picks the odometer *least influenced* by the
factor (Fig. 22.2 b, d, f): an odometer that fails in both conditions is not influenced at all
(the thesis notes this for SfMLearner in §22.2), so the influence answers "what hurts it", and
the score under the factor answers "what works there". Both are in the report.

An odometer that cannot work on a scene by design (one that models pure rotation, on a scene
where the camera translates close to a planar scene) is listed as out of its domain instead of
being ranked. An odometer whose cell did not run (partial or failed,
:mod:`egovid.voeval.outcome`) is never ranked: it is listed with its outcome and tracked share, so
one that produced nothing cannot come out best for scoring like "no motion". The floors
(:mod:`egovid.voeval.floors`) are given beside the winner, and a winner no better than a floor
is marked. With several seeds, a margin smaller than the spread over seeds of the paired
difference is called a tie.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from egovid.voeval.adapters import ODOMETERS
from egovid.voeval.matrices import LOWER_IS_BETTER, METRICS
from egovid.voeval.outcome import outcome, worst

APPLICATION = {"pose_error": "robotic navigation", "oitf": "video stabilisation", "ritf": "augmented reality"}


def assumes_pure_rotation(vo: str) -> bool:
    """True for the built-in odometers that model pure rotation (external commands: unknown, False)."""
    return bool(getattr(ODOMETERS.get(vo), "assumes_pure_rotation", False))


def in_domain(vo: str, motion: str) -> bool:
    """Can ``vo`` work by design on a scene whose camera motion is ``motion``?"""
    return not (motion == "translating" and assumes_pure_rotation(vo))


@dataclass
class Answer:
    """One cell of the table: the best odometer for ``metric`` under ``factor`` of ``source``."""

    source: str
    factor: str
    scene: str
    level: str
    metric: str
    ranking: list[tuple[str, float]] = field(default_factory=list)  # ran, in domain; best first, seed mean
    margin: float = float("nan")  # next minus best, in the metric's units (always >= 0)
    spread: float = 0.0  # std over seeds of the paired difference
    tie: bool = False
    out_of_domain: list[str] = field(default_factory=list)
    not_run: list[tuple[str, str, float]] = field(default_factory=list)  # (vo, outcome, tracked share)
    floors: dict[str, float] = field(default_factory=dict)  # floor -> seed mean

    @property
    def best(self) -> str | None:
        return self.ranking[0][0] if self.ranking else None

    @property
    def no_better_than(self) -> str | None:
        """The floor the winner does not beat (the better floor), or None."""
        if not self.ranking or not self.floors:
            return None
        sign = 1.0 if LOWER_IS_BETTER[self.metric] else -1.0
        floor = min(self.floors, key=lambda f: sign * self.floors[f])
        return floor if sign * self.ranking[0][1] >= sign * self.floors[floor] else None


def _cells(cells: dict, vo: str, scene: str, level: str, seeds: list[int]) -> dict[int, dict]:
    return {s: cells[(vo, scene, level, s)] for s in seeds if (vo, scene, level, s) in cells}


def answer(
    cells: dict,
    vos: list[str],
    seeds: list[int],
    source: str,
    factor: str,
    scene: str,
    level: str,
    motion: str,
    metric: str,
    floors: tuple[str, ...] = (),
) -> Answer:
    """Rank the in-domain odometers that ran by their score on ``scene`` at ``level``."""
    a = Answer(source, factor, scene, level, metric)
    sign = 1.0 if LOWER_IS_BETTER[metric] else -1.0
    per_vo = {}
    for vo in vos:
        cs = _cells(cells, vo, scene, level, seeds)
        if not cs:
            continue
        if not in_domain(vo, motion):
            a.out_of_domain.append(vo)
            continue
        how = worst(c.get("outcome") or outcome(c) for c in cs.values())
        if how != "ran":
            share = float(np.mean([c["tracked"] / max(c["frames"], 1) for c in cs.values()]))
            a.not_run.append((vo, how, share))
            continue
        per_vo[vo] = {s: c[metric] for s, c in cs.items()}
    for f in floors:
        cs = _cells(cells, f, scene, level, seeds)
        if cs:
            a.floors[f] = float(np.mean([c[metric] for c in cs.values()]))
    order = sorted(per_vo, key=lambda v: sign * float(np.mean(list(per_vo[v].values()))))
    a.ranking = [(v, float(np.mean(list(per_vo[v].values())))) for v in order]
    if len(order) >= 2:
        best, nxt = per_vo[order[0]], per_vo[order[1]]
        common = sorted(set(best) & set(nxt))
        d = np.array([sign * (nxt[s] - best[s]) for s in common])
        a.margin = abs(a.ranking[1][1] - a.ranking[0][1])
        a.spread = float(np.std(d)) if len(d) > 1 else 0.0
        a.tie = len(d) > 1 and a.margin <= a.spread
    return a


def answers(run) -> list[list[Answer]]:
    """One row per real sequence as recorded, per factor (synthetic, each real sequence's) and per
    compression (each ideal scene and real sequence at the strongest level), one Answer per application."""
    rows: list[list[Answer]] = []
    if "lossless" not in run.levels:
        return rows
    info = run.scene_info

    def row(source: str, factor: str, scene: str, level: str) -> list[Answer]:
        motion = info[scene]["motion"]
        args = (run.cells, run.vos, run.seeds, source, factor, scene, level, motion)
        return [answer(*args, m, floors=tuple(run.floors)) for m in METRICS]

    real = [s for s in run.scenes if info[s]["kind"] == "real"]
    for s in real:  # the user's own footage as recorded: which VO does best on it at all
        rows.append(row(s, "as recorded", s, "lossless"))
    for f in run.factors:
        rows.append(row(f.source, f.name, f.hard, "lossless"))
    strongest = run.levels[-1]
    if strongest != "lossless":
        for s in dict.fromkeys([*(f.ideal for f in run.factors), *real]):
            src = "synthetic" if info[s]["kind"] == "synthetic" else s
            label = f"compression ({s}, {strongest})" if src == "synthetic" else f"compression ({strongest})"
            rows.append(row(src, label, s, strongest))
    return rows
