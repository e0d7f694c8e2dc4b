"""Below the plan: remove what a viewer sees as shake, as far as the plan's FPMI allows.

The thesis' plan (ch. 9) keeps the motion anchors (their amplitude and timing: the first-person
motion information, FPMI) and eases the path between them. What a viewer sees as shake is the
image path's curvature at time scales under about half a second: the independent measure
(``shake.py``: the frame-to-frame image shift minus its centred 15-frame moving average) counts
everything above about 1.5 Hz fully, a walking bob as much as hand tremor, and the start and stop
of a pan by their acceleration. The two pull against each other only where the anchors are fast.

So the path the frame renders is the plan low-passed (zero-phase Butterworth, order 2) at the
lowest cutoff whose fitted path still keeps ``fpmi_floor`` of the plan's own FPMI (``1 - VE`` of
its pure FPM, measured by the scores' rule at the model's rate): a plan whose FPMI is a slow look around, a pan
or a turn is smoothed at 0.5 Hz and loses nothing a viewer would call intended; a plan whose FPMI
is a running bob keeps the bob (lowering the cutoff would take it away) and only what lies above
the bob's band goes. A plan with no FPMI worth keeping (under
:data:`~egovid.fpv.stabilize.measure.FPMI_NONE`: a drive, a steady pan) keeps it at any cutoff,
so it is smoothed at the lowest (the share of a near-zero FPMI is noise: a shaky drive once fell
back to its plan at 0.48 of 0.0009 and kept 7 × the shake; the check against the input's FPMI
below is unchanged). The FPMI a path keeps grows with the cutoff, give or take a percent (the
low-passed plan nears the plan), so the lowest cutoff is fitted first (a slow plan keeps its
FPMI there: one fit), then the highest; only when the highest keeps the floor are the ones
between fitted, lowest first, and the lowest that keeps it chosen, as fitting every cutoff in
order would; when the highest keeps too little, the plan itself is used without fitting those
between (the running clip of ``benchmarks/stabilize_vs_vidstab.py --speed`` kept 54, 54, 53
and 80 % of the plan's FPMI at 0.5-4 Hz against the 90 % floor: three path fits instead of five,
0.5 s each at 720p; the real clips in ``../shared/data/real`` keep it at 0.5 Hz). The low-passed
plan then goes to the path programme
(:func:`egovid.fpv.stabilize.path.fit_path`), which bends it into the zoom budget, with weights
(:data:`VISIBLE_WEIGHTS`) that make the budget work: where the target cannot be shown (a fast pan
at the end of a clip, a plan that strays further than the crop allows), the path's own curvature
(second and third differences, 10 and 33 times the default weight) costs more than being away
from the target (a twentieth of the default) or cropping (a fifth), so the path is the smoothest
one the crop can cover there instead of the crop's edge hugging the recorded motion.

The plan may itself keep less of the input's FPMI than the floor (its anchors reduced by eq. 9.1,
as the thesis' optimum chose): on a handheld pan the plan kept 47 % and the decoded output 85 %.
What a viewer calls first-person motion is the input's, so when the chosen path keeps less than
``fpmi_floor`` of the input's FPMI, the anchor amplitude the plan took away is given back (the
input's pure FPM minus the plan's, added to the plan) and low-passed at the slow cutoffs only
(:data:`RESTORE_CUTOFFS_HZ`: swings of a second or more; faster turn-backs are shake's, which the
low-pass keeps out); the first such path that keeps ``fpmi_floor`` of the input's FPMI is used,
else the plan's own. The check is on the fitted path with a margin (:data:`FPMI_MARGIN`) for what
the decoded output measures differently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.fpv.perception.model import ViewingModel
from egovid.fpv.stabilize.measure import FPMI_NONE, motion_scores, pure_motion
from egovid.fpv.stabilize.path import FittedPath, PathWeights, fit_path

#: Cutoffs tried (Hz), lowest first (at least two: the lowest and the highest are fitted first).
CUTOFFS_HZ = (0.5, 1.0, 2.0, 4.0)
#: Share of the plan's FPMI the low-passed plan must keep.
FPMI_FLOOR = 0.9
#: Added to ``fpmi_floor`` for the input's FPMI on the fitted path (the decoded output's
#: re-estimated motion reads the anchors a little differently).
FPMI_MARGIN = 0.02
#: Cutoffs (Hz) at which the plan's reduced anchor amplitude is given back, lowest first.
RESTORE_CUTOFFS_HZ = (0.5, 1.0)
#: Path-programme weights below the plan (module docstring).
VISIBLE_WEIGHTS = PathWeights(plan=0.05, d1=10.0, d2=300.0, d3=1000.0, zoom=0.2)


@dataclass
class VisibleTarget:
    """The low-passed plan (K, 3) degrees, the cutoff used (Hz; None = the plan unchanged), the
    share of the plan's FPMI it keeps, the share of the input's (``fpmi_kept_input``) and whether
    the plan's reduced anchor amplitude was given back (``restored``)."""

    target: np.ndarray
    cutoff_hz: float | None
    fpmi_kept: float
    fpmi_kept_input: float = float("nan")
    restored: bool = False


def low_pass(angles: np.ndarray, fps: float, cutoff_hz: float) -> np.ndarray:
    """Zero-phase order-2 Butterworth low-pass of the columns of ``angles`` (K, D) at ``fps``."""
    from scipy.signal import butter, sosfiltfilt

    a = np.asarray(angles, dtype=float)
    if len(a) < 8 or cutoff_hz >= 0.45 * fps:
        return a.copy()
    sos = butter(2, cutoff_hz, fs=fps, output="sos")
    pad = min(len(a) - 1, int(3 * fps / cutoff_hz))
    return sosfiltfilt(sos, a, axis=0, padtype="odd", padlen=pad)


def visible_path(
    original: np.ndarray,
    plan: np.ndarray,
    intr: Intrinsics,
    fps: float,
    *,
    max_zoom: float = 1.10,
    fpmi_floor: float = FPMI_FLOOR,
    model: ViewingModel | None = None,
    anchor_threshold: float = 0.5,
    weights: PathWeights | None = None,
) -> tuple[FittedPath, VisibleTarget]:
    """The rendered path and zoom below ``plan`` (both (K, 3) degrees per frame at ``fps``, with
    the recorded ``original``): the plan low-passed at the lowest cutoff of :data:`CUTOFFS_HZ`
    whose path, bent into ``max_zoom`` by the path programme with :data:`VISIBLE_WEIGHTS`, still
    keeps ``fpmi_floor`` of the plan's FPMI (the crop may not let the path follow the low-passed
    plan: a pan at the clip's end, so the check is on the path, not the target; the cutoffs between
    the lowest and the highest are fitted only when the highest keeps it, module docstring); the plan itself
    with those weights when no cutoff does. When that path keeps less than ``fpmi_floor`` +
    :data:`FPMI_MARGIN` of the input's FPMI, the plan with its reduced anchor amplitude given back,
    low-passed at :data:`RESTORE_CUTOFFS_HZ`, is used instead where its path keeps that much
    (module docstring; a note in ``FittedPath.notes`` says so)."""
    w = weights or VISIBLE_WEIGHTS
    kw = {"model": model, "anchor_threshold": anchor_threshold}

    def fpmi(a: np.ndarray) -> float:
        return 1.0 - motion_scores(a, fps, intr, **kw).pure_fpm_ve

    def share(a: np.ndarray, base: float, least: float = 1e-6) -> float:
        return fpmi(a) / base if base >= least else 1.0

    base, base_in = fpmi(plan), fpmi(original)

    def attempt(hz: float) -> tuple[FittedPath, VisibleTarget]:
        target = low_pass(plan, fps, hz)
        fitted = fit_path(original, target, intr, fps, max_zoom=max_zoom, weights=w)
        return fitted, VisibleTarget(target, hz, float(share(fitted.path, base, FPMI_NONE)))

    def keeps(c: tuple[FittedPath, VisibleTarget]) -> bool:
        return c[1].fpmi_kept >= fpmi_floor

    # The lowest cutoff, then the highest, then those between, lowest first (module docstring).
    lowest, *middle, highest = CUTOFFS_HZ
    chosen = attempt(lowest)
    if not keeps(chosen):
        chosen = attempt(highest)
        chosen = next(filter(keeps, map(attempt, middle)), chosen) if keeps(chosen) else None
    if chosen is None:
        fitted = fit_path(original, plan, intr, fps, max_zoom=max_zoom, weights=w)
        chosen = fitted, VisibleTarget(np.asarray(plan, float).copy(), None, float(share(fitted.path, base, FPMI_NONE)))
    chosen[1].fpmi_kept_input = kept_in = float(share(chosen[0].path, base_in))
    if kept_in >= fpmi_floor + FPMI_MARGIN:
        return chosen
    restored = plan + pure_motion(original, anchor_threshold) - pure_motion(plan, anchor_threshold)
    for hz in RESTORE_CUTOFFS_HZ:
        target = low_pass(restored, fps, hz)
        fitted = fit_path(original, target, intr, fps, max_zoom=max_zoom, weights=w)
        kept_in = share(fitted.path, base_in)
        if kept_in >= fpmi_floor + FPMI_MARGIN:
            fitted.notes.append(
                f"the plan kept {100 * share(plan, base_in):.0f} % of the input's first-person motion: its anchors' "
                f"amplitude given back below {hz:g} Hz ({100 * kept_in:.0f} % kept)"
            )
            return fitted, VisibleTarget(target, hz, float(share(fitted.path, base, FPMI_NONE)), float(kept_in), True)
    return chosen
