"""Plane geometry of paths and drives, in metres on the archive's metric plane (gps.project)."""

from __future__ import annotations

import numpy as np


def project_on_polyline(pts: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Arclength (metres) of the closest point of a polyline ``pts`` (M, 2) to each of ``xy``
    (N, 2); (N,) float."""
    pts = np.asarray(pts, dtype=float)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(pts) < 2:
        return np.zeros(len(xy))
    seg = np.diff(pts, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    out = np.empty(len(xy))
    step = max(1, 2_000_000 // len(seg))  # points per block: bounded memory for long paths
    for a in range(0, len(xy), step):
        p = xy[a : a + step]
        # (n, M-1) parameters of the foot of each point on each segment, clipped to the segment.
        rel = p[:, None, :] - pts[None, :-1, :]
        t = np.clip(np.einsum("nmk,mk->nm", rel, seg) / np.maximum(seg_len**2, 1e-12), 0.0, 1.0)
        foot = pts[None, :-1, :] + seg[None] * t[..., None]
        d = np.hypot(foot[..., 0] - p[:, None, 0], foot[..., 1] - p[:, None, 1])
        k = np.argmin(d, axis=1)
        out[a : a + step] = cum[k] + t[np.arange(len(p)), k] * seg_len[k]
    return out


def range_overlap(a: np.ndarray, b: np.ndarray) -> float:
    """Share of the value range of ``b`` covered by the range of ``a`` (0-1; positions along a
    path in metres)."""
    if len(a) == 0 or len(b) == 0:
        return 0.0
    lo, hi = max(a.min(), b.min()), min(a.max(), b.max())
    span = max(float(b.max() - b.min()), 1e-6)
    return max(0.0, float(hi - lo)) / span
