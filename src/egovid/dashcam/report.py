"""What an archive holds and what joint coding saved: bits per path and per drive (``egovid
dashcam report``; a table or JSON)."""

from __future__ import annotations

from egovid.dashcam.archive.store import Archive
from egovid.dashcam.codec import registry


def archive_report(archive: Archive) -> dict:
    """Bits per path and per drive, joint vs measured standalone sizes (where an ingest measured
    them, ``--measure-savings``), the blob store's size and the codec."""
    cat = archive.catalogue
    drives = {d.id: d for d in cat.drives()}
    per_path: dict[int, dict] = {}
    per_drive = []
    for d in drives.values():
        segs = cat.segments(d.id)
        total = sum(s.bytes for s in segs)
        joint = [s for s in segs if s.mode == "joint" and s.params.get("standalone_bytes")]
        jb = sum(s.bytes for s in joint)
        sb = sum(s.params["standalone_bytes"] for s in joint)
        per_drive.append(
            {
                "drive": d.name,
                "frames": d.frames,
                "bytes": total,
                "bits_per_frame": 8 * total / max(d.frames, 1),
                "joint_frames": sum(s.frame_end - s.frame_start for s in segs if s.mode == "joint"),
                "saving_on_joint_frames": (1 - jb / sb) if sb else None,
                "references": sorted({drives[s.ref_drive_id].name for s in segs if s.ref_drive_id}),
            }
        )
        seg_by_id = {s.id: s for s in segs}
        for seq in cat.sequences(drive_id=d.id):
            seg = seg_by_id[seq.segment_id]
            share = (seq.frame_end - seq.frame_start) / max(seg.frame_end - seg.frame_start, 1)
            p = per_path.setdefault(
                seq.path_id,
                {
                    "path": seq.path_id,
                    "sequences": 0,
                    "frames": 0,
                    "bytes": 0.0,
                    "joint_bytes": 0.0,
                    "standalone_bytes": 0.0,
                },
            )
            p["sequences"] += 1
            p["frames"] += seq.frame_end - seq.frame_start
            p["bytes"] += seg.bytes * share
            if seg.mode == "joint" and seg.params.get("standalone_bytes"):
                p["joint_bytes"] += seg.bytes * share
                p["standalone_bytes"] += seg.params["standalone_bytes"] * share
    paths_out = []
    for pid, p in sorted(per_path.items()):
        rec = cat.path(pid)
        paths_out.append(
            {
                "path": pid,
                "length_m": round(rec.length_m, 1),
                "sequences": p["sequences"],
                "frames": p["frames"],
                "bytes": round(p["bytes"]),
                "bits_per_frame": 8 * p["bytes"] / max(p["frames"], 1),
                "saving": (1 - p["joint_bytes"] / p["standalone_bytes"]) if p["standalone_bytes"] else None,
            }
        )
    return {
        "archive": str(archive.root),
        "blobs": archive.blobs.url,
        "drives": per_drive,
        "paths": paths_out,
        "blob_bytes": archive.blobs.total_bytes(),
        "codec": registry.describe(),
    }
