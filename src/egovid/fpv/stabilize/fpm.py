"""First-person motion structure (thesis §9.1–9.3.1).

A first-person motion (FPM) along one axis is described by its **motion anchors** — the local
extremes, its skeleton: amplitude and frequency, hence the first-person motion information FPMI —
and by its **motion shape** between anchors, which only affects stability. The **pure FPM** is the
zigzag through the anchors (uniquely determined by them, so its VE measures the FPMI).

Editing a motion = (1) moving anchors towards their neighbours by **reduction rates** D (eq. 9.1),
which lowers amplitude and FPMI, then (2) re-drawing the shape between anchors with the
two-parameter **easing function** (eq. 9.2–9.3), which raises stability. The edited motion is made
only of anchors and easing: whatever the original did between anchors (shake) is gone.

Choices made where the thesis is silent or ambiguous (docs/fpv.md):

* anchors are the turning points of a zig-zag filter: a local extreme counts only once the motion
  has turned back from it by more than ``threshold`` degrees, so estimation noise and sub-threshold
  jitter never create anchors; the first and last frames are anchors too and are never moved,
  which keeps the start and end of the view (and so the whole of a monotonic pan);
* eq. 9.2 raises a signed ratio to the power k; we use ``|u|^k`` (u ∈ [-1, 1] is the position
  between the two anchors), and "the anchor nearest to n" for the argmin of eq. 9.3. With
  ``k = 1, s = 1`` the eased segment is two parabolas — constant acceleration, the motion that
  keeps the eye's position error smallest — and ``s = 0`` is the zigzag itself;
* reduction moves an anchor towards the motion's *trend* (a low-pass of the motion as wide as
  the anchor spacing), by a fraction ``D ∈ [0, 1]`` of the distance, and only in the direction
  that shrinks its swing. Moving "towards the nearest neighbour by D times the base amplitude"
  (eq. 9.1 read literally) is the same for a symmetric zigzag, but leaves the centre of the
  oscillation free, and VE is blind to that centre: the optimum drifts away from where the
  camera was looking and costs crop for nothing. Reducing towards the trend keeps the view
  centred, keeps pans and slow turns (they *are* the trend) and lets the end anchors move too.
  :func:`reduction_rates` still reports eq. 9.1's rates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


def find_anchors(theta: np.ndarray, threshold: float = 0.5) -> np.ndarray:
    """Frame indices of the motion anchors of a (K,) motion in degrees (first and last included).

    A local maximum (minimum) becomes an anchor once the motion has dropped (risen) more than
    ``threshold`` degrees from it; between confirmed reversals only the most extreme frame counts.
    """
    x = np.asarray(theta, dtype=float)
    n = len(x)
    if n < 3:
        return np.arange(n)
    anchors = [0]
    direction = 0  # +1 looking for a maximum, -1 for a minimum, 0 undecided
    ext_i = 0
    for i in range(1, n):
        if direction == 0:
            if x[i] - x[0] > threshold:
                direction, ext_i = 1, i
            elif x[0] - x[i] > threshold:
                direction, ext_i = -1, i
            continue
        if direction == 1:
            if x[i] > x[ext_i]:
                ext_i = i
            elif x[ext_i] - x[i] > threshold:
                anchors.append(ext_i)
                direction, ext_i = -1, i
        else:
            if x[i] < x[ext_i]:
                ext_i = i
            elif x[i] - x[ext_i] > threshold:
                anchors.append(ext_i)
                direction, ext_i = 1, i
    if anchors[-1] != n - 1:
        anchors.append(n - 1)
    return np.array(sorted(set(anchors)), dtype=np.int64)


def motion_anchors(theta: np.ndarray, threshold: float = 0.5) -> np.ndarray:
    """The anchors egovid uses everywhere (optimiser, pure FPM, FPMI): :func:`find_anchors` with a
    threshold of at least 3x the motion's measured jitter, so jitter never makes anchors."""
    return find_anchors(theta, max(threshold, 3.0 * noise_level(theta)))


def noise_level(theta: np.ndarray) -> float:
    """Robust standard deviation (degrees) of frame-to-frame jitter in a motion: the MAD of its
    second difference, scaled for white noise (Var Δ² = 6 σ²)."""
    d2 = np.diff(np.asarray(theta, dtype=float), 2)
    if len(d2) < 3:
        return 0.0
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def pure_fpm(anchors: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """The zigzag through anchor ``values`` at frames ``anchors`` (linear in between), (n,)."""
    return np.interp(np.arange(n, dtype=float), anchors.astype(float), np.asarray(values, dtype=float))


@njit(cache=True)
def ease_into(
    anchors: np.ndarray, values: np.ndarray, k: np.ndarray, s: np.ndarray, lo: int, hi: int, out: np.ndarray
) -> None:
    """Frames ``lo`` to ``hi - 1`` of :func:`ease` into ``out`` (length ``hi - lo``); numba, so
    the optimiser's objective (:mod:`egovid.fpv.stabilize.optimize`) can draw only the frames a
    block of anchors moves."""
    for i in range(anchors.shape[0] - 1):
        a, b = anchors[i], anchors[i + 1]
        last = b + 1 if i == anchors.shape[0] - 2 else b
        if last <= lo or a >= hi:
            continue
        va, vb = values[i], values[i + 1]
        half = 0.5 * (b - a)
        mid = 0.5 * (a + b)
        for t in range(max(a, lo), min(last, hi)):
            frac = (t - a) / (b - a) if b > a else 0.0
            p = va + (vb - va) * frac  # pure FPM
            u = (t - mid) / half if half > 0 else 0.0
            near = va if t < mid else vb
            out[t - lo] = p + s[i] * abs(u) ** k[i] * (near - p)
    if anchors.shape[0] == 1:
        out[:] = values[0]


@njit(cache=True)
def _ease(anchors: np.ndarray, values: np.ndarray, k: np.ndarray, s: np.ndarray, n: int) -> np.ndarray:
    out = np.empty(n)
    ease_into(anchors, values, k, s, 0, n, out)
    return out


def ease(anchors: np.ndarray, values: np.ndarray, k: np.ndarray, s: np.ndarray, n: int) -> np.ndarray:
    """Eq. 9.2–9.3: the eased motion through anchor ``values`` with shape ``k``, scale ``s`` per
    anchor pair (arrays of length ``len(anchors) - 1``); (n,) degrees."""
    a = np.asarray(anchors, dtype=np.int64)
    return _ease(
        a,
        np.asarray(values, dtype=np.float64),
        np.broadcast_to(np.asarray(k, dtype=np.float64), (max(len(a) - 1, 0),)).copy(),
        np.broadcast_to(np.asarray(s, dtype=np.float64), (max(len(a) - 1, 0),)).copy(),
        int(n),
    )


@dataclass
class AnchorGeometry:
    """Per-anchor quantities: the nearest neighbour in time and base amplitude of eq. 9.1, the
    intentional trend the anchor is reduced towards, and the direction that shrinks its swing."""

    anchors: np.ndarray
    values: np.ndarray
    neighbour: np.ndarray
    base: np.ndarray
    trend: np.ndarray
    direction: np.ndarray
    room: np.ndarray


def motion_trend(theta: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """The intentional course of a motion: a Gaussian low-pass whose width is the median spacing of
    the anchors, so oscillations (head bob, shake) average out and pans and slow turns remain."""
    from scipy.ndimage import gaussian_filter1d

    spacing = float(np.median(np.diff(anchors))) if len(anchors) > 2 else len(theta)
    sigma = float(np.clip(spacing, 3.0, 90.0))
    return gaussian_filter1d(np.asarray(theta, dtype=float), sigma, mode="nearest")


def anchor_geometry(anchors: np.ndarray, values: np.ndarray, trend: np.ndarray | None = None) -> AnchorGeometry:
    """Neighbours, base amplitudes (eq. 9.1) and reduction targets for anchors at ``anchors``.

    ``trend`` holds the intentional course at the anchor frames (default: the anchors' mean).
    An anchor may only move towards the trend and only in the direction that shrinks its swing
    against its neighbours; ``room`` is how far that is (degrees).
    """
    A = np.asarray(anchors)
    v = np.asarray(values, dtype=float)
    T = len(A)
    m = np.full(T, v.mean()) if trend is None else np.asarray(trend, dtype=float)
    neighbour = np.zeros(T, dtype=np.int64)
    base = np.zeros(T)
    direction = np.zeros(T)
    for i in range(T):
        cands = [j for j in (i - 1, i + 1) if 0 <= j < T]
        if not cands:
            continue
        dist = [abs(A[j] - A[i]) for j in cands]
        best = min(range(len(cands)), key=lambda c: (dist[c], abs(v[cands[c]] - v[i])))
        neighbour[i] = cands[best]
        base[i] = abs(v[i] - v[cands[best]])
        # The swing shrinks when an anchor moves towards its neighbours' side.
        direction[i] = np.sign(np.mean([v[j] for j in cands]) - v[i])
    to_trend = m - v
    room = np.where(np.sign(to_trend) == direction, np.abs(to_trend), 0.0)
    return AnchorGeometry(A, v, neighbour, base, m, direction, room)


def reduce_anchors(geom: AnchorGeometry, D: np.ndarray) -> np.ndarray:
    """New anchor values: each moves a fraction ``D`` (0–1) of the way to the trend."""
    D = np.clip(np.asarray(D, dtype=float), 0.0, 1.0)
    return geom.values + geom.direction * D * geom.room


def reduction_rates(geom: AnchorGeometry, new_values: np.ndarray) -> np.ndarray:
    """Eq. 9.1: D(i) = |θ̃p(A(i)) - θp(A(i))| / |θp(A(i)) - θp(A(neighbour))|."""
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.abs(np.asarray(new_values) - geom.values) / geom.base
    return np.where(geom.base > 0, d, 0.0)
