"""Ingest as a fleet needs it: many files or folders, embedded GPS, trips, events, audio/telemetry.

:func:`prepare` looks at the inputs (:func:`egovid.dashcam.ingest.sources.plan_ingest`: each file's
GPS, clock, kind; trips of loop-recording files) and turns every trip into a
:class:`~egovid.dashcam.ingest.records.DriveInput` for the staged ingest: its files in order
(decoded back to back as one drive), its GPS track (the files' own fixes joined, or the shared
log), its UTC start, and a :class:`FleetRecord` that the ingest's commit writes in the same
transaction (kind, camera, lock, clock, the files and their gaps, the GPS track for ``find`` and
the map, colour tags, the audio/telemetry blob, the files' content digests, and the readings the
car recorded in its video: a Tesla's per-frame speed, acceleration, steering …,
:mod:`egovid.dashcam.archive.readings`). A trip that continues
an archived drive (its first part is that drive's last file: :mod:`egovid.dashcam.ingest.attach`)
becomes one :class:`AppendRecord` per new file instead, each ingested and committed on its own
(one catalogue transaction per file) onto the end of that drive. The audio and telemetry are archived
(:mod:`egovid.dashcam.codec.streams`) into the blob store before the ingest, like its bitstreams: a
failed ingest leaves at most an unreferenced blob for ``gc``.
"""

from __future__ import annotations

import datetime as dt
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from egovid.core.errors import EgovidError
from egovid.dashcam.archive import readings as readings_table
from egovid.dashcam.archive.catalogue import Catalogue
from egovid.dashcam.archive.fleetstore import DriveMeta, DrivePart, FleetStore
from egovid.dashcam.archive.identity import ALREADY_IN
from egovid.dashcam.archive.readings import DriveReadings, join
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.codec.streams import archive_streams, concat_streams
from egovid.dashcam.ingest.attach import DriveTail
from egovid.dashcam.ingest.records import DriveInput, VideoProbe
from egovid.dashcam.ingest.sources import FileSource, IngestPlan
from egovid.dashcam.readings import from_tesla
from egovid.dashcam.route.tracks import GpsTrack, finish_track
from egovid.dashcam.route.trips import Trip


@dataclass
class FleetRecord:
    """The fleet rows of a drive, written by the ingest's commit (picklable: it travels with the
    drive to a Dask worker). ``track``: (t, lat, lon) of the fixes over the drive."""

    meta: DriveMeta
    parts: list[DrivePart]
    track: tuple[np.ndarray, np.ndarray, np.ndarray]
    track_source: str = ""
    files: list[FileRow] = field(default_factory=list)
    unique: bool = True  # False: the user named the drive, a second copy of known files is wanted
    primary: str | None = None  # a channel: the name of the drive it is a camera of
    readings: DriveReadings | None = None

    def commit(self, cat: Catalogue, drive_id: int) -> None:
        self.meta.drive_id = drive_id
        store = FleetStore(cat)
        store.add_drive(self.meta, self.parts, self.track, self.track_source)
        _record_files(store, drive_id, self.files, self.unique)
        if self.primary is not None:
            main = cat.drive(self.primary)
            if main is None or store.meta(main.id).state != "live" or store.primary_of(main.id) != main.id:
                raise EgovidError(f"drive {self.primary!r}, whose {self.meta.channel} camera this is, is not in the "
                                  "archive", "ingest its main camera's files with it")  # fmt: skip
            store.add_channel(drive_id, main.id, self.meta.channel)
        if self.readings is not None:
            readings_table.put(cat, drive_id, self.readings)


@dataclass(frozen=True)
class FileRow:
    """A file of a drive by content: its part, SHA-256 and bytes, name (a label) and camera."""

    part: int
    sha256: str
    size: int
    name: str
    channel: str
    sample: str | None = None  # sampled digest (egovid.dashcam.archive.identity)


def _record_files(store: FleetStore, drive_id: int, files: list[FileRow], unique: bool = True) -> None:
    """The files' digests, inside the commit's transaction; a file another ingest committed
    meanwhile (the same card synced twice at once) makes the commit fail, nothing written
    (``unique`` False: a copy the user asked for)."""
    for f in files:
        if unique and any(k.drive_id is not None for k in store.known_files(f.sha256, f.size)):
            raise EgovidError(f"{f.name} is {ALREADY_IN} (another ingest added it meanwhile)", "nothing to do")
        store.record_file(drive_id, f.part, f.sha256, f.size, f.name, f.channel, f.sample)


@dataclass
class AppendRecord:
    """The fleet rows of one file appended to an archived drive, written by that file's commit:
    its part, its GPS fixes (t, lat, lon), the drive's audio/telemetry blob now (blob, bytes,
    info; None: unchanged), its digest and its recorded readings (on the drive's clock)."""

    part: DrivePart
    track: tuple[np.ndarray, np.ndarray, np.ndarray]
    streams: tuple[str | None, int, dict] | None
    files: list[FileRow] = field(default_factory=list)
    readings: DriveReadings | None = None

    def commit(self, cat: Catalogue, drive_id: int) -> None:
        store = FleetStore(cat)
        store.append_part(drive_id, self.part, self.track, self.streams)
        _record_files(store, drive_id, self.files)
        readings_table.append(cat, drive_id, self.readings)


@dataclass
class PreparedDrive:
    """A trip ready for the staged ingest, and what the user is told about it."""

    name: str
    trip: Trip
    sources: list[FileSource]
    start_utc: float
    track: GpsTrack
    record: FleetRecord | AppendRecord
    notes: list[str] = field(default_factory=list)
    append: DriveTail | None = None  # the archived drive this file is appended to
    append_at: int = 0  # its first frame's index in that drive
    channel_of: str | None = None  # a channel: the drive it is a camera of

    def describe(self) -> str:
        """What the console says about the drive besides the ingest's figures."""
        if self.append is not None:
            return f" appended to drive {self.name!r} at frame {self.append_at} ({self.sources[0].path.name}),"
        if self.channel_of is not None:
            return f" {self.record.meta.channel} camera of drive {self.channel_of!r},"
        kind = (
            "" if self.trip.kind == "drive" else f" {self.trip.kind}{' (locked)' if self.record.meta.locked else ''},"
        )
        gaps = ", ".join(f"{g:.1f}" for g in self.trip.gaps)
        files = f" {len(self.sources)} files (gaps {gaps} s)," if len(self.sources) > 1 else ""
        return f"{kind}{files} starting {self.record.meta.clock['start']} ({self.record.meta.clock['source']}),"

    def summary(self) -> dict:
        """The fleet side of the drive's JSON report."""
        if self.append is not None:
            return {"kind": "drive", "appended_to": self.name, "at_frame": self.append_at,
                    "files": [str(s.path.resolve()) for s in self.sources], "gaps_s": [self.trip.parts[0].gap_before],
                    "notes": self.notes}  # fmt: skip
        m = self.record.meta
        return {"kind": self.trip.kind, "camera": m.channel, "channel_of": self.channel_of,
                "files": [str(s.path.resolve()) for s in self.sources],
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
    return finish_track(t[order], *cols, "; ".join(sorted({x.source for x in tracks})), {})


def prepare(
    archive: Archive,
    plan: IngestPlan,
    *,
    name: str | None = None,
    lock_events: bool = True,
) -> list[PreparedDrive]:
    """The drives of an ingest plan, with their audio/telemetry already in the blob store.

    A trip of another camera's files whose first file was recorded with a main camera's file
    (``plan.heads``) becomes a *channel* of that file's drive (made now, or archived before):
    named ``DRIVE~CHANNEL``, hidden from the lists, tied to its drive at commit (it then waits for
    that drive's commit). Where the drive has that channel already (or is unknown), the trip is a
    drive of its own, as files of a one-camera dashcam are.

    An archive made without the fleet tables (``Archive.create`` without ``setup``) gets them here,
    before any drive is committed: made inside a commit, they would list the drive being added
    as an older one."""
    store = FleetStore(archive.catalogue)
    taken = {d.name for d in archive.catalogue.drives()}
    channel_trips = [t for t in plan.trips.trips if _head_of(plan, t) is not None]
    mains = [t for t in plan.trips.trips if _head_of(plan, t) is None]
    if name is not None and len(mains) > 1:
        raise EgovidError(f"--name {name!r} names one drive, but the inputs make {len(mains)}",
                          "leave --name out: each drive is named after its first file")  # fmt: skip
    out: list[PreparedDrive] = []
    drive_of: dict[Path, str] = {}  # file -> the name of the drive it becomes (for the channels)
    for trip in mains:
        tail = plan.tails.get(trip.parts[0].file.path)
        if tail is not None:
            if name is not None:
                raise EgovidError(f"--name {name!r}: the files continue drive {tail.name!r}", "leave --name out")
            out += _prepare_append(archive, tail, trip, [plan.sources[p.file.path] for p in trip.parts[1:]])
            drive_of.update((p.file.path, tail.name) for p in trip.parts[1:])
            continue
        srcs = [plan.sources[p.file.path] for p in trip.parts]
        nm = _new_name(archive, store, plan, trip, srcs, taken, name)
        if nm is None:
            continue
        out.append(_prepare_trip(archive, nm, trip, srcs, lock_events, unique=name is None))
        drive_of.update((p.file.path, nm) for p in trip.parts)
    for trip in channel_trips:
        head = _head_of(plan, trip)
        srcs = [plan.sources[p.file.path] for p in trip.parts]
        known = plan.known.get(head)
        primary = drive_of.get(head) or (known.drive_name if known is not None else None)
        nm = f"{primary}~{srcs[0].channel}" if primary else None
        if nm is None or nm in taken:  # no drive to join, or it has this camera already
            nm = _new_name(archive, store, plan, trip, srcs, taken, None)
            if nm is not None:
                out.append(_prepare_trip(archive, nm, trip, srcs, lock_events))
            continue
        taken.add(nm)
        p = _prepare_trip(archive, nm, trip, srcs, lock_events)
        p.record.primary = primary
        p.channel_of = primary
        out.append(p)
    return out


def _head_of(plan: IngestPlan, trip: Trip) -> Path | None:
    """The main camera's file a new trip of another camera was recorded with (None: the trip is
    a drive of its own, or it continues an archived drive)."""
    first = trip.parts[0].file.path
    return None if first in plan.tails else plan.heads.get(first)


def _new_name(
    archive: Archive,
    store: FleetStore,
    plan: IngestPlan,
    trip: Trip,
    srcs: list[FileSource],
    taken: set[str],
    name: str | None,
) -> str | None:
    """The name of a new drive (``name``, else its first file's stem; another card's file of the
    same name gets its digest's start appended), added to ``taken``; None: the trip is a drive
    ingested before files were known by content (recorded in ``plan.skipped``)."""
    nm = name or trip.parts[0].file.path.stem
    if nm in taken:
        other = archive.catalogue.drive(nm)
        if name is not None or srcs[0].digest is None:
            raise EgovidError(f"a drive named {nm!r} is already in the archive", "pass --name to choose another")
        if other is not None and not store.has_digests(other.id):
            # a drive ingested before files were known by content: its name is all we know
            plan.skipped.append((trip.parts[0].file.path, f"{ALREADY_IN} as drive {nm!r}"))
            return None
        nm = f"{nm}-{srcs[0].digest.short[:8]}"  # another file of the same name (another card)
        if nm in taken:
            raise EgovidError(f"a drive named {nm!r} is already in the archive", "pass --name to choose another")
    taken.add(nm)
    return nm


def _file_rows(srcs: list[FileSource], first_part: int = 0) -> list[FileRow]:
    return [FileRow(first_part + i, s.digest.sha256, s.digest.size, s.path.name, s.channel, s.digest.sample)
            for i, s in enumerate(srcs) if s.digest is not None]  # fmt: skip


def _fixes(srcs: list[FileSource], start: float, end: float) -> tuple[GpsTrack, tuple]:
    """The files' joined track and its fixes over [start, end] UTC seconds (±5 s)."""
    track = _joined_track(srcs)
    inside = (track.t >= start - 5) & (track.t <= end + 5)
    return track, (track.t[inside], track.lat[inside], track.lon[inside])


def _prepare_append(archive: Archive, tail: DriveTail, trip: Trip, srcs: list[FileSource]) -> list[PreparedDrive]:
    """New loop files of an archived drive, each made an append of its own (in order): its part
    (frames after the drive's, or the previous file's), its fixes, and the drive's audio/telemetry
    blob with the file's joined on (stored now; the commit points the drive at it)."""
    out = []
    at, part_no = tail.frames, tail.parts
    streams = archive.blobs.get(tail.streams_blob) if tail.streams_blob else None
    info = FleetStore(archive.catalogue).meta(tail.drive_id).streams_info
    for p, s in zip(trip.parts[1:], srcs, strict=True):
        n = len(s.times)
        if s.info.fps != tail.fps and abs(s.info.fps - tail.fps) > 0.01 * tail.fps:  # plan_trips checked it
            raise EgovidError(f"{s.path.name} does not continue drive {tail.name!r}", "ingest it with --no-join")
        part = DrivePart(part_no, str(s.path.resolve()), at, at + n, float(p.start_utc), float(p.gap_before))
        own, own_info = archive_streams([(s.path, 0.0, n / tail.fps)])
        new = None
        if own is not None:
            streams = concat_streams(streams, own, at / tail.fps)
            info = info if info.get("audio") or info.get("telemetry") else own_info.to_dict()
            new = (archive.blobs.put(streams), len(streams), info)
        track, fixes = _fixes([s], float(p.start_utc), float(p.start_utc) + s.duration)
        rec = AppendRecord(part, fixes, new, _file_rows([s], part_no), _readings([(s, at / tail.fps, p.start_utc)]))
        notes = list(s.clock.notes) + [f"not archived: {x}" for x in own_info.skipped]
        one = Trip("drive", [p])
        out.append(PreparedDrive(tail.name, one, [s], float(p.start_utc), track, rec, notes, tail, at))
        at += n
        part_no += 1
    return out


def _readings(placed: list[tuple[FileSource, float, float]]) -> DriveReadings | None:
    """The readings the files recorded (Tesla SEI), joined on the drive's clock: ``placed`` holds
    each file with where its first frame lands (seconds into the drive) and its UTC start."""
    out = None
    for s, offset, start_utc in placed:
        if s.telemetry is not None and len(s.telemetry):
            out = join(out, from_tesla(s.telemetry, float(offset), float(start_utc)))
    return out


def _prepare_trip(
    archive: Archive, name: str, trip: Trip, srcs: list[FileSource], lock_events: bool, *, unique: bool = True
) -> PreparedDrive:
    """One trip made a drive: its files' frame ranges, its audio/telemetry blob (stored now), its
    GPS track and its fleet rows."""
    start = float(trip.parts[0].start_utc)
    fps = srcs[0].info.fps
    parts, f = [], 0
    media = []
    placed = []
    for i, (p, s) in enumerate(zip(trip.parts, srcs, strict=True)):
        n = len(s.times)
        parts.append(DrivePart(i, str(s.path.resolve()), f, f + n, float(p.start_utc), float(p.gap_before)))
        media.append((s.path, f / fps, n / fps))
        placed.append((s, f / fps, p.start_utc))
        f += n
    blob, info = archive_streams(media)
    sha = archive.blobs.put(blob) if blob is not None else None
    track, fixes = _fixes(srcs, start, float(trip.parts[-1].start_utc + srcs[-1].duration))
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
    rec = FleetRecord(meta, parts, fixes, track.source, _file_rows(srcs), unique, readings=_readings(placed))
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
        append_at=p.append_at if p.append is not None else None,
        channel=p.append.channel if p.append is not None else p.record.meta.channel,
    )


def drive_probe(p: PreparedDrive) -> VideoProbe:
    """Stage *probe* of a prepared drive from what :func:`~egovid.dashcam.ingest.sources.examine`
    found in its files (each demuxed once): the first file's description, the frame times of
    every file on the trip's clock (seconds from the first frame, the gaps between files kept)
    and the trip's UTC start."""
    starts = [float(x.start_utc) for x in p.trip.parts]
    times = np.concatenate([s.times + (t - starts[0]) for s, t in zip(p.sources, starts, strict=True)])
    return VideoProbe(p.sources[0].path, p.sources[0].info, times, p.start_utc)
