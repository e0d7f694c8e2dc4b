"""Retention: forgetting drives without changing any other drive's frames.

A drive coded jointly decodes with the frames of its reference drive, so forgetting a drive other
drives were coded against cannot simply delete its bitstreams: re-encoding the dependents against
something else would change their pictures. :func:`plan_forget` keeps exactly the random-access
runs still needed (24 frames each by default, the unit decoding can start at): every run of a live
drive, and, transitively, every run holding a frame that a needed run of a joint segment is
predicted from. A forgotten drive none of whose runs is needed is purged; one with needed runs stays
as a hidden *reference* (no longer listed, found, extracted or used as a baseline for new drives)
holding only those runs (its segments trimmed), and is purged by a later forget once nothing needs
them. Bytes freed are those of the bitstreams and runs no remaining segment uses.

Policies pick the drives: :func:`older_than` (recorded before a time) and :func:`over_budget`
(oldest first until the archive fits a byte budget, counting what forgetting really frees).
Locked drives are never picked, and naming one is an error.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from egovid.core.errors import EgovidError

_DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(s|min|m|h|d|w|y)?\s*$", re.IGNORECASE)
_SIZE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([kmgtp]?)(i?b)?\s*$", re.IGNORECASE)
_UNIT_S = {"s": 1, "min": 60, "m": 60, "h": 3600, "d": 86400, "w": 7 * 86400, "y": 365 * 86400}


def parse_duration(text: str) -> float:
    """``90d`` / ``12h`` / ``2w`` / ``30min`` / ``1y`` (365 days) → seconds (no unit: days)."""
    m = _DURATION.match(text or "")
    if not m:
        raise EgovidError(f"--older-than {text!r} is not a duration", "write e.g. 90d, 12h, 2w or 1y")
    return float(m.group(1)) * _UNIT_S[(m.group(2) or "d").lower()]


def parse_size(text: str) -> int:
    """``200G`` / ``1.5T`` / ``500M`` / ``300MiB`` → bytes (binary units: 1K = 1024 bytes)."""
    m = _SIZE.match(text or "")
    if not m:
        raise EgovidError(f"--keep-bytes {text!r} is not a size", "write e.g. 200G, 1.5T or 500M")
    return int(float(m.group(1)) * 1024 ** "_kmgtp".index((m.group(2) or "_").lower()))


@dataclass(frozen=True)
class SegmentRef:
    """What retention needs to know of a segment: its drive, frames [frame_start, frame_end) of that
    drive, its bitstream and size, for a joint segment the reference drive and, per frame, the frame
    of it the frame is predicted from (``refmap``; negative: none), and its random-access runs: one
    every ``refresh`` frames (0: a single run) with ``run_bytes`` bytes each (empty: unknown, then
    the segment is kept or dropped whole)."""

    id: int
    drive_id: int
    frame_start: int
    frame_end: int
    blob: str
    bytes: int
    ref_drive_id: int | None = None
    refmap: np.ndarray | None = None
    refresh: int = 0
    run_bytes: tuple[int, ...] = ()

    @property
    def runs(self) -> int:
        n = self.frame_end - self.frame_start
        return -(-n // self.refresh) if self.refresh > 0 and n > 0 else 1

    def run_of(self, frames: np.ndarray) -> np.ndarray:
        """Run index of each of ``frames`` (drive numbering, inside the segment)."""
        rel = np.asarray(frames, np.int64) - self.frame_start
        return rel // self.refresh if self.refresh > 0 else np.zeros(len(rel), np.int64)

    def frames_of(self, runs: np.ndarray) -> np.ndarray:
        """Bool mask over the segment's frames: those in the given runs (bool mask over runs)."""
        n = self.frame_end - self.frame_start
        if self.refresh <= 0:
            return np.full(n, bool(runs[0]))
        return np.repeat(runs, self.refresh)[:n]


@dataclass
class ForgetPlan:
    """What a forget does: segments deleted whole, segments trimmed to the runs still needed
    (segment id -> kept run ranges [r0, r1)), drives kept as hidden references (their kept segments,
    and the live drives that need them), drives purged, the blobs that go, and the bytes freed."""

    delete_segments: list[int] = field(default_factory=list)
    trim_segments: dict[int, list[tuple[int, int]]] = field(default_factory=dict)
    keep_as_reference: dict[int, list[int]] = field(default_factory=dict)  # drive -> its kept segments
    needed_by: dict[int, list[int]] = field(default_factory=dict)  # kept drive -> live drives needing it
    purge_drives: list[int] = field(default_factory=list)
    delete_blobs: list[str] = field(default_factory=list)
    bytes_freed: int = 0


def _ranges(mask: np.ndarray) -> list[tuple[int, int]]:
    """[a, b) ranges of the true entries of a bool mask."""
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        return []
    cuts = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[idx[0]], idx[cuts + 1]])
    ends = np.concatenate([idx[cuts], [idx[-1]]]) + 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def plan_forget(segments: Iterable[SegmentRef], live_drives: Iterable[int], forgotten: Iterable[int]) -> ForgetPlan:
    """Which segments and runs stay and which go when only ``live_drives`` remain (see the module
    docstring).

    Every run of a live drive's segments is needed; a run of another segment is needed when a
    needed run of a joint segment has a frame predicted from one of its frames (decoding starts at
    a run's first frame, so whole runs count). ``forgotten``: drives no longer live (those being
    forgotten now and hidden references kept earlier): their unneeded runs go — a segment none of
    whose runs is needed is deleted, one with some is trimmed to them."""
    segs = list(segments)
    live = set(live_drives)
    gone = set(forgotten)
    needed = _needed_runs(segs, live)
    plan = ForgetPlan(needed_by=_needed_by(segs, needed, live, gone))
    kept_blobs: set[str] = set()
    freed: dict[str, int] = {}  # blob -> bytes it frees
    for s in segs:
        mask = needed[s.id]
        if s.drive_id not in gone:
            if not mask.all():  # a live drive's segment is always needed; anything else is a caller error
                raise ValueError(f"segment {s.id} of drive {s.drive_id} is neither live nor forgotten")
            kept_blobs.add(s.blob)
            continue
        if not mask.any():
            plan.delete_segments.append(s.id)
            freed[s.blob] = s.bytes
            continue
        plan.keep_as_reference.setdefault(s.drive_id, []).append(s.id)
        if mask.all() or len(s.run_bytes) != s.runs:
            kept_blobs.add(s.blob)  # kept whole (all of it is needed, or its runs' sizes are unknown)
            continue
        plan.trim_segments[s.id] = _ranges(mask)
        freed[s.blob] = int(sum(b for b, m in zip(s.run_bytes, mask, strict=True) if not m))
    plan.purge_drives = sorted(d for d in gone if d not in plan.keep_as_reference)
    plan.delete_blobs = sorted(b for b in freed if b not in kept_blobs)
    plan.bytes_freed = sum(freed[b] for b in plan.delete_blobs)
    return plan


def _needed_runs(segs: list[SegmentRef], live: set[int]) -> dict[int, np.ndarray]:
    """Segment id -> bool mask over its runs: those a live drive needs, directly or through the
    joint segments predicted from them (a work list of newly needed runs, each followed once)."""
    by_drive: dict[int, list[SegmentRef]] = {}
    for s in segs:
        by_drive.setdefault(s.drive_id, []).append(s)
    needed = {s.id: np.zeros(s.runs, bool) for s in segs}
    queue: list[tuple[SegmentRef, np.ndarray]] = []
    for s in segs:
        if s.drive_id in live:
            needed[s.id][:] = True
            queue.append((s, needed[s.id].copy()))
    while queue:
        s, new_runs = queue.pop()
        if s.ref_drive_id is None or s.refmap is None or len(s.refmap) == 0:
            continue
        refs = np.asarray(s.refmap, np.int64)[s.frames_of(new_runs)]
        refs = np.unique(refs[refs >= 0])
        for t in by_drive.get(s.ref_drive_id, []):
            inside = refs[(refs >= t.frame_start) & (refs < t.frame_end)]
            if len(inside) == 0:
                continue
            mark = np.zeros(t.runs, bool)
            mark[np.unique(t.run_of(inside))] = True
            fresh = mark & ~needed[t.id]
            if fresh.any():
                needed[t.id] |= fresh
                queue.append((t, fresh))
    return needed


def _needed_by(
    segs: list[SegmentRef], needed: dict[int, np.ndarray], live: set[int], gone: set[int]
) -> dict[int, list[int]]:
    """Forgotten drive -> the live drives that depend on it (through kept segments)."""
    edges: dict[int, set[int]] = {}
    for s in segs:
        if needed[s.id].any() and s.ref_drive_id is not None:
            edges.setdefault(s.drive_id, set()).add(s.ref_drive_id)
    out: dict[int, list[int]] = {}
    for root in sorted(live):
        seen, stack = set(), [root]
        while stack:
            for nxt in edges.get(stack.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    stack.append(nxt)
        for x in seen & gone:
            out.setdefault(x, []).append(root)
    return out


@dataclass(frozen=True)
class DriveAge:
    """A drive as policies see it: id, recording start (UTC seconds), locked flag."""

    id: int
    start_utc: float
    locked: bool = False


def older_than(drives: Iterable[DriveAge], cutoff_utc: float) -> list[int]:
    """Unlocked drives recorded before ``cutoff_utc``, oldest first."""
    return [d.id for d in sorted(drives, key=lambda d: d.start_utc) if d.start_utc < cutoff_utc and not d.locked]


def over_budget(
    drives: Iterable[DriveAge],
    segments: list[SegmentRef],
    forgotten: Iterable[int],
    keep_bytes: int,
) -> tuple[list[int], ForgetPlan]:
    """The oldest unlocked drives to forget until the archive's bitstreams fit in ``keep_bytes``,
    counting what each step really frees (a baseline's frames that others need stay), and the plan.
    If even forgetting every unlocked drive does not fit, all of them are returned."""
    ds = sorted(drives, key=lambda d: d.start_utc)
    live = [d.id for d in ds]
    gone = set(forgotten)
    total = sum({s.blob: s.bytes for s in segments}.values())
    chosen: list[int] = []
    plan = plan_forget(segments, live, gone)
    for d in ds:
        if total - plan.bytes_freed <= keep_bytes:
            break
        if d.locked:
            continue
        chosen.append(d.id)
        plan = plan_forget(segments, [x for x in live if x not in chosen], gone | set(chosen))
    return chosen, plan
