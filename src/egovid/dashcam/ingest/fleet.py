"""Ingest as a fleet needs it: many files or folders, embedded GPS, trips, events, audio/telemetry.

:func:`prepare` looks at the inputs (:func:`egovid.dashcam.ingest.sources.plan_ingest`: each file's
GPS, clock, kind; trips of loop-recording files) and turns every trip into a
:class:`~egovid.dashcam.ingest.records.DriveInput` for the staged ingest: its files in order
(decoded back to back as one drive), its GPS track (the files' own fixes joined, or the shared
log), its UTC start, and a :class:`FleetRecord` that the ingest's commit writes in the same
transaction (kind, camera, lock, clock, the files and their gaps, the GPS track for ``find`` and
the map, colour tags, the audio/telemetry blob). The audio and telemetry are archived
(:mod:`egovid.dashcam.codec.streams`) into the blob store before the ingest, like its bitstreams: a
failed ingest leaves at most an unreferenced blob for ``gc``.
"""

from __future__ import annotations

import datetime as dt
import uuid
from dataclasses import dataclass, field

import numpy as np

from egovid.core.errors import EgovidError
from egovid.dashcam.archive.catalogue import Catalogue
from egovid.dashcam.archive.fleetstore import DriveMeta, DrivePart, FleetStore
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.codec.streams import archive_streams
from egovid.dashcam.ingest.records import DriveInput, VideoProbe
from egovid.dashcam.ingest.sources import FileSource, IngestPlan
from egovid.dashcam.route.tracks import GpsTrack, _finish
from egovid.dashcam.route.trips import Trip

ALREADY_IN = "already in the archive"  # why a file whose drive was ingested before is skipped


@dataclass
class FleetRecord:
    """The fleet rows of a drive, written by the ingest's commit (picklable: it travels with the
    drive to a Dask worker). ``track``: (t, lat, lon) of the fixes over the drive."""

    meta: DriveMeta
    parts: list[DrivePart]
    track: tuple[np.ndarray, np.ndarray, np.ndarray]
    track_source: str = ""

    def commit(self, cat: Catalogue, drive_id: int) -> None:
        self.meta.drive_id = drive_id
        FleetStore(cat).add_drive(self.meta, self.parts, self.track, self.track_source)


@dataclass
class PreparedDrive:
    """A trip ready for the staged ingest, and what the user is told about it."""

    name: str
    trip: Trip
    sources: list[FileSource]
    start_utc: float
    track: GpsTrack
    record: FleetRecord
    notes: list[str] = field(default_factory=list)

    def describe(self) -> str:
        """What the console says about the drive besides the ingest's figures."""
        kind = (
            "" if self.trip.kind == "drive" else f" {self.trip.kind}{' (locked)' if self.record.meta.locked else ''},"
        )
        gaps = ", ".join(f"{g:.1f}" for g in self.trip.gaps)
        files = f" {len(self.sources)} files (gaps {gaps} s)," if len(self.sources) > 1 else ""
        return f"{kind}{files} starting {self.record.meta.clock['start']} ({self.record.meta.clock['source']}),"

    def summary(self) -> dict:
        """The fleet side of the drive's JSON report."""
        m = self.record.meta
        return {"kind": self.trip.kind, "camera": m.channel, "files": [str(s.path.resolve()) for s in self.sources],
                "gaps_s": self.trip.gaps, "clock": m.clock, "locked": m.locked, "streams": m.streams_info,
                "colour": m.colour, "notes": self.notes}  # fmt: skip


def _joined_track(sources: list[FileSource]) -> GpsTrack:
    """One track over a trip: the shared log as it is, else the files' own fixes joined in time."""
    tracks = []
    for s in sources:
        if not any(s.track is t for t in tracks):
            tracks.append(s.track)
    if len(tracks) == 1:
        return tracks[0]
    t = np.concatenate([x.t for x in tracks])
    order = np.argsort(t, kind="stable")
    cols = [np.concatenate([getattr(x, k) for x in tracks])[order] for k in ("lat", "lon", "speed", "bearing")]
    return _finish(t[order], *cols, "; ".join(sorted({x.source for x in tracks})), {})


def prepare(
    archive: Archive,
    plan: IngestPlan,
    *,
    name: str | None = None,
    lock_events: bool = True,
) -> list[PreparedDrive]:
    """The drives of an ingest plan, with their audio/telemetry already in the blob store.

    An archive made without the fleet tables (``Archive.create`` without ``setup``) gets them here,
    before any drive is committed: made inside a commit, they would list the drive being added
    as an older one."""
    FleetStore(archive.catalogue)
    taken = {d.name for d in archive.catalogue.drives()}
    if name is not None and len(plan.trips.trips) > 1:
        raise EgovidError(f"--name {name!r} names one drive, but the inputs make {len(plan.trips.trips)}",
                          "leave --name out: each drive is named after its first file")  # fmt: skip
    out = []
    single = len(plan.trips.trips) == 1 and not plan.skipped
    for trip in plan.trips.trips:
        nm = name or trip.parts[0].file.path.stem
        if nm in taken:
            if single:
                raise EgovidError(f"a drive named {nm!r} is already in the archive", "pass --name to choose another")
            plan.skipped.append((trip.parts[0].file.path, f"{ALREADY_IN} as drive {nm!r}"))
            continue
        taken.add(nm)
        out.append(_prepare_trip(archive, nm, trip, [plan.sources[p.file.path] for p in trip.parts], lock_events))
    return out


def _prepare_trip(archive: Archive, name: str, trip: Trip, srcs: list[FileSource], lock_events: bool) -> PreparedDrive:
    """One trip made a drive: its files' frame ranges, its audio/telemetry blob (stored now), its
    GPS track and its fleet rows."""
    start = float(trip.parts[0].start_utc)
    fps = srcs[0].info.fps
    parts, f = [], 0
    media = []
    for i, (p, s) in enumerate(zip(trip.parts, srcs, strict=True)):
        n = len(s.times)
        parts.append(DrivePart(i, str(s.path.resolve()), f, f + n, float(p.start_utc), float(p.gap_before)))
        media.append((s.path, f / fps, n / fps))
        f += n
    blob, info = archive_streams(media)
    sha = archive.blobs.put(blob) if blob is not None else None
    track = _joined_track(srcs)
    end = float(trip.parts[-1].start_utc + srcs[-1].duration)
    inside = (track.t >= start - 5) & (track.t <= end + 5)
    locked = lock_events and trip.kind == "event"
    meta = DriveMeta(
        0,
        kind=trip.kind,
        channel=srcs[0].channel,
        locked=locked,
        lock_note="event file" if locked else None,
        clock={"source": srcs[0].clock.source, "start": dt.datetime.fromtimestamp(start, dt.UTC).isoformat(),
               "notes": sorted({n for s in srcs for n in s.clock.notes}),
               "parts": [s.clock.source for s in srcs]},
        colour=srcs[0].info.colour.to_dict(),
        streams_blob=sha,
        streams_bytes=len(blob) if blob is not None else 0,
        streams_info=info.to_dict(),
    )  # fmt: skip
    rec = FleetRecord(meta, parts, (track.t[inside], track.lat[inside], track.lon[inside]), track.source)
    notes = list(meta.clock["notes"]) + [f"not archived: {x}" for x in info.skipped]
    return PreparedDrive(name, trip, srcs, start, track, rec, notes)


def drive_input(p: PreparedDrive) -> DriveInput:
    """The staged ingest's input for a prepared drive, carrying the probe its files' examination
    made (:func:`drive_probe`), so no file is opened again before it is decoded."""
    many = len(p.sources) > 1
    return DriveInput(
        video=p.sources[0].path,
        gps=None,
        name=p.name,
        start_utc=p.start_utc,
        token=uuid.uuid4().hex,
        parts=tuple(s.path for s in p.sources) if many else (),
        part_starts=tuple(float(x.start_utc) for x in p.trip.parts) if many else (),
        track=p.track,
        gps_label=p.sources[0].gps_source,
        extra=p.record,
        probe=drive_probe(p),
    )


def drive_probe(p: PreparedDrive) -> VideoProbe:
    """Stage *probe* of a prepared drive from what :func:`~egovid.dashcam.ingest.sources.examine`
    found in its files (each demuxed once): the first file's description, the frame times of
    every file on the trip's clock (seconds from the first frame, the gaps between files kept)
    and the trip's UTC start."""
    starts = [float(x.start_utc) for x in p.trip.parts]
    times = np.concatenate([s.times + (t - starts[0]) for s, t in zip(p.sources, starts, strict=True)])
    return VideoProbe(p.sources[0].path, p.sources[0].info, times, p.start_utc)
