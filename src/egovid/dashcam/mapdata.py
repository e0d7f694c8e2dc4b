"""The archive's live drives as map records (:class:`~egovid.dashcam.mapview.MapDrive`): one stretch
per stored segment, drawn along the drive's GPS track, with its saving and details."""

from __future__ import annotations

import numpy as np

from egovid.dashcam.archive.fleetstore import FleetStore
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.mapview import MapDrive, MapStretch
from egovid.dashcam.route.clock import iso


def _kib(n: float) -> str:
    return f"{n / 1024:.0f} KiB" if n < 10 * 1024**2 else f"{n / 1024**2:.1f} MiB"


def map_drives(archive: Archive, fleet: FleetStore) -> tuple[list[MapDrive], list[str]]:
    """Map records of every live drive with a GPS track, and the names of those without one
    (ingested before tracks were kept)."""
    cat = archive.catalogue
    out: list[MapDrive] = []
    missing: list[str] = []
    names = {d.id: d.name for d in cat.drives()}
    for d in fleet.live_drives():
        track = fleet.track(d.id)
        if track is None:
            missing.append(d.name)
            continue
        t, lat, lon = track
        futc = fleet.frame_utc(d.id, d.fps)
        meta = fleet.meta(d.id)
        parts = fleet.parts(d.id)
        segs = archive.segments(d.id)
        stretches = []
        for g in segs:
            a, b = float(futc[g.frame_start]), float(futc[min(g.frame_end, len(futc)) - 1])
            inside = (t > a) & (t < b)
            ts = np.concatenate([[a], t[inside], [b]])
            la, lo = np.interp(ts, t, lat), np.interp(ts, t, lon)
            alone = g.params.get("standalone_bytes")
            saving = 1.0 - g.bytes / alone if alone else None
            info = {
                "frames": f"{g.frame_start}-{g.frame_end - 1} ({iso(a)[11:19]}-{iso(b)[11:19]} UTC)",
                "coded": "jointly against " + names.get(g.ref_drive_id, "?") if g.mode == "joint" else "root (intra)",
                "stored": _kib(g.bytes),
                "saving": f"{100 * saving:.1f} % vs standalone" if saving is not None else "not measured",
            }
            if "psnr_y" in g.params:
                info["PSNR-Y"] = f"{g.params['psnr_y']:.2f} dB"
            stretches.append(MapStretch(la, lo, saving, info))
        gaps = [p.gap_before for p in parts[1:]]
        info = {
            "recorded": f"{iso(float(futc[0]))} to {iso(float(futc[-1]))}",
            "length": f"{d.frames} frames, {d.frames / d.fps:.0f} s, {d.width}x{d.height} @ {d.fps:g} fps",
            "size": _kib(sum(g.bytes for g in segs) + meta.streams_bytes),
            "files": f"{len(parts)}" + (f" (gaps {', '.join(f'{x:.1f} s' for x in gaps)})" if gaps else ""),
            "clock": meta.clock.get("source", "?"),
        }
        if meta.locked:
            info["locked"] = meta.lock_note or "yes"
        out.append(MapDrive(d.name, stretches, meta.kind, info))
    return out, missing
