"""The stabiliser end to end: motion → edited motion → rendered video → measurements.

``stabilize()`` is what ``egovid fpv stabilize`` runs. Roll is removed by default (set to the
clip's median roll, so a tilted mount stays as mounted and only roll shake goes); ``keep_roll``
treats it like yaw and pitch. ``strength`` blends the original and the optimal motion
(1 = optimal, 0 = untouched).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from egovid.errors import EgovidError
from egovid.geometry import matrix_from_euler
from egovid.io.camera import Intrinsics
from egovid.io.trajectory import Trajectory
from egovid.io.video import probe
from egovid.perception.model import ViewingModel, from_model_rate, to_model_rate
from egovid.perception.score import AXES, check_angles, score_angles
from egovid.stabilize.fpm import find_anchors, pure_fpm
from egovid.stabilize.optimize import AxisPlan, OptimizeOptions, optimize_axis
from egovid.stabilize.render import RenderStats, homographies, render_stabilized


@dataclass
class StabilizeResult:
    """Everything measured about one stabilisation run (angles in degrees, ITF in dB)."""

    output: str
    times: np.ndarray
    original: np.ndarray
    edited: np.ndarray
    plans: dict[str, AxisPlan]
    ve_before: float
    ve_after: float
    fpmi_before: float
    fpmi_after: float
    render: RenderStats
    seconds: dict[str, float] = field(default_factory=dict)
    params: dict = field(default_factory=dict)

    @property
    def fpmi_retention(self) -> float:
        """Share of first-person motion information kept: (1 - VE_pure after) / (1 - VE_pure before)."""
        lost_before = 1.0 - self.fpmi_before
        return (1.0 - self.fpmi_after) / lost_before if lost_before > 1e-9 else 1.0

    def summary(self) -> dict:
        return {
            "output": self.output,
            "frames": len(self.times),
            "ve_before": self.ve_before,
            "ve_after": self.ve_after,
            "pure_fpm_ve_before": self.fpmi_before,
            "pure_fpm_ve_after": self.fpmi_after,
            "fpmi_retention": self.fpmi_retention,
            "itf_before_db": self.render.itf_before,
            "itf_after_db": self.render.itf_after,
            "black_share": self.render.black_share,
            "crop_factor": self.render.crop,
            "seconds": self.seconds,
            "fps_end_to_end": len(self.times) / max(self.seconds.get("total", 1e-9), 1e-9),
            "params": self.params,
        }


def pure_motion(angles: np.ndarray, threshold: float = 0.5) -> np.ndarray:
    """The pure FPM (zigzag through the anchors) of every axis of a (K, 3) motion."""
    out = np.empty_like(angles)
    for k in range(angles.shape[1]):
        a = find_anchors(angles[:, k], threshold)
        out[:, k] = pure_fpm(a, angles[a, k], len(angles))
    return out


def plan_motion(
    angles: np.ndarray,
    fps: float,
    intr: Intrinsics,
    *,
    strength: float = 1.0,
    keep_roll: bool = False,
    model: ViewingModel | None = None,
    opts: OptimizeOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
    times: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, AxisPlan]]:
    """Edited (K, 3) motion in degrees and the per-axis plans.

    The plan is made at the model's 30 fps (the motion is resampled there and the edited motion
    back to the video's frames), so the objective and the easing table mean the same at every
    frame rate; the plans' anchors are in frames at 30 fps."""
    if not (0.0 <= strength <= 1.0):
        raise EgovidError(f"strength {strength} is outside [0, 1]", "use e.g. --strength 0.7")
    model = model or ViewingModel()
    opts = opts or OptimizeOptions()
    a30, _ = to_model_rate(angles, fps, times)
    axes = ["yaw", "pitch"] + (["roll"] if keep_roll else [])
    edited30 = np.array(a30)
    if not keep_roll:
        edited30[:, 2] = np.median(angles[:, 2])
    plans: dict[str, AxisPlan] = {}
    for step, name in enumerate(axes):
        col = AXES.index(name)
        # Roll's intervals are shifted by the yaw and pitch the viewer will see (eq. 8.2-8.3).
        plans[name] = optimize_axis(a30[:, col], name, intr.hfov_deg, intr.vfov_deg, model, opts, context=edited30)
        edited30[:, col] = plans[name].edited
        if progress is not None:
            progress(step + 1, len(axes))
    edited = from_model_rate(edited30, fps, len(angles), times)
    edited = angles + strength * (edited - angles)
    return edited, plans


def stabilize(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    *,
    intrinsics: Intrinsics | None = None,
    motion: Trajectory | None = None,
    strength: float = 1.0,
    borders: str = "crop",
    keep_roll: bool = False,
    method: str = "ve",
    model: ViewingModel | None = None,
    opts: OptimizeOptions | None = None,
    crf: int = 18,
    progress: Callable[[str, int, int], None] | None = None,
) -> StabilizeResult:
    """Stabilise ``src`` into ``dst`` keeping the intentional first-person motion.

    ``motion`` reuses a previously estimated trajectory (it must have one entry per frame).
    ``progress(stage, done, total)`` is called with stages ``motion``, ``optimise``, ``render``.
    """
    from egovid.motion.estimate import estimate_motion

    t0 = time.perf_counter()
    info = probe(src)
    intr = intrinsics or Intrinsics.default(info.width, info.height)
    model = model or ViewingModel()
    opts = opts or OptimizeOptions(method=method)
    if motion is None:
        cb = (lambda d, t: progress("motion", d, t)) if progress else None
        motion = estimate_motion(src, intr, progress=cb).trajectory
    t1 = time.perf_counter()
    angles = motion.euler()
    fps = info.fps
    check_angles(angles, fps, model)  # too short to score: say so before writing anything
    cb = (lambda d, t: progress("optimise", d, t)) if progress else None
    edited, plans = plan_motion(
        angles, fps, intr, strength=strength, keep_roll=keep_roll, model=model, opts=opts, progress=cb
    )
    t2 = time.perf_counter()
    R_old = matrix_from_euler(angles[:, 0], angles[:, 1], angles[:, 2])
    R_new = matrix_from_euler(edited[:, 0], edited[:, 1], edited[:, 2])
    H = homographies(R_old, R_new, intr)
    cb = (lambda d, t: progress("render", d, t)) if progress else None
    stats = render_stabilized(src, dst, H, borders=borders, R_new=R_new, intrinsics=intr, crf=crf, progress=cb)
    t3 = time.perf_counter()
    hfov, vfov = intr.hfov_deg, intr.vfov_deg
    ve_before = score_angles(angles, fps, hfov, vfov, model=model, method=method).score
    ve_after = score_angles(edited, fps, hfov, vfov, model=model, method=method).score
    fp_before = score_angles(pure_motion(angles, opts.anchor_threshold), fps, hfov, vfov, model=model).score
    fp_after = score_angles(pure_motion(edited, opts.anchor_threshold), fps, hfov, vfov, model=model).score
    return StabilizeResult(
        output=str(dst),
        times=motion.times,
        original=angles,
        edited=edited,
        plans=plans,
        ve_before=ve_before,
        ve_after=ve_after,
        fpmi_before=fp_before,
        fpmi_after=fp_after,
        render=stats,
        seconds={"motion": t1 - t0, "optimise": t2 - t1, "render": t3 - t2, "total": time.perf_counter() - t0},
        params={
            "strength": strength,
            "borders": borders,
            "keep_roll": keep_roll,
            "method": method,
            "focal_px": intr.focal,
            "anchor_threshold_deg": opts.anchor_threshold,
            "d_over_f": model.d_over_f,
            "bias_deg": model.bias_deg,
        },
    )
