"""One cell of the grid: one odometer on one video, scored against the reference.

A cell runs the odometer (in a temporary folder local to the worker), puts its rotations in the
reference's frame, and computes the pose error (eq. 21.11–21.12), OITF and RITF (eq. 21.13–21.19).
It writes its trajectory (TUM) and then its JSON, each atomically; the JSON is the cell's
"done" mark, so a cell that exists is never recomputed and a cell whose worker died is simply run
again.

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

import numpy as np

from egovid.core.files import atomic_write_text
from egovid.core.metrics.pose_error import pose_error
from egovid.core.metrics.visual_error import visual_errors
from egovid.core.trajectory import Trajectory, write_tum
from egovid.voeval.layout import cell_path, scene_dir, video_path
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


def first_pose_frame(valid: np.ndarray) -> int | None:
    """Index of the first frame the odometer gave a pose for (None: it never did)."""
    valid = np.asarray(valid, bool)
    return int(np.argmax(valid)) if valid.any() else None


def evaluate_cell(job: CellJob) -> dict:
    """Run and score one cell; returns the cell's JSON content (read back when it exists)."""
    import cv2

    from egovid.synth.photos import photo
    from egovid.voeval.adapters import anchor_to_truth, make_vo, timed_run

    out = Path(job.out)
    dst = cell_path(out, job.vo, job.scene, job.level, job.seed)
    if dst.exists():
        return json.loads(dst.read_text())
    t_cell = time.perf_counter()
    truth = SceneTruth.load(scene_dir(out, job.seed, job.seeded), job.scene)
    vo = make_vo(job.vo, list(job.commands))
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one core per worker: the grid's parallelism is across cells
    try:
        with tempfile.TemporaryDirectory(prefix="egovid-vo-") as work:
            res = timed_run(
                vo, video_path(out, job.scene, job.level, job.seed, job.seeded), truth.intrinsics, Path(work)
            )
        n = min(len(res.R), len(truth.R))
        R_gt, valid = truth.R[:n], res.valid[:n]
        as_given = res.R[:n]
        anchored = anchor_to_truth(as_given, valid, R_gt)
        R, other = (anchored, as_given) if job.anchor == "truth" else (as_given, anchored)
        pe = pose_error(R_gt, R)
        oitf, ritf = visual_errors([photo(p) for p in VISUAL_IMAGES], R_gt, R, truth.intrinsics, cap_db=job.cap_db)
    finally:
        cv2.setNumThreads(threads)
    first = first_pose_frame(valid)
    cell = {
        "vo": job.vo,
        "scene": job.scene,
        "level": job.level,
        "seed": job.seed,
        "status": res.status,
        "message": res.message,
        "seconds": res.seconds,
        "cell_seconds": time.perf_counter() - t_cell,
        "frames": n,
        "tracked": int(valid.sum()),
        "first_pose_frame": n if first is None else first,
        "anchor": job.anchor,
        "pose_error": pe,
        "pose_error_per_pair": pe / max(n - 1, 1),
        "pose_error_other_anchor": pose_error(R_gt, other),
        "oitf": oitf,
        "ritf": ritf,
        **res.extra,
    }
    dst.parent.mkdir(parents=True, exist_ok=True)
    write_tum(dst.with_suffix(".tum"), Trajectory(truth.times[:n], R))
    atomic_write_text(dst, json.dumps(cell, indent=1))
    return cell
