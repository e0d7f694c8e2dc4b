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

:func:`plan_ingest` then groups the files into trips (:mod:`egovid.dashcam.route.trips`); files that
cannot be used are listed with the reason. Nothing is decoded here but the first frame of each file
(``probe``) and its packet times (core.video.frame_times); both travel with the drive to the
stages (:func:`~egovid.dashcam.ingest.fleet.drive_probe`), so each file is demuxed once per ingest.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.times import creation_time_utc
from egovid.core.video import VideoInfo, frame_times, probe
from egovid.dashcam.ingest.stages import check_frame_size
from egovid.dashcam.route.clock import VideoClock, name_time, resolve_clock
from egovid.dashcam.route.embedded import EmbeddedGps, read_embedded_gps
from egovid.dashcam.route.tracks import GPS_EXTENSIONS, GpsTrack, gps_beside, read_track
from egovid.dashcam.route.trips import FileInfo, TripPlan, expand_inputs, file_channel, file_kind, plan_trips


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
    duration = span(times, info.fps)
    found = (log, "--gps") if log is not None else _own_gps(path, embedded) or _folder_log(path, info, duration, clock)
    if found is None:
        raise EgovidError(
            f"no GPS for {path.name}: none embedded in the video (ExifTool, NMEA text track) and no "
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
    return FileSource(path, info, times, track, source, vc, file_kind(path), file_channel(path), embedded)


@dataclass
class IngestPlan:
    """The drives to ingest (trips of examined files), and the files left out with the reason."""

    trips: TripPlan
    sources: dict[Path, FileSource] = field(default_factory=dict)

    @property
    def skipped(self) -> list[tuple[Path, str]]:
        return self.trips.skipped


def plan_ingest(
    inputs: Sequence[str | os.PathLike],
    *,
    gps: str | os.PathLike | GpsTrack | None = None,
    clock: ClockOptions | None = None,
    join: bool = True,
    max_gap: float = 10.0,
    on_file: Callable[[int, int], None] | None = None,
) -> IngestPlan:
    """Examine the inputs (files, folders searched recursively) and group them into drives.
    ``gps``: one log for all of them (a file, or the track already read).

    With one input file, any problem with it is an error (one line, exit status 2); with several,
    a file that cannot be used is skipped and listed with the reason, and it is an error only when
    none can be used. ``--start`` needs exactly one file."""
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
    for k, f in enumerate(files):
        try:
            sources[f] = examine(f, log, clock, batch=not single)
        except EgovidError as e:
            if single:
                raise
            skipped.append((f, e.one_line()))
        if on_file:
            on_file(k + 1, len(files))
    if not sources:
        first = skipped[0][1] if skipped else "nothing to ingest"
        raise EgovidError(
            f"none of the {len(files)} videos can be ingested (the first: {first})",
            "ingest the files one by one to see each reason; give GPS logs with --gps FILE where the videos have none",
        )
    trips = plan_trips([s.file_info() for s in sources.values()], skipped=skipped, max_gap=max_gap, join=join)
    return IngestPlan(trips, sources)
