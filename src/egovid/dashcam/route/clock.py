"""Which clock says when a video was recorded: GPS time first, the camera's clock only when checked.

Cameras get their own clocks wrong in known ways: GoPro and most dashcams write local time into
the container's ``creation_time`` (tagged as UTC), clocks reset to 2000-01-01 or drift, and file
names carry local time. GPS time is UTC. :func:`resolve_clock` picks the start of the video's first
frame, in this order:

1. ``--start`` (the user knows better);
2. the video's own GPS fixes that carry their video time (timed metadata, NMEA in a text track):
   start = median(GPS UTC − video time); the camera clock is compared with it and a difference is
   reported (a whole number of quarter hours: a time zone);
3. a GPS log without video times (a separate file, or embedded fixes without sample times): a
   candidate start must put at least ``min_cover`` of the video inside the log. Candidates, in
   order: ``creation_time`` and the time in the file name (both minus ``--tz-offset`` hours when
   given). A camera clock the log contradicts is never replaced silently: the error says how much
   of the video the log covers and names the time-zone shift that would fit (``--tz-offset``), or
   ``--start``. Only a video with no clock at all takes the first fix of a log as long as itself
   (its own log).

``gps_offset`` seconds are added to whatever start was chosen (a known lag of a GPS logger).
All times are UTC seconds since the epoch.
"""

from __future__ import annotations

import datetime as dt
import re
from dataclasses import dataclass, field
from pathlib import Path

from egovid.core.errors import EgovidError
from egovid.core.times import plausible_utc
from egovid.dashcam.route.embedded import EmbeddedGps
from egovid.dashcam.route.tracks import GpsTrack

#: Camera clock and GPS agree when within this many seconds (creation_time has 1 s resolution).
AGREE_S = 2.0
MIN_COVER = 0.8
# Dashcam file names: 2024_0131_235959 (Novatek/Viofo), 20240131_235959 (BlackVue, phones),
# 2024-01-31_23-59-59 (Tesla), REC_2024_01_31_23_59_59 (Thinkware), 20240131235959 (others).
_NAME_TIME = re.compile(
    r"(?<!\d)(20\d\d)[_\-]?([01]\d)[_\-]?([0-3]\d)[_\-T ]?([0-2]\d)[_\-:]?([0-5]\d)[_\-:]?([0-5]\d)(?!\d)"
)
# Nextbase: 240915_143027_001_FH.MP4 (two-digit year, at the start of the name).
_NAME_TIME_YY = re.compile(r"^(\d\d)([01]\d)([0-3]\d)_([0-2]\d)([0-5]\d)([0-5]\d)_")


@dataclass(frozen=True)
class VideoClock:
    """The UTC time of a video's first frame (seconds since the epoch), where it came from, and what
    was noticed on the way (e.g. a camera clock set to local time)."""

    start_utc: float
    source: str
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict:
        return {
            "start_utc": self.start_utc,
            "start": iso(self.start_utc),
            "source": self.source,
            "notes": list(self.notes),
        }


def iso(t: float) -> str:
    """UTC seconds → ``2024-01-31T23:59:59.500Z``."""
    return dt.datetime.fromtimestamp(t, dt.UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def name_time(path: str) -> float | None:
    """The recording time in a dashcam file name, read as if it were UTC (seconds; the caller
    applies ``--tz-offset``), None if the name has none. The last match wins (folders may be dated)."""
    found = None
    name = Path(path).name
    yy = _NAME_TIME_YY.match(name)
    matches = [yy] if yy and not _NAME_TIME.search(name) else list(_NAME_TIME.finditer(name))
    for m in matches:
        y, mo, d, h, mi, s = (int(g) for g in m.groups())
        y += 2000 if y < 100 else 0
        try:
            found = dt.datetime(y, mo, d, h, mi, s, tzinfo=dt.UTC).timestamp()
        except ValueError:
            continue
    return found if found is not None and plausible_utc(found) else None


def coverage(track: GpsTrack, start: float, duration: float) -> float:
    """Share (0-1) of the video [start, start + duration] inside the log's time span."""
    lo, hi = max(float(track.t[0]), start), min(float(track.t[-1]), start + duration)
    return max(0.0, hi - lo) / max(duration, 1e-6)


def zone_shifts(track: GpsTrack, start: float, duration: float, min_cover: float = MIN_COVER) -> list[float]:
    """The time-zone offsets (hours, multiples of 15 minutes, 0 < |h| ≤ 14) that would put the video
    inside the log (``start − h·3600`` covered by at least ``min_cover``), most likely first: whole
    hours, then half hours, then quarters, each nearest zero first."""
    fits = [q / 4.0 for q in range(-56, 57) if q and coverage(track, start - q * 900.0, duration) >= min_cover]
    return sorted(fits, key=lambda h: (0 if h == int(h) else 1 if 2 * h == int(2 * h) else 2, abs(h)))


def _hours(seconds: float) -> str:
    h = seconds / 3600.0
    return f"{h:+.2f} h" if abs(h) >= 0.1 else f"{seconds:+.1f} s"


def resolve_clock(
    duration: float,
    *,
    video_name: str = "the video",
    start: float | None = None,
    embedded: EmbeddedGps | None = None,
    track: GpsTrack | None = None,
    creation_time: float | None = None,
    file_time: float | None = None,
    tz_offset_h: float | None = None,
    gps_offset: float = 0.0,
    min_cover: float = MIN_COVER,
) -> VideoClock:
    """The start of the video (see the module docstring). ``duration``: seconds from the first to
    the last frame; ``track``: a GPS log given separately (``--gps``); ``embedded``: the video's own
    fixes; ``creation_time`` / ``file_time``: the camera's clock as written (UTC-tagged); raises
    :class:`EgovidError` when no clock fits the GPS."""
    if start is not None:
        return VideoClock(start + gps_offset, "--start")
    if embedded is not None and embedded.timed:
        return _gps_time_clock(embedded, creation_time, tz_offset_h, gps_offset)
    log = track if track is not None else (embedded.track if embedded is not None else None)
    if log is None:
        raise EgovidError(f"no GPS for {video_name}", "give its GPS log with --gps FILE (GPX, NMEA or CSV)")
    tz = 0.0 if tz_offset_h is None else float(tz_offset_h)
    zone_label = f" {-tz:+g} h (--tz-offset)" if tz else ""
    candidates: list[tuple[str, float]] = []
    if creation_time is not None:
        candidates.append((f"creation_time{zone_label}", creation_time - tz * 3600.0))
    if file_time is not None:
        candidates.append((f"file name time{zone_label}", file_time - tz * 3600.0))
    for label, s in candidates:
        if coverage(log, s, duration) >= min_cover:
            return VideoClock(s + gps_offset, label)
    if not candidates:
        # The video has no clock at all: nothing contradicts the log, and a log as long as the
        # video is the video's own (its first fix is the first frame).
        if abs(float(log.t[-1] - log.t[0]) - duration) <= max(5.0, 0.1 * duration):
            note = "the video has no clock: its start is the GPS log's first fix"
            return VideoClock(float(log.t[0]) + gps_offset, "GPS log start", (note,))
        raise EgovidError(
            f"{video_name} has no clock to place it in GPS log {Path(log.source).name or 'track'}",
            "give its start with --start ISO-TIME",
        )
    raise _no_clock_fits(log, *candidates[0], duration, video_name, tz, min_cover)


def _gps_time_clock(
    embedded: EmbeddedGps, creation_time: float | None, tz_offset_h: float | None, gps_offset: float
) -> VideoClock:
    """The start from the video's own timed GPS fixes, with a note where the camera clock differs."""
    notes: list[str] = []
    s = embedded.start_utc()
    if tz_offset_h is not None:
        notes.append("--tz-offset is not needed: the video's own GPS gives UTC")
    if creation_time is not None and abs(creation_time - s) > AGREE_S:
        d = creation_time - s
        zone = round(d / 900.0) / 4.0
        why = f" (time zone UTC{zone:+g}?)" if abs(d - zone * 3600) < 60 and zone else ""
        notes.append(f"the camera clock (creation_time {iso(creation_time)}) is {_hours(d)} off GPS time{why}")
    return VideoClock(s + gps_offset, f"GPS time ({embedded.reader})", tuple(notes))


def _no_clock_fits(
    log: GpsTrack, label: str, s: float, duration: float, video_name: str, tz: float, min_cover: float
) -> EgovidError:
    """The error for a camera clock (``label``, start ``s``) the log contradicts: how much of the
    video the log covers, and the time-zone shift that would fit (``--tz-offset``), if any."""
    problem = (
        f"GPS log {Path(log.source).name or 'track'} ({iso(float(log.t[0]))} to {iso(float(log.t[-1]))}) covers "
        f"{100 * coverage(log, s, duration):.0f}% of {video_name} (from {iso(s)}, its {label})"
    )
    shifts = [h + tz for h in zone_shifts(log, s, duration, min_cover)]
    if shifts:
        whole = [h for h in shifts if h == int(h)] or shifts[:1]
        more = f" (also fitting: {', '.join(f'{h:+g}' for h in whole[1:4])})" if len(whole) > 1 else ""
        fix = f"the camera clock looks like local time UTC{whole[0]:+g}: pass --tz-offset {whole[0]:g}{more}"
    else:
        fix = "give the GPS log of this drive, or its start with --start ISO-TIME (or shift with --gps-offset SECONDS)"
    return EgovidError(problem, fix)
