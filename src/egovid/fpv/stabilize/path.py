"""The camera path the frame can afford: the planned motion bent into the crop, and a dynamic zoom.

The thesis plans the edited motion (ch. 9) without asking whether the frame can show it: every
degree the new view turns away from the recorded one has to be cropped away, and a fixed crop for
the whole clip is set by its single worst frame. egovid therefore fits the final path and a zoom
that changes over time together, by one linear programme in the spirit of the L1-optimal camera
paths of Grundmann, Kwatra and Essa (CVPR 2011), with the thesis' plan as the target:

    minimise   Σ_k  w_d |d_k| + w_1 |Δd_k| + w_2 |Δ²d_k| + w_3 |Δ³d_k|           (per axis)
             + Σ_k  w_z (1 - s_k) + v_1 |Δs_k| + v_2 |Δ²s_k| + v_3 |Δ³s_k|
    subject to every corner of output frame k, zoomed by 1/s_k, seen through the source frame
               k (the rotation from the recorded to the new orientation, linearised), and
               1 / max_zoom <= s_k <= 1,

where ``d_k = path_k - plan_k`` (degrees, yaw/pitch/roll) is how far the path leaves the plan and
``s_k`` is the share of the frame kept (zoom ``1/s_k``). Where the plan fits, the path is the plan;
where it does not, the path leaves it by a smooth, piecewise-polynomial detour (the L1 terms on the
differences make the detour start and end without a jerk) and never by the recorded jitter; the
zoom rises only around the frames that need it and returns smoothly. A fast intentional pan
becomes a pan of the path, at most the crop margin away from the recorded one, so it is followed
without lag beyond that margin. The weights are per second of video (scaled by the frame rate), so
the result does not depend on it.

The corner constraints are linear in the path and the zoom after linearising the rotation
``Rᵀ R̃ ≈ I + [ω]×`` (ω = J δ from the Euler-angle deviation δ) and the perspective terms at the
current zoom; each solve is followed by the exact check of every corner, and frames that the
linearisation got wrong get a larger margin and the programme is solved again (at most three
passes, then the path of any frame still short is pulled towards the recorded one, by the least
blend the budget covers, eased over a quarter second: the zoom never exceeds ``max_zoom``). Long clips are
solved in overlapping blocks whose starts are tied to the previous block's result, so the cost
grows linearly with length.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.ndimage import minimum_filter1d, uniform_filter1d
from scipy.optimize import linprog

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.rotations import matrix_from_euler

#: A corner may miss its source frame by this much (pixels): a 5 % blend of the border into the
#: outermost pixel, invisible, where the linearised programme touched its limit.
SHORTFALL_TOLERANCE_PX = 0.05


@dataclass(frozen=True)
class PathWeights:
    """L1 weights of the path programme per frame at 30 fps (scaled for other rates so that the
    result depends on time, not frames; see the module docstring).

    ``plan`` per degree of leaving the plan; ``d1``-``d3`` on its first to third differences;
    ``zoom`` per percent of the frame's width cropped; ``z1``-``z3`` on that percentage's
    differences."""

    plan: float = 1.0
    d1: float = 10.0
    d2: float = 30.0
    d3: float = 100.0
    zoom: float = 1.0
    z1: float = 10.0
    z2: float = 30.0
    z3: float = 100.0


@dataclass
class FittedPath:
    """The final (K, 3) path in degrees, the share ``keep`` (K,) of the frame kept (zoom 1/keep),
    and what the fit did."""

    path: np.ndarray
    keep: np.ndarray
    passes: int
    seconds: float
    notes: list[str] = field(default_factory=list)

    @property
    def zoom(self) -> np.ndarray:
        """Per-frame zoom factor (>= 1)."""
        return 1.0 / self.keep


def _corners(intr: Intrinsics) -> np.ndarray:
    w, h = intr.width, intr.height
    return np.array([[0.0, 0.0], [w - 1.0, 0.0], [w - 1.0, h - 1.0], [0.0, h - 1.0]])


def deviation_jacobian(angles: np.ndarray) -> np.ndarray:
    """(K, 3, 3): ω (radians, in the recorded camera's frame) of ``R(θ)ᵀ R(θ + δ)`` per degree of
    δ = (yaw, pitch, roll), at δ = 0 (central differences)."""
    eps = 1e-3
    a = np.asarray(angles, dtype=float)
    R = matrix_from_euler(a[:, 0], a[:, 1], a[:, 2])
    out = np.empty((len(a), 3, 3))
    for i in range(3):
        step = np.zeros(3)
        step[i] = eps
        p = a + step
        m = a - step
        dR = matrix_from_euler(p[:, 0], p[:, 1], p[:, 2]) - matrix_from_euler(m[:, 0], m[:, 1], m[:, 2])
        W = np.swapaxes(R, 1, 2) @ dR / (2 * eps)
        out[:, :, i] = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    return out


def corner_positions(original: np.ndarray, path: np.ndarray, keep: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(K, 4, 2) exact source-pixel positions of the 4 corners of every output frame."""
    return _corner_positions(_rotation_products(original, path), keep, intr)


def _rotation_products(original: np.ndarray, path: np.ndarray) -> np.ndarray:
    """(K, 3, 3, 3) products ``Rᵀ[k, i, j] R̃[k, j, l]`` of the recorded (``R``) and the new
    (``R̃``) orientations, the part of :func:`corner_positions` that the zoom does not change:
    computed once for a bisection, whose steps change only the zoom."""
    R = matrix_from_euler(original[:, 0], original[:, 1], original[:, 2])
    Rn = matrix_from_euler(path[:, 0], path[:, 1], path[:, 2])
    return np.swapaxes(R, 1, 2)[:, :, :, None] * Rn[:, None, :, :]


def _corner_positions(P: np.ndarray, keep: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """:func:`corner_positions` from the products of :func:`_rotation_products`."""
    c = np.array([(intr.width - 1) / 2.0, (intr.height - 1) / 2.0])
    U = c + keep[:, None, None] * (_corners(intr)[None] - c)  # (K, 4, 2) stabilised-view pixels
    rays = np.concatenate([(U - [intr.cx, intr.cy]) / [intr.fx, intr.fy], np.ones((*U.shape[:2], 1))], axis=2)
    # v[k, c, i] = Σ_j Σ_l (Rᵀ[k, i, j] R̃[k, j, l]) rays[k, c, l], summed in the order
    # np.einsum("kij,kjl,kcl->kci") sums (l inside j, each sum from 0), so that the positions are
    # the same to the bit as that einsum's, without its cost on every step of a bisection.
    T = P[:, None] * rays[:, :, None, None, :]  # (K, 4, i, j, l)
    v = np.zeros(T.shape[:3])
    for j in range(3):
        v = v + (((0.0 + T[..., j, 0]) + T[..., j, 1]) + T[..., j, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(v[..., 2:3] > 1e-6, v[..., :2] / v[..., 2:3], np.inf)
    return x * [intr.fx, intr.fy] + [intr.cx, intr.cy]


def coverage_shortfall(original: np.ndarray, path: np.ndarray, keep: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(K,) pixels by which the farthest output corner falls outside its source frame (<= 0: covered)."""
    return _shortfall(_rotation_products(original, path), keep, intr)


def _shortfall(P: np.ndarray, keep: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """:func:`coverage_shortfall` from the products of :func:`_rotation_products`."""
    X = _corner_positions(P, keep, intr)
    lo = -X
    hi = X - [intr.width - 1.0, intr.height - 1.0]
    return np.max(np.maximum(lo, hi), axis=(1, 2))


def required_keep(original: np.ndarray, path: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(K,) the largest share of the frame each frame can keep with ``path`` (exact, bisection)."""
    P = _rotation_products(original, path)
    lo = np.zeros(len(path))
    hi = np.ones(len(path))
    ok = _shortfall(P, hi, intr) <= 1e-9
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        good = _shortfall(P, mid, intr) <= 1e-9
        lo = np.where(good, mid, lo)
        hi = np.where(good, hi, mid)
    return np.where(ok, 1.0, lo)


class _LP:
    """Sparse LP assembly: variables in blocks, rows as COO triplets, L1 terms by slack variables."""

    def __init__(self) -> None:
        self.n = 0
        self.m = 0
        self.cost: list[np.ndarray] = []
        self.lo: list[np.ndarray] = []
        self.hi: list[np.ndarray] = []
        self._r: list[np.ndarray] = []
        self._c: list[np.ndarray] = []
        self._v: list[np.ndarray] = []
        self._b: list[np.ndarray] = []

    def copy(self) -> _LP:
        """A programme to extend without touching this one: the lists are new, the term arrays
        shared (never written), the bounds copied (a window's head fixes some)."""
        out = _LP()
        out.n, out.m = self.n, self.m
        out.cost = list(self.cost)
        out.lo = [a.copy() for a in self.lo]
        out.hi = [a.copy() for a in self.hi]
        out._r, out._c, out._v, out._b = list(self._r), list(self._c), list(self._v), list(self._b)
        return out

    def add_vars(self, count: int, cost: float = 0.0, lo: float = -np.inf, hi: float = np.inf) -> slice:
        s = slice(self.n, self.n + count)
        self.n += count
        self.cost.append(np.full(count, float(cost)))
        self.lo.append(np.full(count, float(lo)))
        self.hi.append(np.full(count, float(hi)))
        return s

    def add_rows(self, cols: list[tuple[slice, sp.spmatrix]], rhs: np.ndarray) -> None:
        """Rows ``Σ_i M_i x[slice_i] <= rhs``."""
        rhs = np.asarray(rhs, float)
        for sl, M in cols:
            M = sp.coo_matrix(M)
            self._r.append(M.row + self.m)
            self._c.append(M.col + sl.start)
            self._v.append(M.data)
        self._b.append(rhs)
        self.m += len(rhs)

    def l1(self, target: slice, M: sp.spmatrix, weight: float) -> None:
        """Add ``weight * Σ |M x[target]|``."""
        m = M.shape[0]
        if m == 0 or weight <= 0:
            return
        e = self.add_vars(m, weight, 0.0)
        eye = sp.identity(m, format="coo")
        self.add_rows([(target, M), (e, -eye)], np.zeros(m))
        self.add_rows([(target, -M), (e, -eye)], np.zeros(m))

    def solve(self) -> np.ndarray:
        A = sp.csr_matrix(
            (np.concatenate(self._v), (np.concatenate(self._r), np.concatenate(self._c))), shape=(self.m, self.n)
        )
        res = linprog(
            np.concatenate(self.cost),
            A_ub=A,
            b_ub=np.concatenate(self._b),
            bounds=np.stack([np.concatenate(self.lo), np.concatenate(self.hi)], axis=1),
            method="highs-ipm",  # the interior point is 3-4x faster than simplex on these banded L1 problems
        )
        if res.status != 0:
            raise EgovidError(f"the camera-path programme failed ({res.message})", "use --borders black or fill")
        return res.x


def _diff(n: int, order: int) -> sp.csr_matrix:
    D = sp.identity(n, format="csr")
    for _ in range(order):
        D = (D[1:] - D[:-1]).tocsr()
    return D


def bspline_basis(n: int, spacing: float) -> sp.csr_matrix:
    """(n, m) uniform cubic B-spline basis: frame k is at parameter k / spacing; every frame is a
    convex combination of 4 consecutive coefficients, so bounds on coefficients bound the curve."""
    t = np.arange(n) / spacing
    seg = np.minimum(np.floor(t).astype(int), max(int(np.ceil(t[-1])) - 1, 0))
    u = t - seg
    w = np.stack([(1 - u) ** 3, 3 * u**3 - 6 * u**2 + 4, -3 * u**3 + 3 * u**2 + 3 * u + 1, u**3], axis=1) / 6.0
    rows = np.repeat(np.arange(n), 4)
    cols = (seg[:, None] + np.arange(4)[None, :]).ravel()
    return sp.csr_matrix((w.ravel(), (rows, cols)), shape=(n, int(seg.max()) + 4))


@functools.lru_cache(maxsize=16)
def _smoothness_terms(m: int, min_keep: float, weights: PathWeights, H: float) -> _LP:
    """The part of a window's programme that its data do not change, for ``m`` coefficients: the
    variables (yaw, pitch, roll deviations, then the percent cropped ``u``, ``m`` each, in that
    order) and the L1 terms on them. Built once per window size and shared by every window and
    fit of a job (a path fit solves several; extend a :meth:`_LP.copy`, never this)."""
    lp = _LP()
    c = [lp.add_vars(m, 0.0, -45.0, 45.0) for _ in range(3)]
    u = lp.add_vars(m, weights.zoom * H, 0.0, 100.0 * (1.0 - min_keep))
    eye = sp.identity(m, format="csr")
    # A k-th difference of coefficients spaced H frames is about H**k times a per-frame one, and
    # stands for H frames: weight w_k H**(1 - k).
    for ax in range(3):
        lp.l1(c[ax], eye, weights.plan * H)
        for k, w in ((1, weights.d1), (2, weights.d2), (3, weights.d3)):
            lp.l1(c[ax], _diff(m, k), w * H ** (1 - k))
    for k, w in ((1, weights.z1), (2, weights.z2), (3, weights.z3)):
        lp.l1(u, _diff(m, k), w * H ** (1 - k))
    return lp


def _solve_window(
    original: np.ndarray,
    plan: np.ndarray,
    B: sp.csr_matrix,
    intr: Intrinsics,
    min_keep: float,
    weights: PathWeights,
    H: float,
    margin: np.ndarray,
    keep0: np.ndarray,
    head: np.ndarray | None,
) -> np.ndarray:
    """One LP over the B-spline coefficients of a window: returns (m, 4) coefficients of
    (d_yaw, d_pitch, d_roll, u = percent cropped); ``head`` fixes the first rows. ``H`` is the
    coefficient spacing in frames at 30 fps (weights are per frame at 30 fps)."""
    n, m = B.shape
    lp = _smoothness_terms(m, min_keep, weights, H).copy()
    c = [slice(i * m, (i + 1) * m) for i in range(3)]
    u = slice(3 * m, 4 * m)
    if head is not None:
        h = len(head)
        for ch in range(4):
            lp.lo[ch][:h] = head[:, ch]
            lp.hi[ch][:h] = head[:, ch]
    # Corner constraints on every frame, linearised at the current zoom keep0.
    J = deviation_jacobian(original)  # (n, 3, 3) radians per degree
    w0 = (J @ (plan - original)[:, :, None])[:, :, 0]  # (n, 3) ω where the path is the plan
    ctr = np.array([(intr.width - 1) / 2.0, (intr.height - 1) / 2.0])
    a0 = (ctr - [intr.cx, intr.cy]) / [intr.fx, intr.fy]
    for P in _corners(intr):
        A = (P - ctr) / [intr.fx, intr.fy]  # normalised corner offset per unit of s
        a = keep0 * A[0] + a0[0]
        b = keep0 * A[1] + a0[1]
        gx = np.stack([-a * b, 1 + a * a, -b], axis=1)  # d(v_x/v_z)/dω
        gy = np.stack([-(1 + b * b), a * b, a], axis=1)
        for axis, g, f, pp, size in ((0, gx, intr.fx, intr.cx, intr.width), (1, gy, intr.fy, intr.cy, intr.height)):
            sign = 1.0 if P[axis] > ctr[axis] else -1.0
            limit = ((size - 1.0 - pp) if sign > 0 else pp) - margin
            gJ = np.einsum("ki,kij->kj", g, J)  # (n, 3) per degree of d
            # s = 1 - u/100: the corner term f A s = f A - (f A / 100) u.
            const = f * (A[axis] + a0[axis] + np.einsum("ki,ki->k", g, w0))
            cols = [(u, sp.diags(-sign * f * A[axis] / 100.0 * np.ones(n)) @ B)]
            cols += [(c[ax], sp.diags(sign * f * gJ[:, ax]) @ B) for ax in range(3)]
            lp.add_rows(cols, limit - sign * const)
    x = lp.solve()
    return np.stack([x[c[0]], x[c[1]], x[c[2]], x[u]], axis=1)


def _solve_blocks(
    original: np.ndarray,
    plan: np.ndarray,
    B: sp.csr_matrix,
    intr: Intrinsics,
    min_keep: float,
    weights: PathWeights,
    H: float,
    margin: np.ndarray,
    keep0: np.ndarray,
    win: int,
    ovl: int,
) -> np.ndarray:
    """(m, 4) B-spline coefficients of the whole clip, solved in windows of ``win`` coefficients
    overlapping by ``ovl``; each window's first rows are tied to the previous window's result."""
    n, m = B.shape
    first = np.asarray(B.indices.reshape(n, 4)[:, 0])  # first coefficient of each frame
    coef = np.zeros((m, 4))
    start, head = 0, None
    while True:
        stop = m if m - start <= win + ovl // 2 else start + win
        frames = np.flatnonzero((first >= start) & (first + 4 <= stop))
        sub = B[frames][:, start:stop]
        cw = _solve_window(
            original[frames], plan[frames], sub, intr, min_keep, weights, H, margin[frames], keep0[frames], head
        )
        keep_to = stop if stop == m else stop - ovl
        coef[start:keep_to] = cw[: keep_to - start]
        if stop == m:
            return coef
        head = cw[keep_to - start - 3 : keep_to - start]
        start = keep_to - 3


def fit_path(
    original: np.ndarray,
    plan: np.ndarray,
    intr: Intrinsics,
    fps: float,
    *,
    max_zoom: float = 1.10,
    weights: PathWeights | None = None,
    knots_per_second: float = 10.0,
    window_s: float = 20.0,
    overlap_s: float = 4.0,
    margin_px: float = 0.0,
) -> FittedPath:
    """The path nearest the ``plan`` (both (K, 3) degrees per frame at ``fps``) that a zoom of at
    most ``max_zoom`` covers, with that zoom per frame (see the module docstring). The detour
    and the zoom are cubic B-splines with ``knots_per_second`` knots; the programme is solved in
    windows of ``window_s`` seconds overlapping by ``overlap_s``."""
    if not (1.0 <= max_zoom <= 4.0) or not np.isfinite(max_zoom):
        raise EgovidError(f"maximum zoom {max_zoom} is outside 1-4", "use e.g. --max-zoom 1.1")
    t0 = time.perf_counter()
    weights = weights or PathWeights()
    original = np.asarray(original, dtype=float)
    plan = np.asarray(plan, dtype=float)
    n = len(original)
    spacing = max(fps / knots_per_second, 1.0)  # frames between knots
    H = spacing * 30.0 / fps  # the same in frames at 30 fps
    B = bspline_basis(n, spacing)
    win = max(round(window_s * knots_per_second), 12)
    ovl = min(max(round(overlap_s * knots_per_second), 6), win // 2)
    min_keep = 1.0 / max_zoom
    margin = np.full(n, margin_px)
    keep0 = np.full(n, 0.5 * (1.0 + min_keep))
    notes: list[str] = []
    passes = 0
    for passes in range(1, 4):  # noqa: B007
        coef = _solve_blocks(original, plan, B, intr, min_keep, weights, H, margin, keep0, win, ovl)
        curve = B @ coef
        path = plan + curve[:, :3]
        keep = 1.0 - curve[:, 3] / 100.0
        short = coverage_shortfall(original, path, keep, intr)
        if np.all(short <= SHORTFALL_TOLERANCE_PX):
            break
        margin = np.where(short > SHORTFALL_TOLERANCE_PX, margin + 1.5 * short + 0.05, margin)
        keep0 = keep
    else:
        missed = int(np.sum(short > SHORTFALL_TOLERANCE_PX))
        path, pulled = pull_within_budget(original, path, intr, min_keep, fps)
        need = required_keep(original, path, intr)
        keep = np.minimum(keep, need)
        if pulled:
            notes.append(
                f"the linearised corners missed {missed} frames; the path was pulled towards the recorded "
                f"one on {pulled} frames to stay within the maximum zoom {max_zoom:g}x"
            )
        else:
            notes.append(f"the linearised corners missed {missed} frames; their zoom raised to cover them")
        if 1.0 / need.min() > max_zoom + 1e-6:  # not expected: the recorded path needs no zoom
            notes.append(f"zoom reaches {1.0 / need.min():.3f}x, above the maximum {max_zoom:g}x")
    return FittedPath(path, keep, passes, time.perf_counter() - t0, notes)


def pull_within_budget(
    original: np.ndarray, path: np.ndarray, intr: Intrinsics, min_keep: float, fps: float, ramp_s: float = 0.25
) -> tuple[np.ndarray, int]:
    """The (K, 3) ``path`` (degrees) moved towards the recorded ``original`` on the frames whose
    exact corners need a share of the frame below ``min_keep`` (a zoom above the budget), and the
    number of frames moved. Each such frame gets the largest blend ``α`` (path = original +
    α (path − original); α = 1 leaves it, 0 is the recorded view, which needs no zoom) that the
    budget covers (bisection on the exact corners); ``α`` is then eroded and box-averaged over
    ``ramp_s`` seconds, which never raises it, so the pull starts and ends without a jerk."""
    original = np.asarray(original, dtype=float)
    path = np.asarray(path, dtype=float)
    bad = np.flatnonzero(required_keep(original, path, intr) < min_keep - 1e-9)
    if not len(bad):
        return path, 0
    o, d = original[bad], path[bad] - original[bad]
    lo = np.zeros(len(bad))  # covered: the recorded view needs no zoom
    hi = np.ones(len(bad))  # not covered
    for _ in range(20):
        mid = 0.5 * (lo + hi)
        good = required_keep(o, o + mid[:, None] * d, intr) >= min_keep - 1e-9
        lo = np.where(good, mid, lo)
        hi = np.where(good, hi, mid)
    best = np.ones(len(path))
    best[bad] = lo
    w = max(round(ramp_s * fps), 1)
    eroded = minimum_filter1d(best, 2 * w + 1, mode="nearest")
    alpha = np.minimum(uniform_filter1d(eroded, 2 * w + 1, mode="nearest"), best)
    return original + alpha[:, None] * (path - original), int(np.sum(alpha < 1.0 - 1e-9))
