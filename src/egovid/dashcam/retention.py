"""Retention: forgetting drives without changing any other drive's frames.

A drive coded jointly decodes with the frames of its reference drive, so forgetting a drive other
drives were coded against cannot simply delete its bitstreams: re-encoding the dependents against
something else would change their pictures. :func:`plan_forget` keeps exactly the segments still
needed: every segment of a live drive, and, transitively, every segment holding a frame that a
needed joint segment refers to. A forgotten drive whose segments are all unneeded is purged; one
with needed segments stays as a hidden *reference* (no longer listed, found, extracted or used as a
baseline for new drives) holding only those segments, and is purged by a later forget once nothing
needs them. Bytes freed are those of the bitstreams no remaining segment uses.

Policies pick the drives: :func:`older_than` (recorded before a time) and :func:`over_budget`
(oldest first until the archive fits a byte budget, counting what forgetting really frees).
Locked drives are never picked, and naming one is an error.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from egovid.errors import EgovidError

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
    drive, its bitstream and size, and for a joint segment the reference drive and the frames of it
    that the segment's frames are predicted from."""

    id: int
    drive_id: int
    frame_start: int
    frame_end: int
    blob: str
    bytes: int
    ref_drive_id: int | None = None
    ref_frames: np.ndarray | None = None


@dataclass
class ForgetPlan:
    """Segments to delete and to keep, drives to purge entirely and drives kept as hidden
    references (with the live drives that still need them), and the bytes freed."""

    delete_segments: list[int] = field(default_factory=list)
    keep_as_reference: dict[int, list[int]] = field(default_factory=dict)  # drive -> its kept segments
    needed_by: dict[int, list[int]] = field(default_factory=dict)  # kept drive -> live drives needing it
    purge_drives: list[int] = field(default_factory=list)
    delete_blobs: list[str] = field(default_factory=list)
    bytes_freed: int = 0


def plan_forget(segments: Iterable[SegmentRef], live_drives: Iterable[int], forgotten: Iterable[int]) -> ForgetPlan:
    """Which segments stay and which go when only ``live_drives`` remain (see the module docstring).

    ``forgotten``: drives no longer live (those being forgotten now and hidden references kept
    earlier); every segment of theirs that no live drive needs, directly or through other needed
    segments, is deleted."""
    segs = list(segments)
    live = set(live_drives)
    gone = set(forgotten)
    by_drive: dict[int, list[SegmentRef]] = {}
    for s in segs:
        by_drive.setdefault(s.drive_id, []).append(s)
    # needed: segment id -> live drives that need it (transitively)
    needed: dict[int, set[int]] = {}
    stack = [(s, s.drive_id) for s in segs if s.drive_id in live]
    while stack:
        s, root = stack.pop()
        if root in needed.get(s.id, ()):
            continue
        needed.setdefault(s.id, set()).add(root)
        if s.ref_drive_id is None or s.ref_frames is None or len(s.ref_frames) == 0:
            continue
        frames = np.unique(np.asarray(s.ref_frames, dtype=np.int64))
        for t in by_drive.get(s.ref_drive_id, []):
            lo = np.searchsorted(frames, t.frame_start)
            if lo < len(frames) and frames[lo] < t.frame_end:
                stack.append((t, root))
    plan = ForgetPlan()
    kept_blobs: set[str] = set()
    for s in segs:
        if s.id in needed:
            kept_blobs.add(s.blob)
            if s.drive_id in gone:
                plan.keep_as_reference.setdefault(s.drive_id, []).append(s.id)
                plan.needed_by.setdefault(s.drive_id, [])
                for d in needed[s.id]:
                    if d not in plan.needed_by[s.drive_id]:
                        plan.needed_by[s.drive_id].append(d)
        elif s.drive_id in gone:
            plan.delete_segments.append(s.id)
        else:  # a live drive's segment is always needed; anything else is a caller error
            raise ValueError(f"segment {s.id} of drive {s.drive_id} is neither live nor forgotten")
    plan.purge_drives = sorted(d for d in gone if d not in plan.keep_as_reference)
    sizes = {s.blob: s.bytes for s in segs if s.id in plan.delete_segments}
    plan.delete_blobs = sorted(b for b in sizes if b not in kept_blobs)
    plan.bytes_freed = sum(sizes[b] for b in plan.delete_blobs)
    for v in plan.needed_by.values():
        v.sort()
    return plan


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
