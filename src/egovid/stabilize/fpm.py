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
* eq. 9.1's neighbour is the anchor nearest in time (ties: the one with the smaller amplitude);
  an anchor moves towards it by ``D · base``, and never more than half way to either adjacent
  anchor, so anchors keep alternating and the edited motion keeps the original's frequency.
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


def pure_fpm(anchors: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """The zigzag through anchor ``values`` at frames ``anchors`` (linear in between), (n,)."""
    return np.interp(np.arange(n, dtype=float), anchors.astype(float), np.asarray(values, dtype=float))


@njit(cache=True)
def _ease(anchors: np.ndarray, values: np.ndarray, k: np.ndarray, s: np.ndarray, n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(anchors.shape[0] - 1):
        a, b = anchors[i], anchors[i + 1]
        va, vb = values[i], values[i + 1]
        half = 0.5 * (b - a)
        mid = 0.5 * (a + b)
        last = b + 1 if i == anchors.shape[0] - 2 else b
        for t in range(a, last):
            frac = (t - a) / (b - a) if b > a else 0.0
            p = va + (vb - va) * frac  # pure FPM
            u = (t - mid) / half if half > 0 else 0.0
            near = va if t < mid else vb
            out[t] = p + s[i] * abs(u) ** k[i] * (near - p)
    if anchors.shape[0] == 1:
        out[:] = values[0]
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
    """Per-anchor quantities of eq. 9.1: the nearest neighbour in time, the base amplitude, the
    direction an anchor moves when reduced, and the largest move that keeps alternation."""

    anchors: np.ndarray
    values: np.ndarray
    neighbour: np.ndarray
    base: np.ndarray
    direction: np.ndarray
    max_move: np.ndarray
    movable: np.ndarray


def anchor_geometry(anchors: np.ndarray, values: np.ndarray) -> AnchorGeometry:
    """Neighbours and base amplitudes of eq. 9.1 for anchors at frames ``anchors``."""
    A = np.asarray(anchors)
    v = np.asarray(values, dtype=float)
    T = len(A)
    neighbour = np.zeros(T, dtype=np.int64)
    base = np.zeros(T)
    direction = np.zeros(T)
    max_move = np.zeros(T)
    movable = np.zeros(T, dtype=bool)
    for i in range(T):
        cands = [j for j in (i - 1, i + 1) if 0 <= j < T]
        if not cands:
            continue
        dist = [abs(A[j] - A[i]) for j in cands]
        best = min(range(len(cands)), key=lambda c: (dist[c], abs(v[cands[c]] - v[i])))
        j = cands[best]
        neighbour[i] = j
        base[i] = abs(v[i] - v[j])
        if 0 < i < T - 1:
            movable[i] = True
            direction[i] = np.sign(v[j] - v[i])
            max_move[i] = 0.5 * min(abs(v[i] - v[i - 1]), abs(v[i] - v[i + 1]))
    return AnchorGeometry(A, v, neighbour, base, direction, max_move, movable)


def reduce_anchors(geom: AnchorGeometry, D: np.ndarray) -> np.ndarray:
    """New anchor values after reduction rates ``D`` (eq. 9.1); end anchors never move."""
    D = np.clip(np.asarray(D, dtype=float), 0.0, None)
    move = np.minimum(D * geom.base, geom.max_move) * geom.movable
    return geom.values + geom.direction * move


def reduction_rates(geom: AnchorGeometry, new_values: np.ndarray) -> np.ndarray:
    """Eq. 9.1: D(i) = |θ̃p(A(i)) - θp(A(i))| / |θp(A(i)) - θp(A(neighbour))|."""
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.abs(np.asarray(new_values) - geom.values) / geom.base
    return np.where(geom.base > 0, d, 0.0)
