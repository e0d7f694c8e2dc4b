"""The stabiliser end to end: motion → planned motion → path the frame affords → rendered video →
measured video.

``stabilize()`` runs the stabiliser on a video and its camera motion (``egovid fpv stabilize``
runs it through :func:`egovid.fpv.stabilize.run.stabilize_video`, which resolves that motion):

1. the camera motion of the input (given, or estimated from the pictures);
2. the thesis' plan (ch. 9, :mod:`egovid.fpv.stabilize.optimize`) at the model's 30 fps: roll is
   levelled by default (set to the clip's median roll, so a tilted mount stays as mounted and only
   roll shake goes; ``keep_roll`` treats it like yaw and pitch); ``strength`` blends the original
   and the planned motion (1 = the plan, 0 = untouched);
3. with ``horizon_lock``, every view of the plan levelled against gravity (the accelerometer's,
   else the path's mean down; :mod:`egovid.fpv.stabilize.horizon`);
4. with ``borders="crop"``, below the plan the visible-shake layer
   (:mod:`egovid.fpv.stabilize.visible`): the plan low-passed as far as its FPMI allows and bent
   into what a dynamic zoom of at most ``max_zoom`` covers (:mod:`egovid.fpv.stabilize.path`;
   ``visible=False``: the path nearest the plan itself, the thesis' stabiliser alone);
5. the frames re-rendered along that path, keeping what the camera wrote
   (:mod:`egovid.fpv.stabilize.render`);
6. unless ``measure=False``, the input and the decoded output measured alike
   (:mod:`egovid.fpv.stabilize.measure`): VE, SVE, FPMI, 2D-VE, ITF and jitter, beside the same
   scores of the path as planned.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from typing import TypeVar

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.lens import PINHOLE, Lens
from egovid.core.errors import EgovidError
from egovid.core.motion.estimate import estimate_motion
from egovid.core.motion.rolling_shutter import frame_rates, row_offsets
from egovid.core.motion.source import CameraMotion
from egovid.core.rotations import matrix_from_euler, so3_exp
from egovid.core.side_call import SideCall, can_fork
from egovid.core.trajectory import Trajectory
from egovid.core.video import Frame, probe
from egovid.core.video.read import decoding_ahead
from egovid.fpv.perception.model import ViewingModel, from_model_rate, to_model_rate
from egovid.fpv.perception.score import AXES, check_angles
from egovid.fpv.stabilize.horizon import down_from_path, lock_horizon
from egovid.fpv.stabilize.measure import MotionScores, VideoMeasures, measure_video, motion_scores
from egovid.fpv.stabilize.optimize import AxisPlan, OptimizeOptions, kernels_loading, load_kernels, optimize_axis
from egovid.fpv.stabilize.path import FittedPath, fit_path
from egovid.fpv.stabilize.render import (
    BORDERS,
    OutputFormat,
    RenderStats,
    content_masks,
    homographies,
    render_stabilized,
)
from egovid.fpv.stabilize.render_views import render_views
from egovid.fpv.stabilize.visible import VisibleTarget, visible_path
from egovid.fpv.stabilize.warp import FrameView, MeshWarp, required_zoom

T = TypeVar("T")


def _retention(pure_before: float, pure_after: float) -> float:
    """Share of first-person motion information kept: (1 - VE_pure after) / (1 - VE_pure before)."""
    lost_before = 1.0 - pure_before
    return (1.0 - pure_after) / lost_before if lost_before > 1e-9 else 1.0


@dataclass
class StabilizeResult:
    """One stabilisation run. Angles in degrees (K, 3): ``original`` (input motion), ``plan`` (the
    thesis' plan), ``path`` (what was rendered); ``keep`` (K,) the share of the frame kept (zoom
    1/keep); scores of the path as ``planned``; ``before``/``after`` measured on the decoded input
    and output (None with ``measure=False``); ``seconds`` per stage (not in :meth:`summary`,
    which is deterministic); ``camera_motion`` the input's motion where
    :func:`egovid.fpv.stabilize.run.stabilize_video` estimated it (its times not in ``seconds``; its
    source, reason, sync and picture-vs-gyro share in :meth:`summary` under ``motion_source``)."""

    output: str
    times: np.ndarray
    original: np.ndarray
    plan: np.ndarray
    path: np.ndarray
    keep: np.ndarray
    plans: dict[str, AxisPlan]
    planned: MotionScores
    planned_before: MotionScores
    before: VideoMeasures | None
    after: VideoMeasures | None
    render: RenderStats
    fitted: FittedPath | None
    visible: VisibleTarget | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    params: dict = field(default_factory=dict)
    camera_motion: CameraMotion | None = field(default=None, repr=False)
    render_warnings: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        """JSON-ready results: the same input and options give the same dict (no timings)."""
        zoom = 1.0 / self.keep
        out = {
            "output": self.output,
            "frames": len(self.times),
            "planned": {"before": asdict(self.planned_before), "after": asdict(self.planned)},
            "fpmi_retention_planned": _retention(self.planned_before.pure_fpm_ve, self.planned.pure_fpm_ve),
            "zoom": {"mean": float(zoom.mean()), "max": float(zoom.max())},
            "black_share": self.render.black_share,
            "bit_depth": self.render.bits,
            "kept_from_input": self.render.kept,
            "not_kept": self.render.dropped,
            "visible_cutoff_hz": self.visible.cutoff_hz if self.visible else None,
            "notes": self.fitted.notes if self.fitted else [],
            "params": self.params,
        }
        if self.camera_motion is not None:
            out["motion_source"] = self.camera_motion.source_dict()
        if self.before is not None and self.after is not None:
            out["measured"] = {"before": self.before.to_dict(), "after": self.after.to_dict()}
            out["fpmi_retention_measured"] = _retention(self.before.pure_fpm_ve, self.after.pure_fpm_ve)
        out["warnings"] = self.warnings()
        return out

    def warnings(self) -> list[str]:
        """What the user should know about the output, each with what to change: the output
        measured shakier than the input (the visible shake of the decoded pictures), frames whose
        lens or rolling shutter needed more zoom than the budget (their corners show border)."""
        return shake_warnings(self.before, self.after, float(np.max(1.0 / self.keep)), self.params) + list(
            self.render_warnings
        )


def shake_warnings(
    before: VideoMeasures | None, after: VideoMeasures | None, zoom_max: float, params: dict
) -> list[str]:
    """The warning for an output whose decoded pictures shake more than the input's
    (``shake_px`` of ``before`` and ``after``), with a suggestion chosen by what limited the run:
    a zoom at its budget (``zoom_max`` against ``params["max_zoom"]``) wants a larger budget;
    otherwise the camera model (field of view, lens) or the motion source is the likely cause."""
    if before is None or after is None or not np.isfinite(before.shake_px) or not np.isfinite(after.shake_px):
        return []
    if after.shake_px <= before.shake_px:
        return []
    budget = params.get("max_zoom")
    if budget is not None and zoom_max >= budget - 1e-3:
        hint = f"the zoom reached its budget ({budget:g}x): try --max-zoom {min(budget + 0.1, 4.0):.2f}"
    else:
        hint = (
            "the warp's camera model may not fit this lens: try --hfov with the camera's field of view, "
            "or --source vision"
        )
    return [
        f"the output shakes more than the input (visible shake {before.shake_px:.3f} → {after.shake_px:.3f} px "
        f"at 480 px width); {hint}"
    ]


#: Decoded pictures (bytes) the render may hold ahead of the warp: its decoding starts beside the
#: path fit (:func:`egovid.core.video.read.decoding_ahead`), which leaves the other core idle.
DECODE_AHEAD_BYTES = 256 << 20

#: How long the plan waits for the side process's axis beyond the time the main axis took (×, and
#: at least the seconds below) before it plans that axis itself (:class:`SideCall`).
SIDE_PATIENCE = (4.0, 120.0)


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
    check_options(strength)
    model = model or ViewingModel()
    opts = opts or OptimizeOptions()
    a30, _ = to_model_rate(angles, fps, times)
    axes = ["yaw", "pitch"] + (["roll"] if keep_roll else [])
    edited30 = np.array(a30)
    if not keep_roll:
        edited30[:, 2] = np.median(angles[:, 2])
    plans: dict[str, AxisPlan] = {}
    load_kernels()  # before the fork: the side process inherits them
    # Yaw and pitch are planned independently (each axis's windows see only its own angle), so
    # pitch runs in a forked process while yaw runs here: the optimiser is single-threaded
    # Python and the second core would idle. Roll waits for both (its intervals move with them).
    pending: dict[str, SideCall] = {}
    if can_fork() and "pitch" in axes:
        col = AXES.index("pitch")
        pending["pitch"] = SideCall(
            optimize_axis, a30[:, col], "pitch", intr.hfov_deg, intr.vfov_deg, model, opts, context=edited30
        )
    try:
        t0 = time.perf_counter()
        for step, name in enumerate(axes):
            col = AXES.index(name)
            if name in pending:
                factor, least = SIDE_PATIENCE
                plans[name] = pending.pop(name).result(max(least, factor * (time.perf_counter() - t0)))
            else:
                # Roll's intervals are shifted by the yaw and pitch the viewer will see (eq. 8.2-8.3).
                plans[name] = optimize_axis(
                    a30[:, col], name, intr.hfov_deg, intr.vfov_deg, model, opts, context=edited30
                )
            edited30[:, col] = plans[name].edited
            if progress is not None:
                progress(step + 1, len(axes))
    finally:
        for call in pending.values():
            call.close()
    edited = from_model_rate(edited30, fps, len(angles), times)
    edited = angles + strength * (edited - angles)
    return edited, plans


#: The stability measures the objective can use.
METHODS = ("ve", "sve")


def check_options(strength: float, borders: str = "crop", method: str = "ve") -> None:
    """Refuse a ``strength`` outside [0, 1], an unknown border mode or stability measure (before
    any work)."""
    if borders not in BORDERS:
        raise EgovidError(f"unknown border mode {borders!r}", f"choose one of {', '.join(BORDERS)}")
    if method not in METHODS:
        raise EgovidError(f"unknown method {method!r}", "choose ve or sve")
    if not (0.0 <= strength <= 1.0):
        raise EgovidError(f"strength {strength} is outside [0, 1]", "use e.g. --strength 0.7")


def stabilize(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    *,
    intrinsics: Intrinsics | None = None,
    motion: Trajectory | None = None,
    strength: float = 1.0,
    borders: str = "crop",
    max_zoom: float = 1.10,
    keep_roll: bool = False,
    method: str = "ve",
    model: ViewingModel | None = None,
    opts: OptimizeOptions | None = None,
    crf: int = 18,
    bit_depth: str = "auto",
    measure: bool = True,
    visible: bool = True,
    horizon_lock: bool = False,
    down_world: np.ndarray | None = None,
    lens: Lens = PINHOLE,
    readout_s: float = 0.0,
    progress: Callable[[str, int, int], None] | None = None,
) -> StabilizeResult:
    """Stabilise ``src`` into ``dst`` keeping the intentional first-person motion.

    ``motion`` reuses a previously estimated trajectory (it must have one entry per frame; without
    it the motion is estimated from the pictures with ``intrinsics``). ``visible`` puts the
    visible-shake layer below the plan (with ``borders="crop"``); ``horizon_lock`` levels every
    view against ``down_world`` ((3,) the world's down direction in the motion's frame, from an
    accelerometer), else against the path's mean down axis. ``lens`` is the camera's projection:
    with a fisheye and ``borders="crop"`` every frame is warped through it (one remap per frame,
    :class:`~egovid.fpv.stabilize.warp.MeshWarp`) and its zoom raised where that lens needs more
    than the path programme's pinhole corners said. ``readout_s`` (seconds, negative: bottom row
    first) is the frame readout of a rolling-shutter sensor: with ``borders="crop"`` every row band
    is then warped from the orientation the camera had when it was read (:func:`row_rotations`),
    as Gyroflow does. ``bit_depth`` (``auto``, ``8``, ``10``) is the output's bits per sample:
    ``auto`` renders a 10-bit input (a phone's HDR HEVC) to 10-bit HEVC with its colour tags and
    HDR10 metadata, an 8-bit one to H.264 (:func:`~egovid.fpv.stabilize.render.output_bits`).
    The zoom a lens or rolling shutter needs beyond the plan is never raised
    above ``max_zoom``; frames that would need more are named in the warnings.
    ``progress(stage, done, total)`` is called with stages ``motion``, ``plan``, ``render`` and
    the measuring stages.
    """
    check_options(strength, borders, method)
    t0 = time.perf_counter()
    info = probe(src)
    intr = intrinsics or Intrinsics.default(info.width, info.height)
    model = model or ViewingModel()
    opts = opts or OptimizeOptions(method=method)
    if motion is None:
        motion = _estimate(src, intr, _stage(progress, "motion"))
    t1 = time.perf_counter()
    angles = motion.euler()
    fps = info.fps
    check_angles(angles, fps, model)  # too short to score: say so before writing anything
    plan, plans = plan_motion(
        angles,
        fps,
        intr,
        strength=strength,
        keep_roll=keep_roll,
        model=model,
        opts=opts,
        progress=_stage(progress, "plan"),
    )
    if horizon_lock:
        plan = lock_horizon(plan, down_world if down_world is not None else down_from_path(angles))
    # The render's decoding starts now, on the other core, while the path is fitted (one thread:
    # the plan's fork is done).
    bits = OutputFormat.of(info, bit_depth).bits
    depth = DECODE_AHEAD_BYTES // (info.width * info.height * 3 // 2 * (2 if bits > 8 else 1))
    with decoding_ahead(src, depth, i420=True, bits=bits) as frames:
        fitted = vt = None
        path, keep = plan, np.ones(len(plan))
        R_old = matrix_from_euler(angles[:, 0], angles[:, 1], angles[:, 2])
        rolling = readout_s != 0.0 and len(R_old) >= 2
        R_rows = warp = lens_zoom = None
        needs: list[tuple[FittedPath, np.ndarray]] = []  # the lens's zoom need of each path tried
        if borders == "crop" and (lens.fisheye or rolling):
            rows = _sensor_rows(intr, info.rotation)
            R_rows = row_rotations(motion.times, R_old, readout_s if rolling else 0.0, rows)
            warp = MeshWarp(intr, info.rotation, lens=lens)
        if borders == "crop":

            def fit(budget: float) -> tuple[FittedPath, VisibleTarget | None]:
                if visible:
                    kw = {"model": model, "anchor_threshold": opts.anchor_threshold}
                    return visible_path(angles, plan, intr, fps, max_zoom=budget, **kw)
                return fit_path(angles, plan, intr, fps, max_zoom=budget), None

            if warp is not None and lens.fisheye:

                def need_of(f: tuple[FittedPath, VisibleTarget | None]) -> np.ndarray:
                    for tried, need in needs:  # the fits are held: identity is safe
                        if tried is f[0]:
                            return need
                    needs.append((f[0], lens_need(warp, f[0].path, R_rows)))
                    return needs[-1][1]

                (fitted, vt), budget = lens_budget(fit, need_of, lambda f: 1.0 / f[0].keep, max_zoom)
                lens_zoom = next((need for tried, need in needs if tried is fitted), None)
                if budget > max_zoom:
                    fitted.notes.append(
                        f"the path was planned with a {budget:.3f}x pinhole budget: through the {lens.kind} lens "
                        f"it needs at most {max_zoom:g}x"
                    )
            else:
                fitted, vt = fit(max_zoom)
            path, keep = fitted.path, fitted.keep
        t2 = time.perf_counter()
        R_new = matrix_from_euler(path[:, 0], path[:, 1], path[:, 2])
        H = homographies(R_old, R_new, intr)
        render_warnings: list[str] = []
        if warp is not None and R_rows is not None:
            views = [FrameView(R_new[k], R_rows[k], 1.0) for k in range(len(R_new))]
            planned_zoom = 1.0 / keep
            zoom, render_warnings = view_zooms(
                warp, views, planned_zoom, max_zoom, _warp_cause(lens, rolling), need=lens_zoom
            )
            for v, z in zip(views, zoom, strict=True):
                v.zoom = float(z)
            keep = 1.0 / zoom
            stats = _render_views(src, dst, views, warp, crf, bit_depth, progress, frames)
            if fitted is not None and np.any(zoom > planned_zoom + 1e-9):
                n = int(np.sum(zoom > planned_zoom + 1e-9))
                fitted.notes.append(f"the {_warp_cause(lens, rolling)} needed more zoom than planned on {n} frames")
        else:
            if rolling:
                render_warnings.append(
                    f"the rolling shutter ({readout_s * 1000:g} ms readout) is corrected only with --borders crop"
                )
            stats = render_stabilized(
                src,
                dst,
                H,
                keep=keep,
                borders=borders,
                R_new=R_new,
                intrinsics=intr,
                crf=crf,
                bit_depth=bit_depth,
                progress=_stage(progress, "render"),
                frames=frames,
            )
    t3 = time.perf_counter()
    scores = {"model": model, "anchor_threshold": opts.anchor_threshold}
    planned_before = motion_scores(angles, fps, intr, **scores)
    planned = motion_scores(path, fps, intr, **scores)
    before = after = None
    if measure:
        masks = None if borders == "crop" else content_masks(H, keep, intr.width, intr.height)
        before = measure_video(src, intr, motion=angles, **scores, progress=progress)
        after = measure_video(dst, intr, masks=masks, zoom=1.0 / keep, **scores, progress=progress)
    t4 = time.perf_counter()
    params = _params(strength, borders, max_zoom, keep_roll, method, intr, opts, model, crf)
    params.update(visible=visible and borders == "crop", horizon_lock=horizon_lock, readout_ms=readout_s * 1000.0)
    params["bit_depth"] = bit_depth
    seconds = {"motion": t1 - t0, "plan": t2 - t1, "render": t3 - t2, "measure": t4 - t3, "total": t4 - t0}
    return StabilizeResult(
        str(dst), motion.times, angles, plan, path, keep, plans, planned, planned_before, before, after, stats,
        fitted, vt, seconds, params, render_warnings=render_warnings,
    )  # fmt: skip


#: Row bands with their own source rotation in a rolling-shutter warp (as the Gyroflow peer's).
RS_BANDS = 16


def row_rotations(times: np.ndarray, R: np.ndarray, readout_s: float, rows: int, bands: int = RS_BANDS) -> np.ndarray:
    """(K, B, 3, 3) camera-to-world orientations of ``bands`` evenly spaced readout positions of
    every frame (first sensor row to last, as :class:`~egovid.fpv.stabilize.warp.FrameView`
    wants them; B = 1 when ``readout_s`` is 0). ``R`` (K, 3, 3) are the orientations at the frame
    time stamps ``times`` (K,) seconds, which are those of the middle row; a sensor of ``rows``
    rows reads row y at :func:`~egovid.core.motion.rolling_shutter.row_offsets` from it (seconds;
    a negative readout reads bottom to top). Between frames the orientation is a C² rotation
    spline through ``R`` (extrapolated by at most half a readout at the clip's ends); with time
    stamps that do not increase, each frame turns at its own central-difference rate."""
    R = np.asarray(R, float)
    if readout_s == 0.0 or len(R) < 2:
        return R[:, None]
    t = np.asarray(times, float)
    s = np.linspace(0.0, 1.0, max(int(bands), 2))
    offsets = row_offsets(s * (rows - 1), rows, readout_s)
    if np.all(np.diff(t) > 0):
        from scipy.spatial.transform import Rotation, RotationSpline

        spline = RotationSpline(t, Rotation.from_matrix(R))
        out = spline((t[:, None] + offsets[None, :]).ravel()).as_matrix()
        return out.reshape(len(R), len(s), 3, 3)
    w = frame_rates(R, t)  # (K, 3) rad/s, each frame's own axes
    return R[:, None] @ so3_exp(w[:, None, :] * offsets[None, :, None])


#: Share of the budget's excess zoom (``max_zoom - 1``) the lens must leave unused before the path
#: is planned again at a larger budget: each try is one more path fit (about 4 s on a 12-s 480p
#: clip), and a raise of a few thousandths moves the path by less than the measured noise of the
#: visible shake (hero6: 2.07-2.19 px over budgets 1.097-1.103).
LENS_BUDGET_MIN_SHARE = 0.1


def lens_budget(
    fit: Callable[[float], T],
    need_of: Callable[[T], np.ndarray],
    zoom_of: Callable[[T], np.ndarray],
    max_zoom: float,
) -> tuple[T, float]:
    """The fit (``fit(budget)``: a path planned with that pinhole zoom budget) whose path the lens
    covers within ``max_zoom`` (``need_of(fit)``: (K,) the zoom the lens needs for each frame), at
    the largest budget tried, and that budget.

    The path programme checks the crop's corners through a pinhole. Through a fisheye the same
    turn of yaw or pitch costs less zoom (the crop's angular margin grows with the field angle as
    ``θ``, not as ``atan``), so a path fitted at ``max_zoom`` leaves part of the margin unused: the
    lens needs ``need0 < max_zoom``. Where the budget binds (the planned zoom, ``zoom_of(fit)``,
    reaches ``max_zoom``; a budget that does not bind is left alone) and the lens leaves at least
    :data:`LENS_BUDGET_MIN_SHARE` of its excess unused, the budget is scaled by the share the lens
    used, ``1 + (max_zoom - 1)² / (need0 - 1)``, at most twice the excess of ``max_zoom`` (the
    linearised corners are not checked beyond that), then half way back; the first whose lens need
    stays within ``max_zoom`` is kept, else the fit at ``max_zoom`` itself. A roll costs the same
    pixels through either lens, so a path that spends its margin on roll gains nothing."""
    first = fit(max_zoom)
    if float(np.max(zoom_of(first))) < max_zoom - 1e-3:
        return first, max_zoom
    need0 = float(np.max(need_of(first)))
    if not (1.0 + 1e-6 < need0 < max_zoom - LENS_BUDGET_MIN_SHARE * (max_zoom - 1.0)):
        return first, max_zoom
    far = min(1.0 + (max_zoom - 1.0) ** 2 / (need0 - 1.0), 1.0 + 2.0 * (max_zoom - 1.0))
    for budget in (far, 0.5 * (far + max_zoom)):
        cand = fit(budget)
        if float(np.max(need_of(cand))) <= max_zoom + 1e-9:
            return cand, budget
    return first, max_zoom


def lens_need(warp: MeshWarp, path: np.ndarray, R_rows: np.ndarray) -> np.ndarray:
    """(K,) zoom ``warp`` needs to cover each frame of ``path`` (K, 3) degrees from ``R_rows``."""
    R_new = matrix_from_euler(path[:, 0], path[:, 1], path[:, 2])
    return required_zoom(warp, [FrameView(R_new[k], R_rows[k], 1.0) for k in range(len(R_new))])


def view_zooms(
    warp: MeshWarp,
    views: list[FrameView],
    planned: np.ndarray,
    max_zoom: float,
    cause: str = "lens",
    need: np.ndarray | None = None,
) -> tuple[np.ndarray, list[str]]:
    """(K,) zoom of each view: the ``planned`` zoom raised to the least one that the warp's own
    projection (lens, rolling shutter) covers, never above ``max_zoom``; and a warning, with what
    to change, when some frames would need more than ``max_zoom`` (their edges show border).
    ``need`` is that least zoom where the caller has it already (:func:`required_zoom` of ``views``)."""
    need = required_zoom(warp, views) if need is None else np.asarray(need, float)
    zoom = np.minimum(np.maximum(np.asarray(planned, float), need), max_zoom)
    over = need > max_zoom + 1e-6
    if not np.any(over):
        return zoom, []
    border = max(
        warp.coverage_shortfall(FrameView(v.R_new, v.R_rows, float(z)))
        for v, z in zip([views[k] for k in np.flatnonzero(over)], zoom[over], strict=True)
    )
    top = float(need.max())
    return zoom, [
        f"the {cause} needs more zoom than --max-zoom {max_zoom:g} on {int(over.sum())} frames (up to {top:.3f}x): "
        f"the zoom is held at {max_zoom:g} and their edges show up to {border:.1f} px of border; "
        f"try --max-zoom {np.ceil(top * 100) / 100:.2f}"
    ]


def _warp_cause(lens: Lens, rolling: bool) -> str:
    """What makes the warp need its own zoom, in words."""
    return " and ".join(x for x, on in (("fisheye lens", lens.fisheye), ("rolling shutter", rolling)) if on)


def _sensor_rows(intr: Intrinsics, rotation: int) -> int:
    """Rows of the sensor (the display's columns where the rotation flag turns the picture)."""
    return intr.width if int(rotation) % 180 == 90 else intr.height


def _render_views(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    views: list[FrameView],
    warp: MeshWarp,
    crf: int,
    bit_depth: str,
    progress: Callable[[str, int, int], None] | None,
    frames: Iterator[Frame] | None = None,
) -> RenderStats:
    """Render ``views`` (their zooms set) through ``warp``, one remap per frame; the render's stats."""
    zoom = np.array([v.zoom for v in views])
    done = render_views(
        src, dst, views, warp, crf=crf, bit_depth=bit_depth, progress=_stage(progress, "render"), frames=frames
    )
    return RenderStats(
        done.frames, 0.0, float(zoom.mean()), float(zoom.max()), done.seconds, done.kept, done.dropped, done.bits
    )


def _params(
    strength: float,
    borders: str,
    max_zoom: float,
    keep_roll: bool,
    method: str,
    intr: Intrinsics,
    opts: OptimizeOptions,
    model: ViewingModel,
    crf: int,
) -> dict:
    """The settings of a run, as :meth:`StabilizeResult.summary` reports them."""
    return {
        "strength": strength,
        "borders": borders,
        "max_zoom": max_zoom if borders == "crop" else None,
        "keep_roll": keep_roll,
        "method": method,
        "focal_px": intr.focal,
        "hfov_deg": intr.hfov_deg,
        "anchor_threshold_deg": opts.anchor_threshold,
        "d_over_f": model.d_over_f,
        "bias_deg": model.bias_deg,
        "crf": crf,
    }


def _estimate(src: str | os.PathLike, intr: Intrinsics, progress: Callable[[int, int], None] | None) -> Trajectory:
    """The camera motion of ``src`` from its pictures, while the planner's kernels load."""
    with kernels_loading():
        return estimate_motion(src, intr, progress=progress).trajectory


def _stage(progress: Callable[[str, int, int], None] | None, stage: str) -> Callable[[int, int], None] | None:
    """``progress`` for one stage, as ``(done, total)``."""
    return (lambda d, t: progress(stage, d, t)) if progress else None
