"""The archive's live drives on a map (``egovid dashcam report --html``): map records
(:class:`~egovid.dashcam.mapview.MapDrive`), one stretch per stored segment drawn along the drive's
GPS track with its saving and details, and the page :func:`~egovid.dashcam.mapview.render_map`
draws of them (:func:`archive_map`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egovid.dashcam.archive.catalogue import Drive, Segment
from egovid.dashcam.archive.fleetstore import FleetStore
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.mapview import OSM_TILES, MapDrive, MapStretch, render_map
from egovid.dashcam.route.clock import iso


def _kib(n: float) -> str:
    return f"{n / 1024:.0f} KiB" if n < 10 * 1024**2 else f"{n / 1024**2:.1f} MiB"


@dataclass
class ArchiveMap:
    """The map page of an archive (HTML, self-contained), the drives drawn on it and the names of
    the live drives without a GPS track (ingested before tracks were kept)."""

    html: str
    drives: list[str]
    missing: list[str]


def tile_url(option: str) -> str | None:
    """The background tiles of ``--tiles``: ``osm`` (OpenStreetMap), ``none``, or an XYZ URL."""
    return {"osm": OSM_TILES, "none": None}.get(option, option)


def archive_map(archive: Archive, *, colour_by: str = "drive", tiles: str = "osm") -> ArchiveMap:
    """The map of the archive's live drives (:func:`map_drives`), titled with the archive folder's
    name; ``colour_by``: ``drive`` or ``saving``; ``tiles``: as ``--tiles`` (:func:`tile_url`)."""
    drives, missing = map_drives(archive)
    title = f"{archive.root.resolve().name}: {len(drives)} drives"
    page = render_map(drives, title=title, tiles=tile_url(tiles), colour_by=colour_by)
    return ArchiveMap(page, [d.name for d in drives], missing)


def map_drives(archive: Archive) -> tuple[list[MapDrive], list[str]]:
    """Map records of every live drive with a GPS track, and the names of those without one
    (ingested before tracks were kept)."""
    fleet = FleetStore(archive.catalogue)
    out: list[MapDrive] = []
    missing: list[str] = []
    names = {d.id: d.name for d in archive.catalogue.drives()}
    for d in fleet.live_drives():
        track = fleet.track(d.id)
        if track is None:
            missing.append(d.name)
            continue
        futc = fleet.frame_utc(d.id, d.fps)
        segs = archive.segments(d.id)
        stretches = [_stretch(g, futc, track, names) for g in segs]
        out.append(MapDrive(d.name, stretches, fleet.meta(d.id).kind, _drive_info(fleet, d, futc, segs)))
    return out, missing


def _stretch(g: Segment, futc: np.ndarray, track, names: dict[int, str]) -> MapStretch:
    """A segment's stretch of the track (positions at its first and last frames and the fixes
    between), with its saving and details."""
    t, lat, lon = track
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
    return MapStretch(la, lo, saving, info)


def _drive_info(fleet: FleetStore, d: Drive, futc: np.ndarray, segs: list[Segment]) -> dict[str, str]:
    """The details of a drive shown on click: when, how long, its size, files and clock, and the
    other cameras of a multi-camera drive."""
    meta = fleet.meta(d.id)
    parts = fleet.parts(d.id)
    gaps = [p.gap_before for p in parts[1:]]
    info = {
        "recorded": f"{iso(float(futc[0]))} to {iso(float(futc[-1]))}",
        "length": f"{d.frames} frames, {d.frames / d.fps:.0f} s, {d.width}x{d.height} @ {d.fps:g} fps",
        "size": _kib(sum(g.bytes for g in segs) + meta.streams_bytes),
        "files": f"{len(parts)}" + (f" (gaps {', '.join(f'{x:.1f} s' for x in gaps)})" if gaps else ""),
        "clock": meta.clock.get("source", "?"),
    }
    cams = fleet.channels(d.id)
    if len(cams) > 1:  # the other cameras of a multi-camera dashcam, with what they take
        cat = fleet.cat
        more = [f"{ch} ({_kib(sum(g.bytes for g in cat.segments(i)))})" for ch, i in cams.items() if i != d.id]
        info["cameras"] = f"{meta.channel} (main), " + ", ".join(more)
    if meta.locked:
        info["locked"] = meta.lock_note or "yes"
    return info
