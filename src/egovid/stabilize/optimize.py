"""Optimise the edited first-person motion (thesis §9.3): reduction rates D of the motion anchors,
easing shapes from the look-up table, objective (9.4).

Per axis, the objective is

    J(D) = 1 - M(θ̃) + M(θ̃p) + α_FPMR · ΔFPMR          (eq. 9.4)

with θ̃ the eased motion through the reduced anchors, θ̃p its pure FPM (the zigzag), M the VE (or
SVE) of that axis, α_FPMR the weights of motions larger than the field of view (eq. 9.5–9.6) and
ΔFPMR(i) = 1 - Δθ̃(i)/Δθ(i) the loss of their amplitude (eq. 9.7 written on amplitudes: the
absolute angle has an arbitrary zero). Lowering anchor amplitudes raises M(θ̃) (stability) but also
M(θ̃p), which is the loss of first-person motion information; the optimum sits where the eased
motion is already comfortable while its zigzag still carries the first-person feeling (point B of
Fig. 9.3b).

Choices (docs/fpv.md): axes are optimised separately with their own VE (the thesis couples them
through the minimum of eq. 8.12, which only the worst axis would feel), computed by the scores'
own rule (:func:`egovid.perception.score.axis_windows`; roll shifted by the other axes' motion);
long motions are cut into overlapping blocks of anchors, each solved by scipy's differential
evolution with the anchors on its left already decided, so the cost grows linearly with length;
the block's objective is the RMS over the windows its anchors influence. Motions are planned at
the model's 30 fps (the caller resamples; :func:`egovid.stabilize.pipeline.plan_motion`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import differential_evolution

from egovid.perception.model import MODEL_FPS, ViewingModel
from egovid.perception.score import AXES, axis_windows
from egovid.stabilize.fpm import (
    AnchorGeometry,
    anchor_geometry,
    ease,
    motion_anchors,
    motion_trend,
    pure_fpm,
    reduce_anchors,
)
from egovid.stabilize.lut import EasingLUT


@dataclass
class OptimizeOptions:
    """Tuning of :func:`optimize_axis`.

    ``anchor_threshold``: degrees a motion must turn back to make an anchor; ``block`` anchors per
    optimisation block and ``stride`` anchors kept from each; ``d_max`` the largest reduction rate;
    ``maxiter``/``popsize`` of differential evolution; ``method`` ve or sve.
    """

    anchor_threshold: float = 0.5
    block: int = 6
    stride: int = 4
    d_max: float = 1.0
    maxiter: int = 12
    popsize: int = 5
    method: str = "ve"
    seed: int = 0
    tie_break: float = 0.01


@dataclass
class AxisPlan:
    """The edited motion of one axis and what the optimiser decided."""

    axis: str
    original: np.ndarray
    edited: np.ndarray
    anchors: np.ndarray
    anchor_values: np.ndarray
    new_anchor_values: np.ndarray
    D: np.ndarray
    k: np.ndarray
    s: np.ndarray
    evaluations: int = 0
    notes: list[str] = field(default_factory=list)


class AxisModel:
    """Everything needed to turn reduction rates into an edited motion and score it.

    ``theta`` is one axis of a motion at the model's 30 fps; ``context`` the whole (K, 3) motion
    (the other axes shift roll's intervals, eq. 8.2–8.3; default: still)."""

    def __init__(
        self,
        theta: np.ndarray,
        axis: str,
        hfov: float,
        vfov: float,
        model: ViewingModel,
        opts: OptimizeOptions,
        lut: EasingLUT | None = None,
        context: np.ndarray | None = None,
    ) -> None:
        self.theta = np.asarray(theta, dtype=float)
        self.n = len(self.theta)
        self.axis = axis
        self.col = AXES.index(axis)
        self.kind = "roll" if axis == "roll" else "yaw"
        self.hfov, self.vfov = hfov, vfov
        fov = vfov if axis == "pitch" else hfov
        self.model = model
        self.opts = opts
        self.lut = lut or EasingLUT.default()
        self.context = np.zeros((self.n, 3)) if context is None else np.array(context, dtype=float)
        self.anchors = motion_anchors(self.theta, opts.anchor_threshold)
        trend = motion_trend(self.theta, self.anchors)[self.anchors]
        self.geom: AnchorGeometry = anchor_geometry(self.anchors, self.theta[self.anchors], trend)
        # FPMR weights (eq. 9.5-9.6): motions between consecutive anchors larger than the view.
        dtheta = np.diff(self.geom.values)
        big = np.abs(dtheta) > fov
        self.alpha = np.zeros(len(dtheta))
        if big.any():
            self.alpha[big] = np.abs(dtheta[big]) / np.abs(dtheta[big]).sum()
        self.dtheta = dtheta

    def values(self, D: np.ndarray) -> np.ndarray:
        return reduce_anchors(self.geom, D)

    def shape(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        swing = np.abs(np.diff(values))
        return self.lut.lookup(self.kind, swing, np.diff(self.anchors) / MODEL_FPS)

    def edited(self, D: np.ndarray) -> np.ndarray:
        v = self.values(D)
        k, s = self.shape(v)
        return ease(self.anchors, v, k, s, self.n)

    def score(self, theta: np.ndarray, lo: int = 0) -> float:
        """RMS of this axis's VE (or SVE) windows for ``theta`` on frames ``lo`` onwards."""
        a = self.context[lo : lo + len(theta)].copy()
        a[:, self.col] = theta
        w = axis_windows(a, self.axis, self.hfov, self.vfov, self.model, self.opts.method)
        return float(np.sqrt(np.mean(w * w))) if len(w) else 1.0

    def objective(self, D: np.ndarray, lo: int = 0, hi: int | None = None) -> float:
        """Eq. 9.4 on frames [lo, hi)."""
        v = self.values(D)
        k, s = self.shape(v)
        eased = ease(self.anchors, v, k, s, self.n)[lo:hi]
        pure = pure_fpm(self.anchors, v, self.n)[lo:hi]
        j = 1.0 - self.score(eased, lo) + self.score(pure, lo)
        # VE saturates near 1 and the pure-FPM VE has a plateau (Fig. 9.3b), so J is often flat in
        # D; a small preference for reduction resolves the tie towards the thesis' "point B", the
        # most stable motion that still keeps the first-person feeling.
        movable = self.geom.room > 0
        if movable.any():
            j += self.opts.tie_break * float(np.mean(1.0 - np.clip(D[movable], 0.0, 1.0)))
        if self.alpha.any():
            with np.errstate(divide="ignore", invalid="ignore"):
                dfpmr = np.where(self.dtheta != 0, 1.0 - np.diff(v) / self.dtheta, 0.0)
            j += float(self.alpha @ dfpmr)
        return j


def optimize_axis(
    theta: np.ndarray,
    axis: str,
    hfov: float,
    vfov: float,
    model: ViewingModel | None = None,
    opts: OptimizeOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
    context: np.ndarray | None = None,
) -> AxisPlan:
    """Edited motion of one axis (degrees per frame at the model's 30 fps) minimising eq. 9.4
    block by block; ``hfov``/``vfov`` in degrees, ``context`` the (K, 3) motion around it."""
    model = model or ViewingModel()
    opts = opts or OptimizeOptions()
    am = AxisModel(theta, axis, hfov, vfov, model, opts, context=context)
    T = len(am.anchors)
    D = np.zeros(T)
    movable = np.flatnonzero(am.geom.room > 0)
    evals = 0
    notes: list[str] = []
    if len(movable) == 0:
        notes.append("nothing to reduce: the motion follows its trend (monotonic, or below the anchor threshold)")
    else:
        D[movable] = 0.5 * opts.d_max  # right context for the first blocks
        margin = model.window_frames + 2
        starts = list(range(0, len(movable), opts.stride))
        for b, start in enumerate(starts):
            idx = movable[start : start + opts.block]
            lo = max(0, int(am.anchors[max(idx[0] - 1, 0)]) - margin)
            hi = min(am.n, int(am.anchors[min(idx[-1] + 1, T - 1)]) + margin + 1)
            base = D.copy()

            def f(x: np.ndarray, idx=idx, base=base, lo=lo, hi=hi) -> float:
                trial = base.copy()
                trial[idx] = x
                return am.objective(trial, lo, hi)

            res = differential_evolution(
                f,
                [(0.0, opts.d_max)] * len(idx),
                maxiter=opts.maxiter,
                popsize=opts.popsize,
                tol=1e-4,
                seed=opts.seed + b,
                polish=False,
                init="sobol",
                x0=np.clip(base[idx], 0.0, opts.d_max),
            )
            evals += int(res.nfev)
            keep = idx if start + opts.block >= len(movable) else idx[: opts.stride]
            D[keep] = res.x[: len(keep)]
            D[idx[len(keep) :]] = res.x[len(keep) :]
            if progress is not None:
                progress(b + 1, len(starts))
    v = am.values(D)
    k, s = am.shape(v)
    return AxisPlan(
        axis=axis,
        original=am.theta,
        edited=ease(am.anchors, v, k, s, am.n),
        anchors=am.anchors,
        anchor_values=am.geom.values,
        new_anchor_values=v,
        D=D,
        k=k,
        s=s,
        evaluations=evals,
        notes=notes,
    )
