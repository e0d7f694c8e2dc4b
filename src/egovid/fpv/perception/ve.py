"""Viewing Experience (VE, eq. 8.1–8.9) and Structure Viewing Experience (SVE, eq. 8.10–8.11) of
one motion component, per window of ``N + 1`` frames.

Inputs are the world-coordinate intervals ``B̃(n) = B(n) + θ(n)`` (eq. 8.1) as arrays ``lo``,
``hi`` (degrees) and the field of view ``fov`` along that axis (degrees).

**VE** is the expected fraction of a window's frames during which the viewer pursues a target
(eq. 8.8). The viewer picks a target uniformly in the field of view; it stays trackable while it
lies in the running intersection of B̃ (eq. 8.5); when it is lost at frame j, a saccade takes
``s`` frames and a new target is chosen at frame ``j + s``. We compute the exact expectation by
dynamic programming over trail start frames: with ``F(l)`` the expected number of tracked frames
from a trail starting at l to the end of the window,

    F(l) = Σ_{j=l..N} [P(V_{l,j-1}) - P(V_{l,j})] · ((j - l) + F(j + s)) + P(V_{l,N}) · (N + 1 - l)

(``F = 0`` past the window, ``P(V_{l,l-1}) = 1``), and ``VE = F(0) / (N + 1)``. This sums every
tracking path weighted by its probability (eq. 8.6) in O(N²) per window instead of enumerating
the exponentially many paths; :func:`ve_bruteforce` enumerates them and the tests prove equality.

Two readings decided here (see docs/fpv.md): a path length counts frames, ``N + 1 - s (n - 1)``
for n trails, over ``N + 1`` frames, so that a still camera scores exactly 1 (eq. 8.7 writes
``N - 6(n-1)`` over ``N + 1``, which caps a still camera at 0.9); and paths whose last target is
lost less than a saccade before the window ends count with the frames they did track (eq. 8.6
lists only paths whose last trail survives), so the path probabilities sum to 1 and VE is a true
expectation. A target can also be lost in its first frame (probability ``1 - |B̃(l)|/FOV``).

**SVE** (eq. 8.10) weights the per-step loss ``ΔB̃(n)`` by the frames it affects. eq. 8.11,
``|B̃(n+1)| - |B̃(n+1) ∩ B̃(n)|``, measures what *becomes* trackable, not what is lost as the text
says, and gives a perfect SVE = 1 to a motion so violent that nothing is ever trackable. The
default ``"coverage"`` reading uses ``FOV - |B̃(n) ∩ B̃(n+1)|`` (the share of the view that cannot
be pursued across the step); it equals eq. 8.11 whenever ``B̃(n+1)`` covers the whole view (all
smooth motion) and is 0 for a still camera. ``variant="thesis"`` gives eq. 8.11 literally.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def ve_window_kernel(lo: np.ndarray, hi: np.ndarray, fov: float, n1: int, sacc: int) -> np.ndarray:
    m_total = lo.shape[0]
    w_total = m_total - n1 + 1
    out = np.empty(max(w_total, 0))
    P = np.empty((n1, n1 + 1))
    F = np.zeros(n1 + 1)
    for i in range(w_total):
        for l in range(n1):
            cur_lo = -1e300
            cur_hi = 1e300
            P[l, l] = 1.0
            for m in range(l, n1):
                if lo[i + m] > cur_lo:
                    cur_lo = lo[i + m]
                if hi[i + m] < cur_hi:
                    cur_hi = hi[i + m]
                width = cur_hi - cur_lo
                P[l, m + 1] = width / fov if width > 0.0 else 0.0
        for l in range(n1 - 1, -1, -1):
            acc = P[l, n1] * (n1 - l)
            for j in range(l, n1):
                lost = P[l, j] - P[l, j + 1]
                if lost > 0.0:
                    nxt = j + sacc
                    acc += lost * ((j - l) + (F[nxt] if nxt < n1 else 0.0))
            F[l] = acc
        out[i] = F[0] / n1
    return out


def ve_windows(lo: np.ndarray, hi: np.ndarray, fov: float, window: int = 10, saccade: int = 6) -> np.ndarray:
    """VE of every window of ``window`` (= N + 1) consecutive intervals; shape ``(M - N,)``.

    ``lo``, ``hi``: (M,) ends of B̃(n) in degrees (world coordinates); ``fov``: degrees.
    """
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    return ve_window_kernel(lo, hi, float(fov), int(window), int(saccade))


@njit(cache=True)
def sve_window_kernel(lo: np.ndarray, hi: np.ndarray, fov: float, n1: int, literal: bool) -> np.ndarray:
    m_total = lo.shape[0]
    n = n1 - 1
    w_total = m_total - n1 + 1
    delta = np.empty(max(m_total - 1, 0))
    for k in range(m_total - 1):
        inter = min(hi[k], hi[k + 1]) - max(lo[k], lo[k + 1])
        inter = inter if inter > 0.0 else 0.0
        if literal:
            nxt = hi[k + 1] - lo[k + 1]
            delta[k] = (nxt if nxt > 0.0 else 0.0) - inter
        else:
            delta[k] = fov - inter
    out = np.empty(max(w_total, 0))
    norm = 2.0 / ((n + 1) * n * fov)
    for i in range(w_total):
        acc = 0.0
        for m in range(n):
            acc += delta[i + m] * (n - m)
        out[i] = 1.0 - norm * acc
    return out


def sve_windows(lo: np.ndarray, hi: np.ndarray, fov: float, window: int = 10, variant: str = "coverage") -> np.ndarray:
    """SVE (eq. 8.10) of every window of ``window`` = N + 1 intervals; shape ``(M - N,)``.

    ``variant``: ``"coverage"`` (default, ``ΔB̃ = FOV - |B̃(n) ∩ B̃(n+1)|``) or ``"thesis"``
    (eq. 8.11 literally); see the module docstring.
    """
    if variant not in ("coverage", "thesis"):
        raise ValueError(f"unknown SVE variant {variant!r}")
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    return sve_window_kernel(lo, hi, float(fov), int(window), variant == "thesis")


def ve_bruteforce(lo, hi, fov: float, saccade: int = 6) -> tuple[float, float]:
    """Reference VE of ONE window by enumerating every tracking path (eq. 8.4–8.8).

    Returns ``(VE, total probability of all paths)``; the latter must be 1. Exponential in the
    window length: for tests on short windows only.
    """
    lo = [float(v) for v in lo]
    hi = [float(v) for v in hi]
    n1 = len(lo)

    def p_tracked(start: int, end: int) -> float:  # P(V_{start,end}); 1 for an empty range
        if end < start:
            return 1.0
        width = min(hi[start : end + 1]) - max(lo[start : end + 1])
        return max(width, 0.0) / fov

    paths: list[tuple[float, int]] = []  # (probability, tracked frames)

    def extend(start: int, prob: float, frames: int) -> None:
        # Last trail survives to the end of the window.
        paths.append((prob * p_tracked(start, n1 - 1), frames + (n1 - start)))
        # Or the target is lost at frame j (eq. 8.4: P(V_{start,j-1}) - P(V_{start,j})).
        for j in range(start, n1):
            p_lost = p_tracked(start, j - 1) - p_tracked(start, j)
            if p_lost <= 0.0:
                continue
            if j + saccade < n1:
                extend(j + saccade, prob * p_lost, frames + (j - start))
            else:
                paths.append((prob * p_lost, frames + (j - start)))

    extend(0, 1.0, 0)
    total = sum(p for p, _ in paths)
    return sum(p * f for p, f in paths) / n1, total
