"""The default `egovid voeval run` grid at its realistic scale, and the same cells on a Dask cluster.

Default grid: every available odometer (egovid, ECC, Mono-VO, COLMAP, ORB-SLAM3 where it installs)
x 6 synthetic scenes (factors feature, data, sensor, motion; compression across) x 7 compression
levels, 300-frame 640x480 clips, one seed. Target: <= 30 minutes on this 2-core machine.

Modes (``--mode``):

* ``local`` — the grid as `egovid voeval run` runs it without a scheduler: a local pool of two
  worker processes (Dask LocalCluster), scenes and ladder included in the time;
* ``cluster`` — a separate `dask scheduler` and `dask worker --nworkers 2 --nthreads 1` on
  127.0.0.1 (what `--scheduler tcp://HOST:PORT` talks to), same grid;
* ``both`` — local, then the cluster on a copy of the prepared scenes (cells only), to compare
  per-cell times of the same cells.

``--vos``, ``--scenes``, ``--levels`` and ``--seeds`` run a part of the grid (a sample of its
cells). Prints the total time, seconds per cell by odometer (mean, max; whole cells: odometer plus
pose error, OITF and RITF) and by stage, the cell statuses, and an extrapolation of the *full*
default grid from the sample (``full_grid_estimate``): every (odometer, scene family, level) cell
not measured takes the mean of that odometer's measured cells of the same scene family (orbit or
pano); each scene's render takes its measured time (``prepare_seconds`` in the scene's JSON; a
scene not rendered, the slowest of its family); each scene's ladder task the sample's per-scene
ladder time scaled by 6 / rungs sampled (CPU of a 6-rung task over a 2-rung one, measured: 2.9 to
3.1); all of it packed on the two workers, plus the longest cell once for the tail. Writes the
report (bench-output/voeval[-cluster]/report.html, report.md, matrices.json).

Measured on this 2-core machine, shared: run the sample with /work/coord/bin/timed (both cores).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
from collections import defaultdict
from pathlib import Path

import numpy as np

from egovid.core.engine import EngineConfig, spawn_cluster
from egovid.voeval.floors import FLOORS, is_floor
from egovid.voeval.layout import LEVELS
from egovid.voeval.results import load_results
from egovid.voeval.runner import GridConfig, evaluate

from _common import cache_dir, report

WORKERS = 2


def _family(scene: str) -> str:
    return scene.split("-")[0]


def extrapolate(out: Path, run, r: dict, cfg: GridConfig) -> dict:
    """Wall minutes of the full default grid (every available odometer x 6 scenes x 7 levels, one
    seed, 2 workers) from the cells and stage times of a sampled run (see the module doc)."""
    full = GridConfig()
    by = defaultdict(list)
    for (vo, scene, lv, _s), c in run.cells.items():
        if is_floor(vo) and lv != "lossless":  # a floor is scored once per scene (read back at every level)
            continue
        t = c.get("cell_seconds", c["seconds"])
        by[(vo, _family(scene), lv)].append(t)
        by[(vo, _family(scene))].append(t)
    missing = [v for v in full.vos if not any(k[0] == v for k in by)]
    cell_s, longest = 0.0, 0.0
    for vo in [*full.vos, *FLOORS]:
        for scene in full.scenes:
            for lv in ["lossless"] if is_floor(vo) else full.levels:
                ts = by.get((vo, _family(scene), lv)) or by.get((vo, _family(scene))) or []
                if ts:
                    cell_s += float(np.mean(ts))
                    longest = max(longest, float(np.max(ts)))
    # Renders: each scene's own time (scene JSON); a scene not rendered takes the slowest of its
    # family (pano-ideal is cheaper than pano-motion's rolling shutter + blur: an upper bound).
    render = {}
    for seed in cfg.seeds:
        for f in (out / "scenes" / f"s{seed}").glob("*.json"):
            meta = json.loads(f.read_text())
            if "prepare_seconds" in meta:
                render[meta["name"]] = meta["prepare_seconds"]
    fam = defaultdict(list)
    for name, t in render.items():
        fam[_family(name)].append(t)
    render_s = sum(render.get(s, max(fam.get(_family(s)) or [max(render.values(), default=0.0)])) for s in full.scenes)
    # Ladder: one task per scene decodes its lossless video once and encodes every rung; the
    # sample's per-scene ladder time scaled by rungs (6 / rungs sampled; the decode is counted as
    # often: an upper bound).
    n_scenes = len(cfg.scenes) * len(cfg.seeds)
    rungs = sum(1 for lv in cfg.levels if lv != "lossless")
    ladder_scene = stages_per_task = 0.0
    if rungs and n_scenes:
        stages_per_task = r["stages"].get("ladder", 0.0) * min(WORKERS, n_scenes) / n_scenes
        ladder_scene = stages_per_task * (len(full.levels) - 1) / rungs
    total = (render_s + len(full.scenes) * ladder_scene + cell_s) / WORKERS + longest
    return {
        "grid": f"{len(full.vos)} VOs x {len(full.scenes)} scenes x {len(full.levels)} levels, "
        f"{full.frames} frames {full.width}x{full.height}, 1 seed",
        "cells": len(full.vos) * len(full.scenes) * len(full.levels),
        "sampled_cells": r["cells"],
        "render_seconds_per_scene": render,
        "render_seconds_full": render_s,
        "ladder_seconds_per_scene_sampled": stages_per_task,
        "ladder_seconds_per_scene_full": ladder_scene,
        "cell_cpu_minutes": cell_s / 60,
        "wall_minutes": total / 60,
        "meets_30_min": total <= 30 * 60 and not missing,
        "vos_not_sampled": missing,
    }


def summary(out: Path, seconds: float, r: dict, mode: str, cfg: GridConfig) -> dict:
    run = load_results(out)
    per_vo, status = defaultdict(list), defaultdict(lambda: defaultdict(int))
    per_scene, per_cell, per_cpu = defaultdict(list), defaultdict(list), defaultdict(list)
    for (vo, scene, lv, _s), c in run.cells.items():
        if is_floor(vo) and lv != "lossless":
            continue
        per_vo[vo].append(c["seconds"])
        per_cpu[vo].append(c.get("cpu_seconds", float("nan")))
        per_cell[vo].append(c.get("cell_seconds", c["seconds"]))
        per_scene[scene].append(c.get("cell_seconds", c["seconds"]))
        status[vo][c["status"]] += 1
    return {
        "mode": mode,
        "cells": r["cells"],
        "computed": r["computed"],
        "stage_minutes": {k: v / 60 for k, v in r["stages"].items()},
        "total_minutes": seconds / 60,
        "target_minutes": 30,
        "meets_target": seconds <= 30 * 60,
        "cores": os.cpu_count(),
        "vo_seconds_per_cell": {
            v: {"mean": float(np.mean(t)), "max": float(np.max(t)), "n": len(t)} for v, t in per_vo.items()
        },
        "cell_seconds_per_vo": {
            v: {"mean": float(np.mean(t)), "max": float(np.max(t)), "n": len(t)} for v, t in per_cell.items()
        },
        "cell_seconds_per_scene": {s: float(np.mean(t)) for s, t in per_scene.items()},
        # CPU seconds of the odometer itself (its process and the processes it started): unlike the
        # wall times above, not inflated when other work shares the machine.
        "vo_cpu_seconds_per_cell": {v: float(np.mean(t)) for v, t in per_cpu.items()},
        "status": {v: dict(s) for v, s in status.items()},
        "full_grid_estimate": extrapolate(out, run, r, cfg),
        "report": str(out / "report.html"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mode", choices=("local", "cluster", "both"), default="local")
    ap.add_argument("--vos", help="odometers (default: every available one)")
    ap.add_argument("--scenes", help="synthetic scenes (default: all six)")
    ap.add_argument("--levels", default=",".join(LEVELS))
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--quick", action="store_true", help="the --quick grid (48 frames, 320x240)")
    ap.add_argument("--resume", action="store_true", help="keep finished cells of an earlier run")
    a = ap.parse_args()
    cfg = GridConfig(levels=a.levels.split(","), seeds=[int(s) for s in a.seeds.split(",")])
    if a.vos:
        cfg.vos = a.vos.split(",")
    if a.scenes:
        cfg.scenes = a.scenes.split(",")
    if a.quick:
        cfg.frames, cfg.width, cfg.height = 48, 320, 240
    out = cache_dir("voeval")
    if a.mode in ("local", "both"):
        if not a.resume:
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir(parents=True)
        r = evaluate(out, cfg, EngineConfig(workers=2))
        report("voeval_grid", summary(out, r["seconds"], r, "local: LocalCluster, 2 worker processes", cfg))
    if a.mode in ("cluster", "both"):
        cl = cache_dir("voeval-cluster")
        if not a.resume:
            shutil.rmtree(cl, ignore_errors=True)
            cl.mkdir(parents=True)
        if a.mode == "both":  # same prepared scenes and ladder: the cluster run times the cells only
            for sub in ("scenes", "videos"):
                shutil.copytree(out / sub, cl / sub, dirs_exist_ok=True)
        with spawn_cluster(cl / "dask", workers=WORKERS) as address:
            r = evaluate(cl, cfg, EngineConfig(scheduler=address))
        report("voeval_grid", summary(cl, r["seconds"], r, f"cluster: dask scheduler + 2 workers at {address}", cfg))


if __name__ == "__main__":
    main()
