"""What an archive holds and what joint coding saved: the drives a user sees (``egovid dashcam
list``), how one is stored (``show``), and bits per path and per drive (``report``; a table or
JSON). Each function returns data; the CLI formats it."""

from __future__ import annotations

from dataclasses import dataclass

from egovid.dashcam.archive import readings
from egovid.dashcam.archive.catalogue import Catalogue, Drive, Segment, Sequence
from egovid.dashcam.archive.fleetstore import (
    channel_of_drives,
    drive_channels,
    fleet_version,
    live_drive,
    live_drives,
)
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.codec import registry


@dataclass
class DriveRow:
    """A drive as ``list`` shows it: the drive, the bytes its segments take with those of its
    other cameras, their modes (sorted) and its cameras (its own first)."""

    drive: Drive
    bytes: int
    modes: list[str]
    cameras: list[str]


def list_drives(archive: Archive) -> list[DriveRow]:
    """``egovid dashcam list``: every live drive (not the hidden references of forgotten ones, nor
    the other cameras of a multi-camera drive, whose bytes count in their drive's row)."""
    cat = archive.catalogue
    rows = []
    for d in live_drives(cat):
        channels = drive_channels(cat, d.id)
        segs = [s for i in channels.values() for s in cat.segments(i)]
        rows.append(DriveRow(d, sum(s.bytes for s in segs), sorted({s.mode for s in segs}), list(channels)))
    return rows


@dataclass
class DriveLayout:
    """How a drive is stored (``show``): its path sequences and segments, and for each segment
    the name of the drive it is coded against (None for a root)."""

    drive: Drive
    sequences: list[Sequence]
    segments: list[tuple[Segment, str | None]]


def describe_drive(archive: Archive, key: str) -> DriveLayout:
    """``egovid dashcam show``: the live drive ``key`` (name or id) and how it is stored."""
    cat = archive.catalogue
    d = live_drive(cat, key, archive.root)
    segs = [(g, cat.drive(g.ref_drive_id).name if g.ref_drive_id else None) for g in cat.segments(d.id)]
    return DriveLayout(d, cat.sequences(drive_id=d.id), segs)


def archive_report(archive: Archive) -> dict:
    """``egovid dashcam report``: bits per path and per drive, joint vs measured standalone sizes
    (where an ingest measured them, ``--measure-savings``), the blob store's size and the codec.
    Each drive says its camera (``channel``); a drive of a multi-camera dashcam lists its
    cameras (``channels``: channel → the drive row holding it), and each of those rows names the
    drive it is a camera of (``channel_of``). For a drive whose car recorded readings, their
    summary (``readings``: maximum speed and accelerations,
    :func:`egovid.dashcam.archive.readings.summarise`; None for the others)."""
    cat = archive.catalogue
    drives = {d.id: d for d in cat.drives()}
    cameras = channel_of_drives(cat)
    primary, others = _channels(cat)
    recorded = readings.summaries(cat)
    per_path: dict[int, dict] = {}
    per_drive = []
    for d in drives.values():
        segs = cat.segments(d.id)
        row = {**_drive_row(d, segs, drives), "readings": recorded.get(d.id)}
        row["channel"] = cameras.get(d.id, "front")
        if d.id in others:
            row["channels"] = {row["channel"]: d.name, **{ch: drives[i].name for ch, i in others[d.id]}}
        if d.id in primary:
            row["channel_of"] = drives[primary[d.id]].name
        per_drive.append(row)
        _add_sequences(per_path, cat, d, segs)
    return {
        "archive": str(archive.root),
        "blobs": archive.blobs.url,
        "drives": per_drive,
        "paths": [_path_row(cat, pid, p) for pid, p in sorted(per_path.items())],
        "blob_bytes": archive.blobs.total_bytes(),
        "codec": registry.describe(),
    }


def _channels(cat: Catalogue) -> tuple[dict[int, int], dict[int, list[tuple[str, int]]]]:
    """The multi-camera drives (read only): channel drive → its drive, and drive → its other
    cameras (channel, drive id)."""
    if fleet_version(cat) < 2:
        return {}, {}
    primary: dict[int, int] = {}
    others: dict[int, list[tuple[str, int]]] = {}
    for i, p, ch in cat._q("SELECT drive_id, primary_id, channel FROM drive_channels ORDER BY drive_id"):
        primary[int(i)] = int(p)
        others.setdefault(int(p), []).append((ch, int(i)))
    return primary, others


def _drive_row(d: Drive, segs: list[Segment], drives: dict[int, Drive]) -> dict:
    """A drive's line of the report: its bytes, bits per frame, joint frames and their saving."""
    total = sum(s.bytes for s in segs)
    joint = [s for s in segs if s.mode == "joint" and s.params.get("standalone_bytes")]
    jb = sum(s.bytes for s in joint)
    sb = sum(s.params["standalone_bytes"] for s in joint)
    return {
        "drive": d.name,
        "frames": d.frames,
        "bytes": total,
        "bits_per_frame": 8 * total / max(d.frames, 1),
        "joint_frames": sum(s.frame_end - s.frame_start for s in segs if s.mode == "joint"),
        "saving_on_joint_frames": (1 - jb / sb) if sb else None,
        "references": sorted({drives[s.ref_drive_id].name for s in segs if s.ref_drive_id}),
    }


def _add_sequences(per_path: dict[int, dict], cat: Catalogue, d: Drive, segs: list[Segment]) -> None:
    """Add a drive's sequences to the totals of their paths (a segment's bytes shared out by the
    frames each sequence holds of it)."""
    seg_by_id = {s.id: s for s in segs}
    for seq in cat.sequences(drive_id=d.id):
        seg = seg_by_id[seq.segment_id]
        share = (seq.frame_end - seq.frame_start) / max(seg.frame_end - seg.frame_start, 1)
        p = per_path.setdefault(
            seq.path_id,
            {"sequences": 0, "frames": 0, "bytes": 0.0, "joint_bytes": 0.0, "standalone_bytes": 0.0},
        )
        p["sequences"] += 1
        p["frames"] += seq.frame_end - seq.frame_start
        p["bytes"] += seg.bytes * share
        if seg.mode == "joint" and seg.params.get("standalone_bytes"):
            p["joint_bytes"] += seg.bytes * share
            p["standalone_bytes"] += seg.params["standalone_bytes"] * share


def _path_row(cat: Catalogue, pid: int, p: dict) -> dict:
    """A path's line of the report, from its totals (:func:`_add_sequences`)."""
    return {
        "path": pid,
        "length_m": round(cat.path(pid).length_m, 1),
        "sequences": p["sequences"],
        "frames": p["frames"],
        "bytes": round(p["bytes"]),
        "bits_per_frame": 8 * p["bytes"] / max(p["frames"], 1),
        "saving": (1 - p["joint_bytes"] / p["standalone_bytes"]) if p["standalone_bytes"] else None,
    }
