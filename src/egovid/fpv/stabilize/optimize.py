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
own rule (:func:`egovid.fpv.perception.score.axis_windows`; roll shifted by the other axes' motion);
long motions are cut into overlapping blocks of anchors, each solved by scipy's differential
evolution with the anchors on its left already decided, so the cost grows linearly with length;
the block's objective is the RMS over the windows its anchors influence. Motions are planned at
the model's 30 fps (the caller resamples; :func:`egovid.fpv.stabilize.pipeline.plan_motion`).
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.optimize import differential_evolution

from egovid.fpv.perception.model import MODEL_FPS, ViewingModel
from egovid.fpv.perception.score import AXES, axis_geometry, axis_windows_kernel
from egovid.fpv.stabilize.fpm import (
    AnchorGeometry,
    anchor_geometry,
    ease,
    ease_into,
    motion_anchors,
    motion_trend,
    reduce_anchors,
)
from egovid.fpv.stabilize.lut import EasingLUT


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


@njit(cache=True)
def _pairwise_sum(x: np.ndarray) -> float:
    """Sum of a 1-D array in NumPy's pairwise order, so that means match ``np.mean`` bit for bit."""
    n = x.shape[0]
    if n < 8:
        res = 0.0
        for i in range(n):
            res += x[i]
        return res
    if n <= 128:
        r = x[:8].copy()
        i = 8
        while i < n - (n % 8):
            for j in range(8):
                r[j] += x[i + j]
            i += 8
        res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        while i < n:
            res += x[i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise_sum(x[:n2]) + _pairwise_sum(x[n2:])


@njit(cache=True)
def _axis_rms(a, col, kinds, shifts, fovs, halfs, ps, thr, n1, sacc, sve):  # pragma: no cover - numba
    """RMS of one axis's VE/SVE windows of the (m, 3) motion ``a`` (degrees, model rate), by
    :func:`egovid.fpv.perception.score.axis_windows_kernel`; the mean in NumPy's summation order."""
    out = axis_windows_kernel(a, col, kinds, shifts, fovs, halfs, ps, thr, n1, sacc, sve, False)
    if out.shape[0] == 0:
        return 1.0
    return math.sqrt(_pairwise_sum(out * out) / out.shape[0])


@njit(cache=True)
def _interp_into(anchors: np.ndarray, values: np.ndarray, lo: int, hi: int, out: np.ndarray) -> None:
    """Frames ``lo`` to ``hi - 1`` of the zigzag through the anchors (``np.interp``'s arithmetic,
    so equal to :func:`egovid.fpv.stabilize.fpm.pure_fpm` bit for bit)."""
    last = anchors.shape[0] - 1
    j = 0
    for t in range(lo, hi):
        x = float(t)
        while j < last and anchors[j + 1] <= x:
            j += 1
        if j == last or anchors[j] == x:
            out[t - lo] = values[j]
        else:
            slope = (values[j + 1] - values[j]) / (anchors[j + 1] - anchors[j])
            out[t - lo] = slope * (x - anchors[j]) + values[j]


@njit(cache=True)
def _objective(
    D, values, direction, room, movable, anchors, seg_len, log_amps, table,
    ctx, lo, hi, col, kinds, shifts, fovs, halfs, ps, thr, n1, sacc, sve, tie,
):  # fmt: skip  # pragma: no cover - numba
    """Eq. 9.4 without the FPMR term, on frames [lo, hi) of the (n, 3) motion ``ctx`` whose
    column ``col`` is planned: anchors reduced by ``D`` (eq. 9.1 towards the trend), easing
    looked up in ``table`` (nearest log-amplitude in ``log_amps``; segment-length cells
    ``seg_len``), the eased and the pure motion drawn on those frames only and scored by
    :func:`_axis_rms`, and the tie-break towards reduction (see :meth:`AxisModel.objective`)."""
    T = anchors.shape[0]
    v = np.empty(T)
    for i in range(T):
        d = min(max(D[i], 0.0), 1.0)
        v[i] = values[i] + direction[i] * d * room[i]
    k = np.empty(max(T - 1, 0))
    s = np.empty(max(T - 1, 0))
    for i in range(T - 1):
        la = math.log(max(abs(v[i + 1] - v[i]), 1e-6))
        best = 0
        dist = abs(la - log_amps[0])
        for j in range(1, log_amps.shape[0]):
            dj = abs(la - log_amps[j])
            if dj < dist:
                best, dist = j, dj
        k[i] = table[best, seg_len[i], 0]
        s[i] = table[best, seg_len[i], 1]
    a = ctx[lo:hi].copy()
    line = np.empty(hi - lo)
    ease_into(anchors, v, k, s, lo, hi, line)
    a[:, col] = line
    j_val = 1.0 - _axis_rms(a, col, kinds, shifts, fovs, halfs, ps, thr, n1, sacc, sve)
    _interp_into(anchors.astype(np.float64), v, lo, hi, line)
    a[:, col] = line
    j_val += _axis_rms(a, col, kinds, shifts, fovs, halfs, ps, thr, n1, sacc, sve)
    count = 0
    for i in range(T):
        if movable[i]:
            count += 1
    if count:
        kept = np.empty(count)
        c = 0
        for i in range(T):
            if movable[i]:
                kept[c] = 1.0 - min(max(D[i], 0.0), 1.0)
                c += 1
        j_val += tie * (_pairwise_sum(kept) / count)
    return j_val


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
        # What the compiled objective needs: the easing table's cells, each component's geometry.
        table = self.lut.tables[self.kind]
        self._log_amps = np.log(self.lut.amplitudes)
        self._seg_len = np.abs((np.diff(self.anchors) / MODEL_FPS)[:, None] - self.lut.durations[None, :]).argmin(1)
        self._table = np.ascontiguousarray(table, dtype=np.float64)
        self._axis = axis_geometry(axis, hfov, vfov, model)
        self._movable = self.geom.room > 0

    def values(self, D: np.ndarray) -> np.ndarray:
        return reduce_anchors(self.geom, D)

    def shape(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        swing = np.abs(np.diff(values))
        return self.lut.lookup(self.kind, swing, np.diff(self.anchors) / MODEL_FPS)

    def edited(self, D: np.ndarray) -> np.ndarray:
        v = self.values(D)
        k, s = self.shape(v)
        return ease(self.anchors, v, k, s, self.n)

    def objective(self, D: np.ndarray, lo: int = 0, hi: int | None = None) -> float:
        """Eq. 9.4 on frames [lo, hi) (one compiled call, :func:`_objective`; the eased and pure
        motions are drawn on those frames only).

        VE saturates near 1 and the pure-FPM VE has a plateau (Fig. 9.3b), so J is often flat in
        D; a small preference for reduction (``tie_break``) resolves the tie towards the thesis'
        "point B", the most stable motion that still keeps the first-person feeling."""
        hi = self.n if hi is None else min(hi, self.n)
        j = _objective(
            np.asarray(D, dtype=np.float64),
            self.geom.values, self.geom.direction, self.geom.room, self._movable,
            self.anchors, self._seg_len, self._log_amps, self._table,
            self.context, int(lo), int(hi), self.col,
            self._axis.kinds, self._axis.shifts, self._axis.fovs, self._axis.halfs, self._axis.ps, self._axis.thr,
            self.model.window_frames, self.model.saccade_frames, self.opts.method == "sve", self.opts.tie_break,
        )  # fmt: skip
        if self.alpha.any():
            v = self.values(D)
            with np.errstate(divide="ignore", invalid="ignore"):
                dfpmr = np.where(self.dtheta != 0, 1.0 - np.diff(v) / self.dtheta, 0.0)
            j += float(self.alpha @ dfpmr)
        return j


def load_kernels() -> None:
    """Load the compiled objective and the easing table now (~0.3 s the first time in a process),
    so that a planner forked afterwards inherits them instead of loading them again."""
    theta = np.linspace(0.0, 1.0, 16)
    am = AxisModel(theta, "yaw", 90.0, 60.0, ViewingModel(), OptimizeOptions())
    am.objective(np.zeros(len(am.anchors)))


@contextlib.contextmanager
def kernels_loading() -> Iterator[None]:
    """:func:`load_kernels` on a thread while the block runs (the motion stage leaves the
    interpreter free most of the time: OpenCV, FFmpeg and the compiled fits run without the GIL);
    joined when the block ends, so that no thread holds a lock when the planner forks."""
    loader = threading.Thread(target=load_kernels, name="load-planner", daemon=True)
    loader.start()
    try:
        yield
    finally:
        loader.join()


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
