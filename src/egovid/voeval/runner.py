"""The evaluation grid: scenes × compression levels × seeds × visual odometers, on the task engine.

:func:`run_grid` prepares the test videos (synthetic renders, imported real sequences, their
degraded copies, the H.264 ladder) and then evaluates every missing cell, each stage as
independent tasks on :mod:`egovid.core.engine`: in this process, on a local pool of worker processes
(the default), or on a Dask cluster (``--scheduler``; the run folder must then be reachable at the
same path from every worker). Every output is written atomically by the task that makes it and
is skipped when it exists, so an interrupted run resumes where it stopped and a task that runs
twice (its worker was killed, Dask ran it again elsewhere) does no harm.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

from egovid.core.engine import EngineConfig, open_client, run_tasks
from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_text
from egovid.core.metrics.visual_error import DEFAULT_CAP_DB
from egovid.core.video import VideoWriter, iter_frames
from egovid.voeval.cell import ANCHORS, CellJob, evaluate_cell
from egovid.voeval.degrade import REAL_FACTORS
from egovid.voeval.layout import LEVELS, Factor, cell_path, scene_dir, video_path
from egovid.voeval.scenes import FACTORS, SCENES, SceneTruth, render_scene

#: Realistic default (issue 16): 640x480, 300 frames; ``--quick`` is the old smoke-test grid.
DEFAULT_FRAMES, DEFAULT_SIZE = 300, (640, 480)
QUICK_FRAMES, QUICK_SIZE = 48, (320, 240)
#: Settings that change a cell's numbers: a run folder cannot be resumed with other values.
RESULT_KEYS = ("frames", "width", "height", "cap_db", "anchor")
#: Odometers that take longest start first, so the grid does not end waiting on one slow cell.
SLOW_FIRST = {"colmap": 0, "orbslam3": 1, "egovid": 2}


def default_vos() -> list[str]:
    """Every built-in odometer that can run here (ORB-SLAM3 only where pyorbslam3 installs)."""
    from egovid.voeval.adapters import available_vos

    return available_vos()


@dataclass
class GridConfig:
    """What to evaluate. ``sequences`` are ``FORMAT:PATH`` specs; ``scenes`` the synthetic scenes
    (empty: real sequences only); ``real_factors`` the image-level factors applied to real frames."""

    vos: list[str] = field(default_factory=default_vos)
    commands: list[str] = field(default_factory=list)
    frames: int = DEFAULT_FRAMES
    width: int = DEFAULT_SIZE[0]
    height: int = DEFAULT_SIZE[1]
    levels: list[str] = field(default_factory=lambda: list(LEVELS))
    scenes: list[str] = field(default_factory=lambda: list(SCENES))
    sequences: list[str] = field(default_factory=list)
    real_factors: list[str] = field(default_factory=lambda: list(REAL_FACTORS))
    seeds: list[int] = field(default_factory=lambda: [0])
    cap_db: float = DEFAULT_CAP_DB
    anchor: str = "none"
    preset: str = "medium"

    def check(self) -> None:
        """Raise :class:`EgovidError` for settings that cannot work, before any work starts."""
        bad = [x for x in self.levels if x not in LEVELS]
        if bad or not self.levels:
            raise EgovidError(
                f"unknown compression level(s) {', '.join(bad) or '(none)'}", f"use some of {', '.join(LEVELS)}"
            )
        bad = [x for x in self.scenes if x not in SCENES]
        if bad:
            raise EgovidError(f"unknown scene(s) {', '.join(bad)}", f"use some of {', '.join(SCENES)}")
        bad = [x for x in self.real_factors if x not in REAL_FACTORS]
        if bad:
            raise EgovidError(
                f"unknown real-frame factor(s) {', '.join(bad)}", f"use some of {', '.join(REAL_FACTORS)}"
            )
        if self.anchor not in ANCHORS:
            raise EgovidError(f"unknown anchoring {self.anchor!r}", f"use one of {', '.join(ANCHORS)}")
        if not self.seeds or any(s < 0 for s in self.seeds) or len(set(self.seeds)) != len(self.seeds):
            raise EgovidError(f"seeds {self.seeds} are not distinct non-negative integers", "write e.g. --seeds 0,1,2")
        if not self.scenes and not self.sequences:
            raise EgovidError(
                "nothing to evaluate: no synthetic scene and no --sequence", "drop --no-synthetic or add --sequence"
            )
        if self.frames < 10:
            raise EgovidError(f"{self.frames} frames per scene are too few", "use at least 10")


@dataclass(frozen=True)
class SceneJob:
    """One scene to prepare: a synthetic render, a real import, or a real scene degraded by a factor."""

    out: str
    kind: str  # synthetic | real | derived
    name: str
    seed: int
    frames: int
    width: int
    height: int
    source: str = ""  # FORMAT:PATH of a real sequence; the base scene of a derived one
    factor: str = ""

    @property
    def seeded(self) -> bool:
        return self.kind != "real"


@dataclass(frozen=True)
class EncodeJob:
    """The missing rungs of one scene's compression ladder."""

    out: str
    scene: str
    seed: int
    seeded: bool
    levels: tuple[str, ...]
    preset: str


def prepare_scene(job: SceneJob) -> str:
    """Render, import or degrade one scene (skipped when its truth exists); returns its name."""
    from egovid.voeval.degrade import degrade_scene
    from egovid.voeval.sequences import import_sequence, open_sequence, parse_specs

    out = Path(job.out)
    folder = scene_dir(out, job.seed, job.seeded)
    folder.mkdir(parents=True, exist_ok=True)
    if (folder / f"{job.name}.json").exists():
        return job.name
    video = folder / f"{job.name}.mkv"
    t = time.perf_counter()
    if job.kind == "synthetic":
        truth = render_scene(job.name, video, frames=job.frames, width=job.width, height=job.height, seed=job.seed)
    elif job.kind == "real":
        [spec] = parse_specs([job.source])
        spec = type(spec)(spec.fmt, spec.path, job.name)
        if spec.fmt == "gyro":
            from egovid.voeval.gyro_reference import import_gyro_sequence

            truth = import_gyro_sequence(spec, video, job.frames)
        else:
            truth = import_sequence(open_sequence(spec), video, job.frames)
        truth.meta["source"] = spec.text
    else:
        base_dir = scene_dir(out, job.seed, seeded=False)
        base = SceneTruth.load(base_dir, job.source)
        truth = degrade_scene(base_dir / f"{job.source}.mkv", base, job.factor, job.seed, video)
    truth.meta["prepare_seconds"] = round(time.perf_counter() - t, 2)  # render / import / degrade
    truth.save(folder)
    return job.name


def encode_levels(job: EncodeJob) -> list[str]:
    """Encode one scene at every missing CRF of the ladder, decoding its lossless video once (each
    rung is its own x264 encoder, one thread: the same file as encoding the rungs one by one)."""
    out = Path(job.out)
    dsts = {lv: video_path(out, job.scene, lv, job.seed, job.seeded) for lv in job.levels}
    todo = {lv: d for lv, d in dsts.items() if not d.exists()}
    if todo:
        src = video_path(out, job.scene, "lossless", job.seed, job.seeded)
        truth = SceneTruth.load(src.parent, job.scene)
        i = truth.intrinsics
        with contextlib.ExitStack() as stack:
            writers = []
            for lv, dst in todo.items():
                dst.parent.mkdir(parents=True, exist_ok=True)
                crf = int(lv.removeprefix("crf"))
                writers.append(
                    stack.enter_context(
                        VideoWriter(dst, i.width, i.height, truth.fps, crf=crf, preset=job.preset, threads=1)
                    )
                )
            for f in iter_frames(src):
                for w in writers:
                    w.write(f.image, f.time)
    return [str(d) for d in dsts.values()]


def guarded(task: tuple[Callable, object]) -> object:
    """Run ``fn(job)`` of ``task = (fn, job)`` on a worker; a user error (a bad input found only
    while working) comes back as the value, so it is reported once, plainly, and not retried."""
    fn, job = task
    try:
        return fn(job)
    except EgovidError as exc:
        return exc


def _folder_visible(path: str) -> bool:
    return (Path(path) / "config.json").exists()


def scene_jobs(out: Path, cfg: GridConfig) -> tuple[list[SceneJob], list[SceneJob], list[Factor]]:
    """(first-stage jobs, degraded-scene jobs, factor pairs) of a configuration."""
    from egovid.voeval.sequences import parse_specs

    first = [
        SceneJob(str(out), "synthetic", s, seed, cfg.frames, cfg.width, cfg.height)
        for seed in cfg.seeds
        for s in cfg.scenes
    ]
    factors = [Factor("synthetic", f, a, b) for f, (a, b) in FACTORS.items() if a in cfg.scenes and b in cfg.scenes]
    derived = []
    for spec in parse_specs(cfg.sequences):
        first.append(SceneJob(str(out), "real", spec.name, 0, cfg.frames, 0, 0, source=spec.text))
        for f in cfg.real_factors:
            derived += [
                SceneJob(str(out), "derived", f"{spec.name}+{f}", seed, cfg.frames, 0, 0, spec.name, f)
                for seed in cfg.seeds
            ]
            factors.append(Factor(spec.name, f, spec.name, f"{spec.name}+{f}"))
    return first, derived, factors


def check_sequences(out: Path, jobs: list[SceneJob]) -> None:
    """Read every real sequence not imported yet (lists, calibration, reference; not the images),
    so a bad one is reported before any work starts."""
    from egovid.voeval.sequences import open_sequence, parse_specs

    for job in jobs:
        if job.kind != "real" or (scene_dir(out, 0, False) / f"{job.name}.json").exists():
            continue
        [spec] = parse_specs([job.source])
        if spec.fmt == "gyro":
            from egovid.voeval.gyro_reference import check_gyro_video

            check_gyro_video(spec.path)
        else:
            open_sequence(spec)


def _check_resume(out: Path, cfg: GridConfig) -> None:
    cfg_file = out / "config.json"
    if not cfg_file.exists():
        return
    try:
        old = json.loads(cfg_file.read_text())
    except (OSError, json.JSONDecodeError):
        raise EgovidError(f"{cfg_file} is unreadable", "remove the run folder or use another --out") from None
    for key in RESULT_KEYS:
        if key in old and old[key] != getattr(cfg, key):
            raise EgovidError(
                f"{out} was made with {key} = {old[key]}, not {getattr(cfg, key)}",
                "use the same settings to resume, or another --out",
            )


def _raise_failures(stage: str, failures: list) -> None:
    if failures:
        key, err = failures[0]
        if isinstance(err, EgovidError):
            raise err
        raise EgovidError(
            f"{len(failures)} {stage} task(s) failed (first: {key}: {type(err).__name__}: {err})"[:600],
            "run the same command again to retry them (finished work is kept)",
        )


def run_grid(
    out: str | os.PathLike,
    cfg: GridConfig,
    engine: EngineConfig | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict:
    """Prepare every missing scene and video, evaluate every missing cell.

    Returns ``{"cells": n, "computed": m, "seconds": s, "stages": {stage: seconds}}``.
    """
    from egovid.voeval.adapters import make_vos

    out = Path(out).resolve()
    cfg.check()
    make_vos(cfg.vos, cfg.commands)  # unknown names fail here, before any work
    if not cfg.vos and not cfg.commands:
        raise EgovidError("no visual odometer to evaluate", "give --vo egovid,ecc,... or --vo-cmd")
    engine = engine or EngineConfig(workers=2)
    first, derived, factors = scene_jobs(out, cfg)
    check_sequences(out, first)
    out.mkdir(parents=True, exist_ok=True)
    _check_resume(out, cfg)
    atomic_write_text(out / "config.json", json.dumps(asdict(cfg), indent=1))
    t0 = time.perf_counter()
    vo_names = [*cfg.vos, *(_command_name(c, i) for i, c in enumerate(cfg.commands))]
    stages: dict[str, float] = {}
    with open_client(engine) as client:
        if client is not None and engine.scheduler is not None:
            [seen] = run_tasks(_folder_visible, [str(out)], config=engine, client=client, name="voeval-check")
            if not (seen.ok and seen.value):
                raise EgovidError(
                    f"the Dask workers cannot see the run folder {out}",
                    "put --out on a filesystem every worker mounts at the same path (e.g. NFS)",
                )

        def stage(name: str, fn, items: list, keys: list[str]) -> list:
            failures = []
            t_stage = time.perf_counter()
            if progress:
                progress(name, 0, len(items))
            tasks = run_tasks(
                guarded, [(fn, it) for it in items], config=engine, keys=keys, name=f"voeval-{name}", client=client
            )
            for done, o in enumerate(tasks, start=1):
                if not o.ok:
                    failures.append((o.key, o.error))
                elif isinstance(o.value, EgovidError):
                    failures.append((o.key, o.value))
                if progress:
                    progress(name, done, len(items))
            stages[name] = time.perf_counter() - t_stage
            return failures

        _raise_failures("scene", stage("scenes", prepare_scene, first, [f"{j.name}@s{j.seed}" for j in first]))
        _raise_failures("scene", stage("degrade", prepare_scene, derived, [f"{j.name}@s{j.seed}" for j in derived]))
        instances = [(j.name, j.seed, j.seeded) for j in [*first, *derived]]
        enc = []
        for s, seed, seeded in instances:
            missing = [
                lv for lv in cfg.levels if lv != "lossless" and not video_path(out, s, lv, seed, seeded).exists()
            ]
            if missing:
                enc.append(EncodeJob(str(out), s, seed, seeded, tuple(missing), cfg.preset))
        _raise_failures("encode", stage("ladder", encode_levels, enc, [f"{j.scene}@s{j.seed}-ladder" for j in enc]))
        catalogue = _catalogue(out, first, derived, factors)
        atomic_write_text(out / "scenes.json", json.dumps(catalogue, indent=1))
        seeded = {s: sd for s, _, sd in instances}
        scenes = list(dict.fromkeys(s for s, _, _ in instances))
        all_cells = [
            CellJob(str(out), vo, tuple(cfg.commands), s, seeded[s], lv, seed, cfg.cap_db, cfg.anchor)
            for vo in vo_names
            for s in scenes
            for lv in cfg.levels
            for seed in cfg.seeds
        ]
        todo = [c for c in all_cells if not cell_path(out, c.vo, c.scene, c.level, c.seed).exists()]
        todo.sort(key=lambda c: SLOW_FIRST.get(c.vo, 9))
        failures = stage("cells", evaluate_cell, todo, [f"{c.vo}/{c.scene}/{c.level}/s{c.seed}" for c in todo])
    _raise_failures("cell", failures)
    return {"cells": len(all_cells), "computed": len(todo), "seconds": time.perf_counter() - t0, "stages": stages}


def _command_name(command: str, index: int) -> str:
    from egovid.voeval.adapters import split_command

    return split_command(command, index)[0]


def _catalogue(out: Path, first: list[SceneJob], derived: list[SceneJob], factors: list[Factor]) -> dict:
    scenes = {}
    for j in [*first, *derived]:
        if j.name in scenes:
            continue
        meta = json.loads((scene_dir(out, j.seed, j.seeded) / f"{j.name}.json").read_text())
        scenes[j.name] = {
            "kind": j.kind,
            "seeded": j.seeded,
            "motion": meta.get("motion", "general"),
            "source": j.source if j.kind != "synthetic" else "synthetic",
            "frames": meta.get("frames"),
            **({"factor": j.factor} if j.factor else {}),
        }
    return {"scenes": scenes, "factors": [asdict(f) for f in factors]}


@dataclass
class RunResults:
    """Every cell of a run folder: ``cells[(vo, scene, level, seed)]``, with the run's odometers,
    scenes, levels, seeds, factor pairs and scene descriptions in a stable order."""

    cells: dict
    vos: list[str]
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
    if not cells:
        raise EgovidError(f"{out} has no finished cells", "run `egovid voeval run --out DIR` (it resumes)")
    cfg = json.loads((out / "config.json").read_text()) if (out / "config.json").exists() else {}
    order = [*cfg.get("vos", [])]
    vos = sorted({k[0] for k in cells}, key=lambda v: (order.index(v) if v in order else len(order), v))
    scenes = [s for s in catalogue["scenes"] if any(k[1] == s for k in cells)]
    levels = [lv for lv in LEVELS if any(k[2] == lv for k in cells)]
    seeds = sorted({k[3] for k in cells})
    factors = [Factor(**f) for f in catalogue["factors"] if f["ideal"] in scenes and f["hard"] in scenes]
    return RunResults(cells, vos, scenes, levels, seeds, factors, catalogue["scenes"])
