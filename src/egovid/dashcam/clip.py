"""``dashcam clip``: a shareable video of an incident, with its GPX beside it.

The moment is given as a UTC time (``--at``) or a place (``--near``, the closest pass of the latest
drive there, or of ``--drive``); :func:`plan_clip` finds it and :func:`window` turns it into the
drive's frames [f0, f1) covering ``before`` seconds before and ``after`` seconds after.
:func:`write_clip` writes those frames as
the archive decodes them (checked against the encoder's reconstruction digests, as ``extract``
does) into an H.264 MP4 that phones and browsers play (yuv420p, ``+faststart``; CRF 18 by
default, or lossless with ``lossless=True``: then every frame is bit-exact with the archive), tagged
with the source's colour tags, with the archived audio (as AAC) and telemetry (GoPro GPMF …) of
the same stretch, and writes ``NAME.gpx`` beside it with the GPS fixes of the stretch.
"""

from __future__ import annotations

import datetime as dt
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_text
from egovid.dashcam.archive.catalogue import Drive
from egovid.dashcam.archive.fleetstore import FleetStore
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.extract import archived_extras, channel_jobs, extract_video
from egovid.dashcam.find import Query, frame_positions, stretches
from egovid.dashcam.route.clock import iso
from egovid.dashcam.route.tracks import project


@dataclass
class ClipPlan:
    """What a clip holds: drive, frames [frame_start, frame_end), the UTC time of its first frame and
    of the moment asked for (seconds)."""

    drive: Drive
    frame_start: int
    frame_end: int
    start_utc: float
    moment_utc: float

    @property
    def frames(self) -> int:
        return self.frame_end - self.frame_start


def window(frame_utc: np.ndarray, moment: float, before: float, after: float) -> tuple[int, int]:
    """Frames [f0, f1) from ``before`` seconds before ``moment`` (UTC) to ``after`` seconds after it,
    cut to the drive."""
    f0 = int(np.searchsorted(frame_utc, moment - before, side="left"))
    f1 = int(np.searchsorted(frame_utc, moment + after, side="right"))
    return max(0, f0), min(len(frame_utc), max(f1, f0 + 1))


def plan_clip(
    archive: Archive,
    *,
    at: float | None = None,
    near: tuple[float, float] | None = None,
    radius: float = 50.0,
    drive: str | None = None,
    before: float = 10.0,
    after: float = 10.0,
) -> ClipPlan:
    """Find the drive and frames of a clip (see the module docstring): ``at`` (UTC seconds) in the
    latest drive recording then, or the closest pass within ``radius`` metres of ``near`` (lat,
    lon degrees) of the drive that passed last; ``drive``: only that one (name or id)."""
    if (at is None) == (near is None):
        raise EgovidError("give the moment with --at TIME or the place with --near LAT,LON", "one of the two")
    for name, v in (("--before", before), ("--after", after)):
        if not (np.isfinite(v) and 0 <= v <= 3600):
            raise EgovidError(f"{name} {v} is not usable", "give seconds between 0 and 3600")
    fleet = FleetStore(archive.catalogue)
    drives = [fleet.live_drive(drive)] if drive is not None else fleet.live_drives()
    best: tuple[float, float, Drive, np.ndarray] | None = None  # (rank, moment, drive, frame_utc)
    for d in drives:
        futc = fleet.frame_utc(d.id, d.fps)
        moment = _moment_in(fleet, d, futc, at, near, radius) if len(futc) else None
        if moment is None:
            continue
        rank = d.start_utc if at is not None else moment  # the latest drive; the latest pass
        if best is None or rank > best[0]:
            best = (rank, moment, d, futc)
    if best is None:
        raise _not_there(at, near, radius, drive)
    _, moment, d, futc = best
    f0, f1 = window(futc, moment, before, after)
    return ClipPlan(d, f0, f1, float(futc[f0]), moment)


def channel_plans(archive: Archive, plan: ClipPlan, channel: str | None = None) -> dict[str, ClipPlan]:
    """The clip of each camera ``channel`` names (default: the drive's main one; ``all``: every
    camera, over the time all of them recorded; :func:`~egovid.dashcam.extract.channel_jobs`),
    by channel name."""
    jobs = channel_jobs(archive, plan.drive, plan.frame_start, plan.frame_end, channel)
    return {j.channel: replace(plan, drive=j.drive, frame_start=j.frame_start, frame_end=j.frame_end,
                               start_utc=j.start_utc if np.isfinite(j.start_utc) else plan.start_utc)
            for j in jobs}  # fmt: skip


def _moment_in(fleet: FleetStore, d: Drive, futc: np.ndarray, at, near, radius: float) -> float | None:
    """The clip's moment in drive ``d`` (UTC seconds): ``at`` if the drive was recording then,
    else the frame of its closest pass near ``near``; None if it has neither."""
    if at is not None:
        return at if futc[0] - 0.5 / d.fps <= at <= futc[-1] + 0.5 / d.fps else None
    track = fleet.track(d.id)
    if track is None:
        return None
    found = stretches(Query(near=near, radius=radius), d.name, "", futc, *track, fps=d.fps)
    if not found:
        return None
    s = min(found, key=lambda x: x.distance_m)
    return _closest_moment(futc, track, near, s.frame_start, s.frame_end)


def _not_there(at, near, radius: float, drive: str | None) -> EgovidError:
    """The error for a moment or place no drive (or not ``drive``) recorded."""
    where = iso(at) if at is not None else f"within {radius:g} m of {near[0]:.6f},{near[1]:.6f}"
    if at is not None:
        what = f"drive {drive} was not recorded at {where}" if drive else f"{where} is not recorded in any drive"
    else:
        what = f"drive {drive} never passed {where}" if drive else f"no drive passed {where}"
    return EgovidError(what, "see `egovid dashcam find` for when and where drives were recorded")


def _closest_moment(futc, track, near, f0: int, f1: int) -> float:
    """UTC of the frame of [f0, f1) closest to ``near``."""
    pos = frame_positions(futc[f0:f1], *track)
    xy = project(pos[:, 0], pos[:, 1], near)
    return float(futc[f0 + int(np.argmin(np.hypot(xy[:, 0], xy[:, 1])))])


def write_gpx(path: str | os.PathLike, name: str, t: np.ndarray, lat: np.ndarray, lon: np.ndarray) -> Path:
    """A GPX 1.1 track of fixes (UTC seconds, degrees), written atomically."""
    import gpxpy.gpx  # only clips write GPX

    gpx = gpxpy.gpx.GPX()
    gpx.creator = "egovid"
    trk = gpxpy.gpx.GPXTrack(name=name)
    seg = gpxpy.gpx.GPXTrackSegment()
    for ti, la, lo in zip(t, lat, lon, strict=True):
        seg.points.append(
            gpxpy.gpx.GPXTrackPoint(float(la), float(lo), time=dt.datetime.fromtimestamp(float(ti), dt.UTC))
        )
    trk.segments.append(seg)
    gpx.tracks.append(trk)
    return atomic_write_text(path, gpx.to_xml(version="1.1"))


def write_clip(
    archive: Archive,
    plan: ClipPlan,
    out: str | os.PathLike,
    *,
    crf: int = 18,
    lossless: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Write the clip and its GPX (see the module docstring); returns what was written.
    ``progress(done, total)``: frames written."""
    out = Path(out)
    if out.suffix.lower() != ".mp4":
        raise EgovidError(f"cannot write a clip to {out.name}", "give an .mp4 output (H.264)")
    d = plan.drive
    fleet = FleetStore(archive.catalogue)
    extras = archived_extras(archive, d)
    extract_video(
        archive, d, out, progress, (plan.frame_start, plan.frame_end), **extras,
        crf=None if lossless else crf, audio_codec="aac",
    )  # fmt: skip
    info = fleet.meta(d.id).streams_info
    kept = [k for k in ("audio", "telemetry") if info.get(k)] if extras.get("streams") is not None else []
    gpx_path = out.with_suffix(".gpx")
    fixes = _write_stretch_gpx(gpx_path, fleet, plan)
    return {"video": str(out), "gpx": str(gpx_path) if fixes else None, "drive": d.name, "frames": plan.frames,
            "frame_start": plan.frame_start, "frame_end": plan.frame_end, "start": iso(plan.start_utc),
            "moment": iso(plan.moment_utc), "gps_fixes": fixes, "streams": kept, "lossless": lossless}  # fmt: skip


def _write_stretch_gpx(path: Path, fleet: FleetStore, plan: ClipPlan) -> int:
    """Write the GPS fixes of the clip's stretch (a second either side) as GPX; how many (0: no
    file written)."""
    d = plan.drive
    track = fleet.track(d.id)
    if track is None:
        return 0
    t, lat, lon = track
    end_utc = plan.start_utc + plan.frames / d.fps
    sel = (t >= plan.start_utc - 1.0) & (t <= end_utc + 1.0)
    if not sel.any():
        return 0
    write_gpx(path, f"{d.name} {iso(plan.start_utc)}", t[sel], lat[sel], lon[sel])
    return int(sel.sum())
