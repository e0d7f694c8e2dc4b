"""Object-position intervals B(k) of the SPEM model (thesis §7.3, eq. 7.2–7.9).

For frame k and one type of motion, B(k) is the set of target positions β (degrees, relative to
the camera at frame k, within the field of view) that the viewer can pursue from frame k through
k+2 without a catch-up saccade. The position error of a target is the second difference of its
observation angle (eq. 7.6); with the reading decided in DESIGN.md, a target seen at β in frame k
is at ``β - (θ(k') - θ(k))`` in frame k' (eq. 7.3 writes θ(k'-1), an index slip):

* yaw / pitch (eq. 7.2–7.3):  ``φ(k'; β) = atan(f tan(β - Δ_k') / d)``
* roll (eq. 7.4–7.5):         ``φ(k'; β) = 2 asin(r sin(Δ_k'/2) / sqrt(d² + r²))``, ``r = f tan β``

with ``Δ_k' = θ(k') - θ(k)``. The trackable set of ``|PE|`` is ``[0, T]`` (see
:mod:`egovid.fpv.perception.model`). Numerically, ``|PE(β)|`` is unimodal over the field of view for
viewing distances of at least twice the focal length (checked on 20 000 random motions), so
B(k) is one interval; we locate a point of it and find its two ends by safeguarded root finding,
to 1e-9 rad. A target more than 90° off the optical axis in any of the three frames is lost.

Everything here runs under numba; angles are in radians inside the kernels.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_HALF_PI = math.pi / 2.0 - 1e-9
_BIG = 1e9


@njit(cache=True)
def _pe_yaw(beta: float, d1: float, d2: float, r: float) -> float:
    a0 = beta
    a1 = beta - d1
    a2 = beta - d2
    if abs(a1) >= _HALF_PI or abs(a2) >= _HALF_PI or abs(a0) >= _HALF_PI:
        return _BIG
    return math.atan(r * math.tan(a2)) - 2.0 * math.atan(r * math.tan(a1)) + math.atan(r * math.tan(a0))


@njit(cache=True)
def _pe_roll(beta: float, d1: float, d2: float, q: float) -> float:
    t = math.tan(beta)
    rho = t / math.sqrt(q * q + t * t)
    s1 = min(1.0, max(-1.0, rho * math.sin(0.5 * d1)))
    s2 = min(1.0, max(-1.0, rho * math.sin(0.5 * d2)))
    return 2.0 * math.asin(s2) - 4.0 * math.asin(s1)


@njit(cache=True)
def _pe(kind: int, beta: float, d1: float, d2: float, p: float) -> float:
    if kind == 0:
        return _pe_yaw(beta, d1, d2, p)
    return _pe_roll(beta, d1, d2, p)


@njit(cache=True)
def _excess(kind: int, beta: float, d1: float, d2: float, p: float, thr: float) -> float:
    return abs(_pe(kind, beta, d1, d2, p)) - thr


@njit(cache=True)
def _boundary(kind: int, a: float, b: float, fa: float, fb: float, d1, d2, p, thr) -> float:
    """Root of |PE| - thr between a (excess fa > 0) and b (excess fb <= 0): Illinois method."""
    side = 0
    x = b
    for _ in range(100):
        x = b - fb * (b - a) / (fb - fa) if fb != fa else 0.5 * (a + b)
        if not (min(a, b) < x < max(a, b)):
            x = 0.5 * (a + b)
        fx = _excess(kind, x, d1, d2, p, thr)
        if fx <= 0.0 and fx > -1e-15:
            return x
        if abs(b - a) < 1e-10:
            break
        if fx > 0.0:
            a, fa = x, fx
            if side == -1:
                fb *= 0.5
            side = -1
        else:
            b, fb = x, fx
            if side == 1:
                fa *= 0.5
            side = 1
    return b  # always on the trackable side


@njit(cache=True)
def _interval(kind: int, h: float, d1: float, d2: float, p: float, thr: float) -> tuple[float, float]:
    """(lo, hi) in radians of the trackable β in [-h, h]; lo == hi when empty."""
    fa = _excess(kind, -h, d1, d2, p, thr)
    fb = _excess(kind, h, d1, d2, p, thr)
    if fa <= 0.0 and fb <= 0.0:
        return -h, h
    # Find a trackable point: minimise |PE| (unimodal) by golden section, stop early on success.
    inside = 0.0
    found = False
    if fa <= 0.0:
        inside, found = -h, True
    elif fb <= 0.0:
        inside, found = h, True
    else:
        g = 0.6180339887498949
        lo, hi = -h, h
        x1 = hi - g * (hi - lo)
        x2 = lo + g * (hi - lo)
        f1 = _excess(kind, x1, d1, d2, p, thr)
        f2 = _excess(kind, x2, d1, d2, p, thr)
        for _ in range(60):
            if f1 <= 0.0:
                inside, found = x1, True
                break
            if f2 <= 0.0:
                inside, found = x2, True
                break
            if hi - lo < 2e-5:
                break
            if f1 < f2:
                hi, x2, f2 = x2, x1, f1
                x1 = hi - g * (hi - lo)
                f1 = _excess(kind, x1, d1, d2, p, thr)
            else:
                lo, x1, f1 = x1, x2, f2
                x2 = lo + g * (hi - lo)
                f2 = _excess(kind, x2, d1, d2, p, thr)
        if not found:
            m = 0.5 * (lo + hi)
            return m, m
    fi = _excess(kind, inside, d1, d2, p, thr)
    left = -h if fa <= 0.0 else _boundary(kind, -h, inside, fa, fi, d1, d2, p, thr)
    right = h if fb <= 0.0 else _boundary(kind, h, inside, fb, fi, d1, d2, p, thr)
    return left, right


@njit(cache=True)
def interval_kernel(kind: int, theta: np.ndarray, h: float, p: float, thr: float) -> np.ndarray:
    n = theta.shape[0] - 2
    out = np.empty((max(n, 0), 2))
    for k in range(n):
        d1 = theta[k + 1] - theta[k]
        d2 = theta[k + 2] - theta[k]
        lo, hi = _interval(kind, h, d1, d2, p, thr)
        out[k, 0] = lo
        out[k, 1] = hi
    return out


def yaw_pitch_intervals(theta_deg: np.ndarray, fov_deg: float, d_over_f: float, threshold_deg: float) -> np.ndarray:
    """B(k) for a yaw or pitch motion: (K-2, 2) array of [lo, hi] in degrees, camera-relative.

    ``theta_deg`` is the (K,) camera angle per frame, ``fov_deg`` the field of view along that
    axis, ``threshold_deg`` the largest trackable ``|PE|``.
    """
    theta = np.deg2rad(np.asarray(theta_deg, dtype=np.float64))
    out = interval_kernel(0, theta, math.radians(fov_deg) / 2.0, 1.0 / d_over_f, math.radians(threshold_deg))
    return np.rad2deg(out)


def roll_intervals(theta_deg: np.ndarray, fov_deg: float, d_over_f: float, threshold_deg: float) -> np.ndarray:
    """B(k) for a roll motion along one image direction with field of view ``fov_deg``."""
    theta = np.deg2rad(np.asarray(theta_deg, dtype=np.float64))
    out = interval_kernel(1, theta, math.radians(fov_deg) / 2.0, d_over_f, math.radians(threshold_deg))
    return np.rad2deg(out)


def position_error_deg(kind: str, beta_deg, d1_deg: float, d2_deg: float, d_over_f: float) -> np.ndarray:
    """PE (degrees) of targets at ``beta_deg`` for frame-to-frame angles ``Δ1``, ``Δ2`` (plain NumPy;
    used by tests and plots)."""
    b = np.deg2rad(np.asarray(beta_deg, dtype=float))
    d1, d2 = math.radians(d1_deg), math.radians(d2_deg)
    if kind in ("yaw", "pitch"):
        r = 1.0 / d_over_f

        def phi(x):
            return np.arctan(r * np.tan(x))

        out = phi(b - d2) - 2 * phi(b - d1) + phi(b)
        lost = (np.abs(b - d1) >= _HALF_PI) | (np.abs(b - d2) >= _HALF_PI) | (np.abs(b) >= _HALF_PI)
        return np.where(lost, np.inf, np.rad2deg(out))
    if kind == "roll":
        t = np.tan(b)
        rho = t / np.sqrt(d_over_f**2 + t * t)
        out = 2 * np.arcsin(np.clip(rho * np.sin(d2 / 2), -1, 1)) - 4 * np.arcsin(np.clip(rho * np.sin(d1 / 2), -1, 1))
        return np.rad2deg(out)
    raise ValueError(kind)
