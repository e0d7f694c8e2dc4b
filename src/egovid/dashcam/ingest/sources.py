"""What an ingest is given, looked at before any work: each file's video, GPS and clock, and the
drives (trips) they make.

For every file :func:`examine` finds:

* its GPS: ``--gps`` (one log may cover many files; a file of a batch it does not cover keeps its
  own, below), else the file beside it with the same name
  (.gpx/.nmea/.csv), else the video's own (:mod:`egovid.dashcam.route.embedded`), else another log in
  its folder that its camera clock puts it in (one log per drive, beside the drive's first file);
  the video's own GPS is read even when a log is given, since its GPS time is the best clock there is;
* its clock (:mod:`egovid.dashcam.route.clock`): GPS time, else the camera clock checked against the log;
* its kind (drive, event, parking) and camera (front, rear, …) from its folder and name.

:func:`plan_ingest` first recognises each file by its content (:mod:`egovid.dashcam.archive.identity`:
a sampled digest, the full one for a file it does not recognise) and leaves out, unexamined, the
files the archive holds already (a card synced again costs the reading of a few MiB per file).
A file of another camera of a multi-camera dashcam
(:mod:`egovid.dashcam.route.channels`: the rear file of the same moment as a front file) is a
*companion*: it takes the clock and GPS of the primary camera's file of its moment (in this
ingest, or archived before), so the channels of a drive are in step; it is examined on its own
only when no such file exists. Then the files are grouped into trips
(:mod:`egovid.dashcam.route.trips`); files that cannot be used are listed with the reason.
Nothing is decoded here but the first frame of each file (``probe``) and its packet times
(core.video.frame_times); both travel with the drive to the stages
(:func:`~egovid.dashcam.ingest.fleet.drive_probe`), so each file is demuxed once per ingest.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from egovid.core.camera.tesla import TeslaTelemetry, read_tesla_telemetry
from egovid.core.errors import EgovidError
from egovid.core.times import creation_time_utc
from egovid.core.video import VideoInfo, frame_times, probe
from egovid.dashcam.archive.fleetstore import KnownFile
from egovid.dashcam.archive.identity import FileDigest, already_in, file_digest
from egovid.dashcam.ingest.stages import check_frame_size
from egovid.dashcam.route.camera_gps import tesla_rows
from egovid.dashcam.route.channels import channel_rank, file_camera
from egovid.dashcam.route.clock import VideoClock, name_time, resolve_clock
from egovid.dashcam.route.embedded import EmbeddedGps, from_rows, read_embedded_gps
from egovid.dashcam.route.tracks import GPS_EXTENSIONS, GpsTrack, gps_beside, read_track
from egovid.dashcam.route.trips import FileInfo, Trip, TripPlan, expand_inputs, file_channel, file_kind, plan_trips


@dataclass
class ClockOptions:
    """How the user helps the clock: ``start`` (UTC seconds of the first frame; only for a single
    file), ``tz_offset_h`` (hours the camera clock is ahead of UTC), ``gps_offset`` (seconds added to
    every start)."""

    start: float | None = None
    tz_offset_h: float | None = None
    gps_offset: float = 0.0


@dataclass
class FileSource:
    """One input file, examined: video description, frame times (seconds from its first frame),
    the GPS track that covers it and where it came from, the clock, kind and camera."""

    path: Path
    info: VideoInfo
    times: np.ndarray
    track: GpsTrack
    gps_source: str
    clock: VideoClock
    kind: str
    channel: str
    embedded: EmbeddedGps | None = None
    digest: FileDigest | None = None
    telemetry: TeslaTelemetry | None = None  # a Tesla clip's per-frame readings (kept by the archive)

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the end of the last (one frame period after its start)."""
        return span(self.times, self.info.fps)

    def file_info(self) -> FileInfo:
        """The file as the trip planner sees it (a clock read from creation_time or a file name
        counts whole seconds)."""
        coarse = not self.clock.source.startswith(("GPS", "--start"))
        return FileInfo(self.path, self.clock.start_utc, self.duration, self.info.width, self.info.height,
                        self.info.fps, self.kind, self.channel, 1.0 if coarse else 0.0)  # fmt: skip


def _beside(video: Path) -> Path | None:
    try:
        return gps_beside(video)
    except EgovidError:
        return None


@functools.lru_cache(maxsize=64)
def _read_log(path: Path, mtime: float) -> GpsTrack | None:
    try:
        return read_track(path)
    except EgovidError:
        return None


def _folder_log(path: Path, info: VideoInfo, duration: float, clock: ClockOptions) -> tuple[GpsTrack, str] | None:
    """A GPS log in the video's folder that covers it, for a video with no GPS of its own: loggers
    and some cameras write one log per drive, named after its first file, so the later loop files of
    the drive have none beside them. A log counts only where the video's own clock (creation_time,
    file name, ``--tz-offset``) puts the video inside it (:func:`resolve_clock`'s coverage check)."""
    exts = {e.lower() for e in GPS_EXTENSIONS}
    created, named = creation_time_utc(info.creation_time), name_time(path.name)
    if created is None and named is None:
        return None  # nothing would place the video inside another file's log
    cands = sorted(f for f in path.parent.iterdir() if f.is_file() and f.suffix.lower() in exts)
    for f in cands:
        track = _read_log(f, f.stat().st_mtime)
        if track is None:
            continue
        try:
            resolve_clock(duration, video_name=path.name, track=track, creation_time=created, file_time=named,
                          tz_offset_h=clock.tz_offset_h, gps_offset=clock.gps_offset)  # fmt: skip
        except EgovidError:
            continue
        return track, str(f)
    return None


def _own_gps(path: Path, embedded: EmbeddedGps | None) -> tuple[GpsTrack, str] | None:
    """The file's own GPS and where it came from: the log beside it, else the video's embedded
    fixes; None when it has neither."""
    side = _beside(path)
    if side is not None:
        return read_track(side), str(side)
    if embedded is not None:
        return embedded.track, f"embedded: {embedded.reader}"
    return None


def span(times: np.ndarray, fps: float) -> float:
    """Seconds from a video's first frame to the end of its last (one frame period after its
    start), given its frame times (seconds) and frame rate."""
    return float(times[-1]) + 1.0 / max(fps, 1e-6) if len(times) else 0.0


def examine(video: str | os.PathLike, log: GpsTrack | None, clock: ClockOptions, *, batch: bool = False) -> FileSource:
    """Look at one file (see the module docstring); raises :class:`EgovidError` naming what is
    missing (a video that does not decode, no GPS anywhere: ``--gps``, a clock no GPS confirms).
    ``batch``: the file is one of many sharing ``log``; where the log does not cover it, its own GPS
    (beside it, or in the video) is used instead of giving up."""
    path = Path(video)
    info = probe(path)
    times = frame_times(path)
    check_frame_size(path, info)
    embedded = read_embedded_gps(path)
    tesla = read_tesla_telemetry(path) if embedded is None else None
    if tesla is not None:
        embedded = _tesla_gps(path, info, clock, tesla)
    duration = span(times, info.fps)
    found = (log, "--gps") if log is not None else _own_gps(path, embedded) or _folder_log(path, info, duration, clock)
    if found is None:
        raise EgovidError(
            f"no GPS for {path.name}: none embedded in the video (NMEA text track, GoPro GPMF, Tesla SEI, "
            f"ExifTool) and no "
            f"{path.stem}.gpx, .nmea or .csv beside it",
            "give the drive's GPS log with --gps FILE",
        )
    track, source = found

    def place(log_track: GpsTrack) -> VideoClock:
        return resolve_clock(
            duration,
            video_name=path.name,
            start=clock.start,
            embedded=embedded,
            track=log_track,
            creation_time=creation_time_utc(info.creation_time),
            file_time=name_time(path.name),
            tz_offset_h=clock.tz_offset_h,
            gps_offset=clock.gps_offset,
        )

    try:
        vc = place(track)
    except EgovidError:
        own = _own_gps(path, embedded) if batch and source == "--gps" else None
        if own is None:
            raise
        track, source = own
        vc = place(track)
    return FileSource(path, info, times, track, source, vc, file_kind(path), file_channel(path), embedded,
                      telemetry=tesla)  # fmt: skip


def _tesla_gps(path: Path, info: VideoInfo, clock: ClockOptions, tel: TeslaTelemetry) -> EmbeddedGps | None:
    """A Tesla clip's per-frame SEI positions (firmware 2025.44.25+; ``tel``, read from its SEI).
    Its messages carry no time of day: the clip's start is the time in its file name (the car's
    local clock; ``--tz-offset`` applies), else the container's creation time; None without either."""
    start = name_time(path.name)
    if start is None:
        start = creation_time_utc(info.creation_time)
    if start is None:
        return None
    start -= (clock.tz_offset_h or 0.0) * 3600.0
    return from_rows(tesla_rows(tel, start))


class ArchivedFiles(Protocol):
    """What the examination asks the archive (:class:`~egovid.dashcam.ingest.attach.Archived`):
    whether it holds a file already (by content; with the file's full digest where it was taken),
    for such a file its UTC start and its drive's
    GPS track (a companion file recorded with it takes both), and the last files of archived
    drives that end between two UTC times (new loop files may continue them)."""

    def identify(self, path: Path) -> tuple[KnownFile | None, FileDigest | None]: ...

    def clock_of(self, known: KnownFile) -> tuple[float, GpsTrack] | None: ...

    def tails(self, t0: float, t1: float) -> dict[Path, tuple[FileInfo, object]]: ...


def examine_companion(
    video: str | os.PathLike, start_utc: float, track: GpsTrack, source: str, label: str
) -> FileSource:
    """Look at a file of another camera recorded with a primary camera's file: its video and frame
    times, with the primary's clock (``start_utc``, UTC seconds; ``source``: how the primary's was
    set) and GPS ``track`` (``label``: the primary's file, for the catalogue)."""
    path = Path(video)
    info = probe(path)
    times = frame_times(path)
    check_frame_size(path, info)
    clock = VideoClock(float(start_utc), f"{source}, recorded with {label}")
    return FileSource(path, info, times, track, f"with {label}", clock, file_kind(path), file_camera(path).channel)


@dataclass
class IngestPlan:
    """The drives to ingest (trips of examined files), the files left out with the reason, the
    files the archive holds already (by content: path -> what it is there), and the archived
    drives new files continue: a trip whose first part is such a drive's last file (its path a
    key of ``tails``, :func:`~egovid.dashcam.ingest.attach.tail_path`) is appended to it.
    ``heads``: each file of another camera -> the main camera's file of its moment (among the
    inputs, examined now or archived before): its trip becomes a channel of that file's drive."""

    trips: TripPlan
    sources: dict[Path, FileSource] = field(default_factory=dict)
    known: dict[Path, KnownFile] = field(default_factory=dict)
    tails: dict[Path, object] = field(default_factory=dict)
    heads: dict[Path, Path] = field(default_factory=dict)

    @property
    def skipped(self) -> list[tuple[Path, str]]:
        return self.trips.skipped


def _slots(files: list[Path]) -> dict[Path, Path]:
    """Companion file -> the primary camera's file of its moment (same slot and kind, the best
    channel, :func:`~egovid.dashcam.route.channels.channel_rank`), among ``files``."""
    groups: dict[tuple[str, str], list[Path]] = {}
    for f in files:
        cam = file_camera(f)
        if cam.rule is not None:
            groups.setdefault((cam.slot, file_kind(f)), []).append(f)
    out: dict[Path, Path] = {}
    for members in groups.values():
        ranked = sorted(members, key=lambda f: (channel_rank(file_camera(f).channel), f.name.lower()))
        head = ranked[0]
        for f in ranked[1:]:
            if file_camera(f).channel != file_camera(head).channel:
                out[f] = head
    return out


def plan_ingest(
    inputs: Sequence[str | os.PathLike],
    *,
    gps: str | os.PathLike | GpsTrack | None = None,
    clock: ClockOptions | None = None,
    join: bool = True,
    max_gap: float = 10.0,
    on_file: Callable[[int, int], None] | None = None,
    archived: ArchivedFiles | None = None,
) -> IngestPlan:
    """Examine the inputs (files, folders searched recursively) and group them into drives.
    ``gps``: one log for all of them (a file, or the track already read); ``archived``: the
    archive's answers (files it holds already are left out unexamined, and companions of those
    take their clock).

    With one input file, any problem with it is an error (one line, exit status 2); with several,
    a file that cannot be used is skipped and listed with the reason, and it is an error only when
    none can be used (files the archive holds already are no error: the plan is then empty).
    ``--start`` needs exactly one file."""
    clock = clock or ClockOptions()
    files = expand_inputs(inputs)
    if not files:
        raise EgovidError(f"no videos in {', '.join(map(str, inputs))}", "give dashcam video files or folders of them")
    if clock.start is not None and len(files) > 1:
        raise EgovidError(
            "--start gives the start of one video, but several were given",
            "use --tz-offset HOURS for a camera clock set to local time, or ingest the file alone",
        )
    log = gps if isinstance(gps, GpsTrack) or gps is None else read_track(gps)
    single = len(files) == 1 and not Path(inputs[0]).is_dir()
    sources: dict[Path, FileSource] = {}
    skipped: list[tuple[Path, str]] = []
    known: dict[Path, KnownFile] = {}
    digests: dict[Path, FileDigest] = {}
    for f in files:
        if archived is None:
            continue
        hit, digest = archived.identify(f)
        if digest is not None:
            digests[f] = digest
        if hit is not None:
            if single:  # one file named: its problems are still errors (checked before "nothing to do")
                examine(f, log, clock, batch=False)
            known[f] = hit
            skipped.append((f, already_in(hit)))
    todo = [f for f in files if f not in known]
    primary_of = _slots(files)
    # primaries first: their companions take their clock
    order = sorted(todo, key=lambda f: f in primary_of)
    for k, f in enumerate(order):
        try:
            src = _companion(f, primary_of.get(f), sources, known, archived)
            sources[f] = src if src is not None else examine(f, log, clock, batch=not single)
            sources[f].digest = digests[f] if f in digests else file_digest(f) if archived is not None else None
        except EgovidError as e:
            if single:
                raise
            skipped.append((f, e.one_line()))
        if on_file:
            on_file(k + 1, len(todo))
    if not sources and not known:
        first = skipped[0][1] if skipped else "nothing to ingest"
        raise EgovidError(
            f"none of the {len(files)} videos can be ingested (the first: {first})",
            "ingest the files one by one to see each reason; give GPS logs with --gps FILE where the videos have none",
        )
    infos = [s.file_info() for s in sources.values()]
    tails: dict[Path, tuple[FileInfo, object]] = {}
    timed = [i for i in infos if i.start_utc is not None]
    if archived is not None and join and timed:
        t0 = min(i.start_utc for i in timed) - max_gap - 1.0
        tails = archived.tails(t0, max(i.start_utc + i.duration for i in timed))
    trips = plan_trips([*infos, *(i for i, _ in tails.values())], skipped=skipped, max_gap=max_gap, join=join)
    trips.trips = [t for trip in trips.trips for t in _cut_at_tails(trip, tails)]
    used = {t.parts[0].file.path for t in trips.trips if t.parts[0].file.path in tails}
    heads = {
        f: h for f, h in primary_of.items() if f in sources and sources[f].gps_source.startswith("with ")
    }  # examined as its companion
    return IngestPlan(trips, sources, known, {p: tails[p][1] for p in used}, heads)


def _cut_at_tails(trip: Trip, tails: dict) -> list[Trip]:
    """A trip cut before each archived drive's last file in it: the files before it are a drive of
    their own, those after it continue that drive; a tail alone is no trip."""
    out: list[Trip] = []
    for part in trip.parts:
        if part.file.path in tails or not out:
            out.append(Trip(trip.kind, [part]))
        else:
            out[-1].parts.append(part)
    return [t for t in out if not (len(t.parts) == 1 and t.parts[0].file.path in tails)]


def _companion(
    f: Path,
    head: Path | None,
    sources: dict[Path, FileSource],
    known: dict[Path, KnownFile],
    archived: ArchivedFiles | None,
) -> FileSource | None:
    """The companion examination of ``f`` when the primary camera's file of its moment (``head``)
    was examined in this ingest or is in the archive; None: examine ``f`` on its own."""
    if head is None:
        return None
    if head in sources:
        p = sources[head]
        return examine_companion(f, p.clock.start_utc, p.track, p.clock.source, p.path.name)
    if head in known and archived is not None:
        found = archived.clock_of(known[head])
        if found is not None:
            return examine_companion(f, found[0], found[1], "the archive", known[head].name)
    return None
