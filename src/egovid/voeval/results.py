"""The finished cells of a run folder, read back for the report and the benchmark.

Floor cells (:mod:`egovid.voeval.floors`) are scored once per scene at the lossless level; they
are read back at every level of the run (a floor sees no video), so every table can show them.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from egovid.core.errors import EgovidError
from egovid.voeval.floors import FLOORS, is_floor
from egovid.voeval.layout import LEVELS, Factor


@dataclass
class RunResults:
    """Every cell of a run folder: ``cells[(vo, scene, level, seed)]``, with the run's odometers
    (``vos``, floors not included), floors present, scenes, levels, seeds, factor pairs and scene
    descriptions in a stable order."""

    cells: dict
    vos: list[str]
    floors: list[str]
    scenes: list[str]
    levels: list[str]
    seeds: list[int]
    factors: list[Factor]
    scene_info: dict


def load_results(out: str | os.PathLike) -> RunResults:
    """Read all cells of a run folder."""
    out = Path(out)
    if not (out / "results").exists() or not (out / "scenes.json").exists():
        raise EgovidError(f"{out} has no results", "run `egovid voeval run --out DIR` first")
    catalogue = json.loads((out / "scenes.json").read_text())
    cells = {}
    for f in sorted((out / "results").glob("*/s*/*.json")):
        c = json.loads(f.read_text())
        cells[(c["vo"], c["scene"], c["level"], c["seed"])] = c
    if not any(not is_floor(k[0]) for k in cells):
        raise EgovidError(f"{out} has no finished cells", "run `egovid voeval run --out DIR` (it resumes)")
    cfg = json.loads((out / "config.json").read_text()) if (out / "config.json").exists() else {}
    order = [*cfg.get("vos", [])]
    vos = sorted(
        {k[0] for k in cells if not is_floor(k[0])}, key=lambda v: (order.index(v) if v in order else len(order), v)
    )
    scenes = [s for s in catalogue["scenes"] if any(k[1] == s for k in cells)]
    levels = [lv for lv in LEVELS if any(k[2] == lv for k in cells if not is_floor(k[0]))]
    seeds = sorted({k[3] for k in cells})
    for (vo, scene, level, seed), c in list(cells.items()):
        if is_floor(vo) and level == "lossless":
            for lv in levels:
                cells.setdefault((vo, scene, lv, seed), c)
    floors = [f for f in FLOORS if any(k[0] == f for k in cells)]
    factors = [Factor(**f) for f in catalogue["factors"] if f["ideal"] in scenes and f["hard"] in scenes]
    return RunResults(cells, vos, floors, scenes, levels, seeds, factors, catalogue["scenes"])
