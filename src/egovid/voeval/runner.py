"""The evaluation grid: scenes × compression levels × seeds × visual odometers, on the task engine.

:func:`evaluate` is what ``egovid voeval run``, the benchmark and the demo call: :func:`run_grid`,
then the report. :func:`run_grid` prepares the test videos (synthetic renders, imported real
sequences, their degraded copies, the H.264 ladder) and then evaluates every missing cell (every
odometer at every level, and the floors once per scene), each stage as independent tasks on
:mod:`egovid.core.engine`: in this process, on a local pool of worker processes (the default), or
on a Dask cluster (``--scheduler``; the run folder must then be reachable at the same path from
every worker). Every output is written atomically by the task that makes it and is skipped when
it exists, so an interrupted run resumes where it stopped and a task that runs twice (its worker
was killed, Dask ran it again elsewhere) does no harm.
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
from egovid.voeval.adapters import DEFAULT_TIMEOUT_S, ODOMETERS, available_vos, make_vos, split_command
from egovid.voeval.cell import ANCHORS, CellJob, evaluate_cell
from egovid.voeval.degrade import REAL_FACTORS, degrade_scene
from egovid.voeval.floors import FLOORS
from egovid.voeval.gyro_reference import check_gyro_video, import_gyro_sequence
from egovid.voeval.layout import LEVELS, Factor, cell_path, scene_dir, video_path
from egovid.voeval.report import write_report
from egovid.voeval.scenes import FACTORS, SCENES, SceneTruth, render_scene
from egovid.voeval.sequences import SequenceSpec, import_sequence, open_sequence, parse_specs

#: Realistic default (issue 16): 640x480, 300 frames; ``--quick`` is the old smoke-test grid.
DEFAULT_FRAMES, DEFAULT_SIZE = 300, (640, 480)
QUICK_FRAMES, QUICK_SIZE = 48, (320, 240)
#: Settings that change a cell's numbers: a run folder cannot be resumed with other values.
RESULT_KEYS = ("frames", "width", "height", "cap_db", "anchor")


@dataclass
class GridConfig:
    """What to evaluate. ``sequences`` are ``FORMAT:PATH`` specs; ``scenes`` the synthetic scenes
    (empty: real sequences only); ``real_factors`` the image-level factors applied to real frames;
    ``timeout`` the seconds an odometer may run on one video in its own process (then its cell is
    recorded as timed out)."""

    vos: list[str] = field(default_factory=available_vos)
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
    timeout: float = DEFAULT_TIMEOUT_S

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
        if not self.timeout > 0:
            raise EgovidError(f"an odometer timeout of {self.timeout} s cannot work", "give a positive --vo-timeout")
        if not self.vos and not self.commands:
            raise EgovidError("no visual odometer to evaluate", "give --vo egovid,ecc,... or --vo-cmd")
        make_vos(self.vos, self.commands)  # unknown or missing odometers fail here, before any work

    @property
    def odometers(self) -> list[str]:
        """Names of every odometer of the run: built-ins, then the ``--vo-cmd`` commands."""
        return [*self.vos, *(split_command(c, i)[0] for i, c in enumerate(self.commands))]


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


def _render(job: SceneJob, video: Path) -> SceneTruth:
    return render_scene(job.name, video, frames=job.frames, width=job.width, height=job.height, seed=job.seed)


def _import(job: SceneJob, video: Path) -> SceneTruth:
    [spec] = parse_specs([job.source])
    spec = SequenceSpec(spec.fmt, spec.path, job.name)
    if spec.fmt == "gyro":
        truth = import_gyro_sequence(spec, video, job.frames)
    else:
        truth = import_sequence(open_sequence(spec), video, job.frames)
    truth.meta["source"] = spec.text
    return truth


def _degrade(job: SceneJob, video: Path) -> SceneTruth:
    base_dir = scene_dir(Path(job.out), job.seed, seeded=False)
    base = SceneTruth.load(base_dir, job.source)
    return degrade_scene(base_dir / f"{job.source}.mkv", base, job.factor, job.seed, video)


#: How each kind of scene is made.
PREPARE = {"synthetic": _render, "real": _import, "derived": _degrade}


def prepare_scene(job: SceneJob) -> str:
    """Render, import or degrade one scene (skipped when its truth exists); returns its name."""
    folder = scene_dir(Path(job.out), job.seed, job.seeded)
    folder.mkdir(parents=True, exist_ok=True)
    if (folder / f"{job.name}.json").exists():
        return job.name
    t = time.perf_counter()
    truth = PREPARE[job.kind](job, folder / f"{job.name}.mkv")
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
    for job in jobs:
        if job.kind != "real" or (scene_dir(out, 0, False) / f"{job.name}.json").exists():
            continue
        [spec] = parse_specs([job.source])
        if spec.fmt == "gyro":
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


class _Stages:
    """Runs the grid's stages on one engine client, timing each (``seconds[stage]``)."""

    def __init__(self, engine: EngineConfig, client, progress: Callable[[str, int, int], None] | None) -> None:
        self.engine, self.client, self.progress = engine, client, progress
        self.seconds: dict[str, float] = {}

    def run(self, name: str, fn: Callable, items: list, keys: list[str]) -> list:
        """Run ``fn`` on every item; returns the failures as (key, error)."""
        failures = []
        t_stage = time.perf_counter()
        if self.progress:
            self.progress(name, 0, len(items))
        tasks = run_tasks(
            guarded,
            [(fn, it) for it in items],
            config=self.engine,
            keys=keys,
            name=f"voeval-{name}",
            client=self.client,
        )
        for done, o in enumerate(tasks, start=1):
            if not o.ok:
                failures.append((o.key, o.error))
            elif isinstance(o.value, EgovidError):
                failures.append((o.key, o.value))
            if self.progress:
                self.progress(name, done, len(items))
        self.seconds[name] = time.perf_counter() - t_stage
        return failures


def _encode_jobs(out: Path, cfg: GridConfig, instances: list[tuple[str, int, bool]]) -> list[EncodeJob]:
    jobs = []
    for s, seed, seeded in instances:
        missing = [lv for lv in cfg.levels if lv != "lossless" and not video_path(out, s, lv, seed, seeded).exists()]
        if missing:
            jobs.append(EncodeJob(str(out), s, seed, seeded, tuple(missing), cfg.preset))
    return jobs


def _cell_jobs(out: Path, cfg: GridConfig, instances: list[tuple[str, int, bool]]) -> list[CellJob]:
    """Every cell of the run: each odometer at each level, each floor at the lossless level only."""
    seeded = {s: sd for s, _, sd in instances}
    scenes = list(dict.fromkeys(s for s, _, _ in instances))
    cmds = tuple(cfg.commands)

    def job(vo: str, s: str, lv: str, seed: int) -> CellJob:
        return CellJob(str(out), vo, cmds, s, seeded[s], lv, seed, cfg.cap_db, cfg.anchor, cfg.timeout)

    cells = [job(vo, s, lv, seed) for vo in cfg.odometers for s in scenes for lv in cfg.levels for seed in cfg.seeds]
    return cells + [job(f, s, "lossless", seed) for f in FLOORS for s in scenes for seed in cfg.seeds]


def run_grid(
    out: str | os.PathLike,
    cfg: GridConfig,
    engine: EngineConfig | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict:
    """Prepare every missing scene and video, evaluate every missing cell.

    Returns ``{"cells": n, "computed": m, "seconds": s, "stages": {stage: seconds}}`` (floor cells
    included).
    """
    out = Path(out).resolve()
    cfg.check()
    engine = engine or EngineConfig(workers=2)
    first, derived, factors = scene_jobs(out, cfg)
    check_sequences(out, first)
    out.mkdir(parents=True, exist_ok=True)
    _check_resume(out, cfg)
    atomic_write_text(out / "config.json", json.dumps(asdict(cfg), indent=1))
    t0 = time.perf_counter()
    with open_client(engine) as client:
        if client is not None and engine.scheduler is not None:
            [seen] = run_tasks(_folder_visible, [str(out)], config=engine, client=client, name="voeval-check")
            if not (seen.ok and seen.value):
                raise EgovidError(
                    f"the Dask workers cannot see the run folder {out}",
                    "put --out on a filesystem every worker mounts at the same path (e.g. NFS)",
                )
        stages = _Stages(engine, client, progress)
        _raise_failures("scene", stages.run("scenes", prepare_scene, first, [f"{j.name}@s{j.seed}" for j in first]))
        keys = [f"{j.name}@s{j.seed}" for j in derived]
        _raise_failures("scene", stages.run("degrade", prepare_scene, derived, keys))
        instances = [(j.name, j.seed, j.seeded) for j in [*first, *derived]]
        enc = _encode_jobs(out, cfg, instances)
        keys = [f"{j.scene}@s{j.seed}-ladder" for j in enc]
        _raise_failures("encode", stages.run("ladder", encode_levels, enc, keys))
        atomic_write_text(out / "scenes.json", json.dumps(_catalogue(out, first, derived, factors), indent=1))
        all_cells = _cell_jobs(out, cfg, instances)
        todo = [c for c in all_cells if not cell_path(out, c.vo, c.scene, c.level, c.seed).exists()]
        todo.sort(key=lambda c: getattr(ODOMETERS.get(c.vo), "slow_rank", 9))
        failures = stages.run("cells", evaluate_cell, todo, [f"{c.vo}/{c.scene}/{c.level}/s{c.seed}" for c in todo])
    _raise_failures("cell", failures)
    seconds = time.perf_counter() - t0
    return {"cells": len(all_cells), "computed": len(todo), "seconds": seconds, "stages": stages.seconds}


def evaluate(
    out: str | os.PathLike,
    cfg: GridConfig,
    engine: EngineConfig | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    *,
    report: bool = True,
    norm: str = "thesis",
) -> dict:
    """``egovid voeval run``: :func:`run_grid`, then (``report``) :func:`write_report`. Returns
    run_grid's summary plus ``"report": (html, md)`` paths (None without a report) and
    ``"report_seconds"``."""
    r = run_grid(out, cfg, engine, progress)
    t = time.perf_counter()
    r["report"] = write_report(out, norm=norm) if report else None
    r["report_seconds"] = time.perf_counter() - t
    return r


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
