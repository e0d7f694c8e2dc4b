"""One cell of the grid: one odometer (or floor) on one video, scored against the reference.

A cell runs the odometer (in a temporary folder local to the worker), puts its rotations in the
reference's frame, and computes the pose error (eq. 21.11–21.12), OITF and RITF (eq. 21.13–21.19),
and the standard ATE and RPE as evo computes them (:mod:`egovid.voeval.evo_errors`). It writes its
trajectory (TUM) and then its JSON, each atomically; the JSON is the cell's "done" mark, so a cell
that exists is never recomputed and a cell whose worker died is simply run again.

**Outcome.** Every cell is ``ran``, ``partial`` or ``failed`` with its tracked share beside it
(:mod:`egovid.voeval.outcome`); the report never ranks a partial or failed cell above one that ran. Why frames
were lost is kept in ``diagnosis``: the odometer's own reason, its exit status, whether it timed
out, the last lines of its output, and for an odometer that needs parallax to initialise, how far
the reference camera moved over the clip.

**Late starters.** Odometers that need to initialise (ORB-SLAM3, COLMAP) give no pose for the
first frames. Their output is relative to their own first pose, and the frames before it hold
that pose (no estimate = no motion): ``anchor="none"``, what eq. 21.11 sees when the odometer's
output is taken as it is. ``anchor="truth"`` instead hands the odometer the true orientation of
its first tracked frame (:func:`egovid.voeval.adapters.anchor_to_truth`); it was the default
before and favours late starters. Every cell records ``first_pose_frame`` (frames before the
first pose) and the pose error under the other choice (``pose_error_other_anchor``), so the
effect of the choice is measured on every run.
"""

from __future__ import annotations

import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from egovid.core.files import atomic_write_text
from egovid.core.metrics.pose_error import pose_error
from egovid.core.metrics.visual_error import visual_errors
from egovid.core.rotations import angle_deg
from egovid.core.trajectory import Trajectory, write_tum
from egovid.synth.photos import photo
from egovid.voeval.adapters import DEFAULT_TIMEOUT_S, ODOMETERS, VOResult, anchor_to_truth, make_vo, timed_run
from egovid.voeval.evo_errors import ate_rpe
from egovid.voeval.floors import floor_trajectory, is_floor
from egovid.voeval.layout import cell_path, scene_dir, video_path
from egovid.voeval.outcome import outcome
from egovid.voeval.scenes import SceneTruth

ANCHORS = ("none", "truth")
#: Pictures moved by the true rotation and stabilised by the estimate (image replacement, §21.3).
VISUAL_IMAGES = ("astronaut", "coffee", "rocket")


@dataclass(frozen=True)
class CellJob:
    """What a worker needs to evaluate one cell (picklable)."""

    out: str
    vo: str
    commands: tuple[str, ...]
    scene: str
    seeded: bool
    level: str
    seed: int
    cap_db: float
    anchor: str = "none"
    timeout: float = DEFAULT_TIMEOUT_S


def first_pose_frame(valid: np.ndarray) -> int | None:
    """Index of the first frame the odometer gave a pose for (None: it never did)."""
    valid = np.asarray(valid, bool)
    return int(np.argmax(valid)) if valid.any() else None


def reference_motion(truth: SceneTruth) -> str:
    """How far the reference camera moves over the clip (path length where it has positions, the
    largest rotation from the first frame), said for an odometer that needs parallax to start."""
    turn = float(np.max(angle_deg(truth.R)))
    text = f"turns up to {turn:.1f}° from its first frame over {len(truth.R)} frames"
    if truth.t is not None:
        path = float(np.sum(np.linalg.norm(np.diff(truth.t, axis=0), axis=1)))
        unit = truth.meta.get("translation_unit", "m")
        text = f"moves {path:.3g} {'m' if unit == 'm' else 'units'} along its path and " + text
    return (
        f"the reference camera {text} (a monocular odometer initialises only once two views are far enough "
        "apart: parallax)"
    )


def evaluate_cell(job: CellJob) -> dict:
    """Run and score one cell; returns the cell's JSON content (read back when it exists)."""
    out = Path(job.out)
    dst = cell_path(out, job.vo, job.scene, job.level, job.seed)
    if dst.exists():
        return json.loads(dst.read_text())
    t_cell = time.perf_counter()
    truth = SceneTruth.load(scene_dir(out, job.seed, job.seeded), job.scene)
    res = _floor(job.vo, truth) if is_floor(job.vo) else _run_odometer(job, truth)
    cell, R, t = score(job, truth, res)
    cell["cell_seconds"] = time.perf_counter() - t_cell
    dst.parent.mkdir(parents=True, exist_ok=True)
    write_tum(dst.with_suffix(".tum"), Trajectory(truth.times[: len(R)], R, t))
    atomic_write_text(dst, json.dumps(cell, indent=1))
    return cell


def _floor(name: str, truth: SceneTruth) -> VOResult:
    R, t = floor_trajectory(name, truth)
    return VOResult(R, np.ones(len(R), bool), "ok", t=t)


def _run_odometer(job: CellJob, truth: SceneTruth) -> VOResult:
    vo = make_vo(job.vo, list(job.commands), job.timeout)
    video = video_path(Path(job.out), job.scene, job.level, job.seed, job.seeded)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one core per worker: the grid's parallelism is across cells
    try:
        with tempfile.TemporaryDirectory(prefix="egovid-vo-") as work:
            return timed_run(vo, video, truth.intrinsics, Path(work), truth.dataset)
    finally:
        cv2.setNumThreads(threads)


def score(job: CellJob, truth: SceneTruth, res: VOResult) -> tuple[dict, np.ndarray, np.ndarray | None]:
    """The cell's JSON content and the trajectory scored (R, t) from an odometer's result."""
    n = min(len(res.R), len(truth.R))
    R_gt, valid = truth.R[:n], res.valid[:n]
    t_gt = None if truth.t is None else truth.t[:n]
    t_est = None if res.t is None else res.t[:n]
    as_given = res.R[:n]
    anchored = anchor_to_truth(as_given, valid, R_gt)
    R, other = (anchored, as_given) if job.anchor == "truth" else (as_given, anchored)
    pe = pose_error(R_gt, R)
    oitf, ritf = visual_errors([photo(p) for p in VISUAL_IMAGES], R_gt, R, truth.intrinsics, cap_db=job.cap_db)
    first = first_pose_frame(valid)
    cell = {
        "vo": job.vo,
        "scene": job.scene,
        "level": job.level,
        "seed": job.seed,
        "status": res.status,
        "seconds": res.seconds,
        "cpu_seconds": res.cpu_seconds,
        "frames": n,
        "tracked": int(valid.sum()),
        "tracked_share": float(valid.mean()) if n else 0.0,
        "first_pose_frame": n if first is None else first,
        "anchor": job.anchor,
        "pose_error": pe,
        "pose_error_per_pair": pe / max(n - 1, 1),
        "pose_error_other_anchor": pose_error(R_gt, other),
        "oitf": oitf,
        "ritf": ritf,
        **ate_rpe(truth.times[:n], R_gt, R, t_gt, t_est),
        "gives_translation": t_est is not None,
        **res.extra,
    }
    cell["outcome"] = outcome(cell)
    diagnosis = res.diagnosis.to_dict()
    cls = ODOMETERS.get(job.vo)
    if cell["outcome"] != "ran" and cls is not None and cls.needs_parallax:
        diagnosis["reference_motion"] = reference_motion(truth)
    cell["diagnosis"] = diagnosis
    cell["reason"] = diagnosis["reason"]
    return cell, R, t_est
