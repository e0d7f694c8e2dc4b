"""Path matching: splitting a drive into per-path sequences (thesis §14.1, §15.1, Table 15.1).

Paths are directional polylines in metres (resampled every ``SPACING`` m) that do not overlap.
For a new drive (GPS fixes at ~1 Hz, projected to metres) and each known path, the indicator
sequence of §15.1 is

    I(n) = 1  if  min_{S(n-1) <= m} || G(n) - L(m) ||  <=  T + e,
    S(n) = the arg min (the closest path point, never moving backwards along the path),

with T half the point spacing and e the GPS error (metres, not degrees as in the thesis). We also
require the drive's bearing to agree with the path's direction (paths are one-way: the other
side of the street looks different) unless the car is nearly stopped. Runs of I = 1 (short
drop-outs bridged) become sequences on that path; the rest of the drive becomes new paths.
Where a drive joins or leaves a path in its middle, the path is split there, so paths stay
"mutually independent" and every sequence covers whole paths (Table 15.1).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

SPACING = 5.0  # metres between path points
GPS_ERROR = 12.0  # metres (the thesis' e, 1.35e-4 degrees, is about 15 m)
MIN_RUN = 4  # fixes
BRIDGE = 3  # fixes of drop-out bridged inside a run
MIN_SPEED_FOR_BEARING = 2.0  # m/s
MAX_BEARING_DIFF = 60.0  # degrees


def resample(points: np.ndarray, spacing: float = SPACING) -> np.ndarray:
    """A polyline resampled every ``spacing`` metres (first and last point kept)."""
    p = np.asarray(points, dtype=float)
    if len(p) < 2:
        return p.copy()
    d = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    if d[-1] < 1e-9:
        return p[:1].copy()
    n = max(2, int(np.ceil(d[-1] / spacing)) + 1)
    s = np.linspace(0.0, d[-1], n)
    return np.stack([np.interp(s, d, p[:, 0]), np.interp(s, d, p[:, 1])], axis=1)


def smooth_track(xy: np.ndarray, window: int = 5) -> np.ndarray:
    """Moving-average smoothing of noisy GPS positions (edges shrink the window)."""
    if len(xy) < 3:
        return xy.copy()
    out = np.empty_like(xy)
    h = window // 2
    for i in range(len(xy)):
        a, b = max(0, i - h), min(len(xy), i + h + 1)
        out[i] = xy[a:b].mean(axis=0)
    return out


def path_bearings(points: np.ndarray) -> np.ndarray:
    """Direction (degrees clockwise from north) of each path point's outgoing segment."""
    d = np.diff(points, axis=0)
    b = np.degrees(np.arctan2(d[:, 0], d[:, 1])) % 360.0
    return np.concatenate([b, b[-1:]]) if len(b) else np.zeros(len(points))


def _angle_diff(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0)


@dataclass
class PathMatch:
    """Indicator and closest points of one drive against one path."""

    path_id: int
    indicator: np.ndarray  # (N,) bool
    closest: np.ndarray  # (N,) int, S(n)
    distance: np.ndarray  # (N,) metres


def match_path(
    path_id: int,
    points: np.ndarray,
    xy: np.ndarray,
    bearing: np.ndarray,
    speed: np.ndarray,
    tolerance: float = SPACING / 2 + GPS_ERROR,
    lookahead: int = 24,
) -> PathMatch:
    """The indicator sequence I(n) and closest points S(n) of a drive against one path."""
    n = len(xy)
    M = len(points)
    pb = path_bearings(points)
    ind = np.zeros(n, bool)
    closest = np.zeros(n, np.int64)
    dist = np.full(n, np.inf)
    s_prev = None
    for k in range(n):
        if s_prev is None:
            d_all = np.hypot(points[:, 0] - xy[k, 0], points[:, 1] - xy[k, 1])
            lo, hi = 0, M
        else:
            lo, hi = s_prev, min(M, s_prev + lookahead)
            d_all = np.hypot(points[lo:hi, 0] - xy[k, 0], points[lo:hi, 1] - xy[k, 1])
        j = int(np.argmin(d_all))
        m = lo + j
        d = float(d_all[j])
        ok_dir = speed[k] < MIN_SPEED_FOR_BEARING or _angle_diff(bearing[k], pb[m]) <= MAX_BEARING_DIFF
        closest[k], dist[k] = m, d
        if d <= tolerance and ok_dir:
            ind[k] = True
            s_prev = m
        elif s_prev is not None and d > 4 * tolerance:
            s_prev = None  # left the path for good: re-acquire globally if it comes back
    return PathMatch(path_id, ind, closest, dist)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open [a, b) runs of True."""
    out, start = [], None
    for i, v in enumerate(mask):
        if v and start is None:
            start = i
        elif not v and start is not None:
            out.append((start, i))
            start = None
    if start is not None:
        out.append((start, len(mask)))
    return out


def bridge(mask: np.ndarray, gap: int = BRIDGE) -> np.ndarray:
    """Fill runs of False no longer than ``gap`` that sit between two runs of True."""
    m = mask.copy()
    runs = _runs(mask)
    for (_, b), (c, _) in itertools.pairwise(runs):
        if c - b <= gap:
            m[b:c] = True
    return m


@dataclass
class DrivePiece:
    """A stretch of fixes [start, end) of the drive: on an existing path (with the path point range
    it covers) or new (``path_id`` None)."""

    start: int
    end: int
    path_id: int | None
    first_point: int = 0
    last_point: int = 0
    closest: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def split_drive(matches: list[PathMatch], n: int) -> list[DrivePiece]:
    """Assign each fix to at most one path (the closest matching one), keep runs of at least
    ``MIN_RUN`` fixes, and cover the rest of the drive with new-path pieces."""
    owner = np.full(n, -1, np.int64)
    best = np.full(n, np.inf)
    masks = {m.path_id: bridge(m.indicator) for m in matches}
    for m in matches:
        better = masks[m.path_id] & (m.distance < best)
        owner[better] = m.path_id
        best[better] = m.distance[better]
    pieces: list[DrivePiece] = []
    k = 0
    while k < n:
        j = k
        while j < n and owner[j] == owner[k]:
            j += 1
        pieces.append(DrivePiece(k, j, None if owner[k] < 0 else int(owner[k])))
        k = j
    # Runs on a path that are too short are not trusted: they become part of new paths.
    for p in pieces:
        if p.path_id is not None and p.end - p.start < MIN_RUN:
            p.path_id = None
    merged: list[DrivePiece] = []
    for p in pieces:
        if merged and merged[-1].path_id == p.path_id:
            merged[-1].end = p.end
        else:
            merged.append(p)
    by_id = {m.path_id: m for m in matches}
    for p in merged:
        if p.path_id is not None:
            c = by_id[p.path_id].closest[p.start : p.end]
            p.closest = np.maximum.accumulate(c)
            p.first_point, p.last_point = int(p.closest[0]), int(p.closest[-1])
    # Merge too-short new pieces into their neighbours (GPS noise at junctions).
    out: list[DrivePiece] = []
    for p in merged:
        if p.path_id is None and p.end - p.start < 2 and out:
            out[-1].end = p.end
            if out[-1].path_id is not None:
                out[-1].closest = np.concatenate([out[-1].closest, np.full(p.end - p.start, out[-1].last_point)])
            continue
        out.append(p)
    return out


def split_points(first: int, last: int, n_points: int, margin: int = 2) -> list[int]:
    """Indices at which a path must be split so that [first, last] becomes whole paths."""
    cuts = []
    if first > margin:
        cuts.append(first)
    if last < n_points - 1 - margin:
        cuts.append(last + 1)
    return cuts


def split_positions(positions: np.ndarray, offsets: list[float]) -> list[tuple[int, int, int, np.ndarray]]:
    """Cut a sequence's per-frame positions (metres along a path) where its path is cut at
    ``offsets`` (metres: 0, cut 1, …, the path's length): ``(part, k0, k1, positions on the part)``
    for each run of frames [k0, k1) on one part (Table 15.1: the older drives' sequences are split
    with their path)."""
    part = np.clip(np.searchsorted(offsets[1:-1], positions, side="right"), 0, len(offsets) - 2)
    out = []
    k = 0
    while k < len(part):
        j = k
        while j < len(part) and part[j] == part[k]:
            j += 1
        out.append((int(part[k]), k, j, positions[k:j] - offsets[part[k]]))
        k = j
    return out
