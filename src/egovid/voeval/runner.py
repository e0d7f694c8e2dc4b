"""The evaluation grid: scenes × compression levels × visual odometers, resumable.

Folder layout of a run (``--out DIR``)::

    DIR/config.json                 what was asked
    DIR/scenes/SCENE.mkv            lossless originals (FFV1) + SCENE.gt.tum + SCENE.json
    DIR/videos/SCENE__crfNN.mp4     the H.264 compression ladder
    DIR/results/VO/SCENE__LEVEL.json  one cell: status, time, pose error, OITF, RITF (+ .tum)

A cell whose JSON exists is never recomputed, so an interrupted run resumes where it stopped.
Cells run in a pool of worker processes, the slowest odometers first.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from egovid.errors import EgovidError
from egovid.io.files import atomic_write_text
from egovid.io.trajectory import Trajectory, write_tum
from egovid.io.video import VideoWriter, iter_frames
from egovid.metrics.pose_error import pose_error
from egovid.metrics.visual_error import DEFAULT_CAP_DB, visual_errors
from egovid.synth.photos import photo
from egovid.voeval.adapters import anchor_to_truth, make_vos, timed_run
from egovid.voeval.scenes import SCENES, SceneTruth, render_scene

CRFS = (18, 24, 30, 36, 42, 48)
LEVELS = ("lossless", *(f"crf{c}" for c in CRFS))
VISUAL_IMAGES = ("astronaut", "coffee", "rocket")


def default_vos() -> list[str]:
    """The built-in odometers available here (ORB-SLAM3 only where pyorbslam3 installs)."""
    from egovid.voeval.adapters import orbslam3_available

    return ["egovid", "ecc", "monovo", "colmap", *(["orbslam3"] if orbslam3_available() else [])]


@dataclass
class GridConfig:
    """What to evaluate (defaults: the thesis' ladder, short clips)."""

    vos: list[str] = field(default_factory=lambda: default_vos())
    commands: list[str] = field(default_factory=list)
    frames: int = 48
    width: int = 320
    height: int = 240
    levels: list[str] = field(default_factory=lambda: list(LEVELS))
    scenes: list[str] = field(default_factory=lambda: list(SCENES))
    cap_db: float = DEFAULT_CAP_DB
    workers: int = 2
    seed: int = 0


def video_path(out: Path, scene: str, level: str) -> Path:
    return out / "scenes" / f"{scene}.mkv" if level == "lossless" else out / "videos" / f"{scene}__{level}.mp4"


def cell_path(out: Path, vo: str, scene: str, level: str) -> Path:
    return out / "results" / vo / f"{scene}__{level}.json"


def prepare(out: Path, cfg: GridConfig, progress: Callable[[str, int, int], None] | None = None) -> None:
    """Render the scenes and their compression ladder (skipping what exists)."""
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    (out / "videos").mkdir(parents=True, exist_ok=True)
    for k, s in enumerate(cfg.scenes):
        src = out / "scenes" / f"{s}.mkv"
        if not (src.exists() and (out / "scenes" / f"{s}.json").exists()):
            truth = render_scene(s, src, frames=cfg.frames, width=cfg.width, height=cfg.height, seed=cfg.seed)
            truth.save(out / "scenes")
        for level in cfg.levels:
            if level == "lossless":
                continue
            dst = video_path(out, s, level)
            if dst.exists():
                continue
            crf = int(level.removeprefix("crf"))
            with VideoWriter(dst, cfg.width, cfg.height, 30.0, crf=crf, preset="medium") as w:
                for f in iter_frames(src):
                    w.write(f.image, f.time)
        if progress:
            progress("scenes", k + 1, len(cfg.scenes))


def run_cell(
    out: str, vo_names: list[str], commands: list[str], vo_name: str, scene: str, level: str, cap_db: float
) -> dict:
    """Evaluate one odometer on one video (runs in a worker process)."""
    out = Path(out)
    vo = next(v for v in make_vos(vo_names, commands) if v.name == vo_name)
    truth = SceneTruth.load(out / "scenes", scene)
    work = out / "work" / vo_name / f"{scene}__{level}"
    res = timed_run(vo, video_path(out, scene, level), truth.intrinsics, work)
    n = min(len(res.R), len(truth.R))
    R_gt = truth.R[:n]
    R = anchor_to_truth(res.R[:n], res.valid[:n], R_gt)
    pe = pose_error(R_gt, R)
    oitf, ritf = visual_errors([photo(p) for p in VISUAL_IMAGES], R_gt, R, truth.intrinsics, cap_db=cap_db)
    cell = {
        "vo": vo_name,
        "scene": scene,
        "level": level,
        "status": res.status,
        "message": res.message,
        "seconds": res.seconds,
        "frames": n,
        "tracked": int(res.valid[:n].sum()),
        "pose_error": pe,
        "pose_error_per_pair": pe / max(n - 1, 1),
        "oitf": oitf,
        "ritf": ritf,
        **res.extra,
    }
    dst = cell_path(out, vo_name, scene, level)
    dst.parent.mkdir(parents=True, exist_ok=True)
    write_tum(dst.with_suffix(".tum"), Trajectory(np.arange(n) / truth.fps, R))
    atomic_write_text(dst, json.dumps(cell, indent=1))
    import shutil

    shutil.rmtree(work, ignore_errors=True)
    return cell


def run_grid(out: str | os.PathLike, cfg: GridConfig, progress: Callable[[str, int, int], None] | None = None) -> dict:
    """Run every missing cell; returns {"cells": n, "computed": m, "seconds": s}."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    vos = make_vos(cfg.vos, cfg.commands)
    if not vos:
        raise EgovidError("no visual odometer to evaluate", "give --vo egovid,ecc,... or --vo-cmd")
    cfg_file = out / "config.json"
    if cfg_file.exists():
        old = json.loads(cfg_file.read_text())
        for key in ("frames", "width", "height", "seed"):
            if old.get(key) != getattr(cfg, key):
                raise EgovidError(
                    f"{out} was made with {key} = {old.get(key)}, not {getattr(cfg, key)}",
                    "use the same settings to resume, or another --out",
                )
    atomic_write_text(cfg_file, json.dumps(asdict(cfg), indent=1))
    t0 = time.perf_counter()
    prepare(out, cfg, progress)
    todo = [
        (v.name, s, lv)
        for v in vos
        for s in cfg.scenes
        for lv in cfg.levels
        if not cell_path(out, v.name, s, lv).exists()
    ]
    slow = {"colmap": 0, "orbslam3": 0}
    todo.sort(key=lambda c: slow.get(c[0], 1))
    total = len(vos) * len(cfg.scenes) * len(cfg.levels)
    done = total - len(todo)
    if progress:
        progress("cells", done, total)
    if todo:
        with ProcessPoolExecutor(max_workers=max(1, cfg.workers)) as pool:
            futs = [pool.submit(run_cell, str(out), cfg.vos, cfg.commands, v, s, lv, cfg.cap_db) for v, s, lv in todo]
            for f in as_completed(futs):
                f.result()
                done += 1
                if progress:
                    progress("cells", done, total)
    return {"cells": total, "computed": len(todo), "seconds": time.perf_counter() - t0}


def load_results(out: str | os.PathLike) -> tuple[dict, list[str], list[str], list[str]]:
    """All cells of a run: ({(vo, scene, level): cell}, vos, scenes, levels) in a stable order."""
    out = Path(out)
    if not (out / "results").exists():
        raise EgovidError(f"{out} has no results", "run `egovid voeval run --out DIR` first")
    results = {}
    for f in sorted((out / "results").glob("*/*.json")):
        c = json.loads(f.read_text())
        results[(c["vo"], c["scene"], c["level"])] = c
    cfg = json.loads((out / "config.json").read_text()) if (out / "config.json").exists() else {}
    vos = sorted({k[0] for k in results}, key=lambda v: ([*cfg.get("vos", []), v]).index(v))
    scenes = [s for s in SCENES if any(k[1] == s for k in results)]
    levels = [lv for lv in LEVELS if any(k[2] == lv for k in results)]
    return results, vos, scenes, levels
