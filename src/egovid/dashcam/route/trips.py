"""Trips from loop recordings: many 1-5 minute files become the drives they were.

Dashcams cut a drive into files of a few minutes ("loop recording") and keep event files
(a bump, a button press) and parking-mode files apart. :func:`plan_trips` takes the files of an
ingest, each with its start time and kind, and groups them:

* files are ordered by their start time (the clock of :mod:`egovid.dashcam.route.clock`: GPS time, else
  the checked camera clock); files without one follow in file-name order;
* consecutive normal files of the same camera (front, rear, …) with the same frame size and rate,
  where each starts at most ``max_gap`` seconds after the previous one ended (and not before it
  ended, less ``overlap`` seconds), are one trip; the gaps between them are recorded;
* event and parking files are drives of their own kind, never joined with others;
* files that cannot be used are listed with the reason, never dropped silently.

The kind of a file comes from the folder and file names the cameras use (:func:`file_kind`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from egovid.core.video import Frame, iter_frames
from egovid.dashcam.route.channels import file_camera
from egovid.dashcam.route.inputs import VIDEO_SUFFIXES, expand_inputs  # noqa: F401 (the names importers use)

KINDS = ("drive", "event", "parking")
MAX_GAP_S = 10.0
OVERLAP_S = 1.0

# Folder names (any level) that cameras and their apps give protected and parking recordings:
# Viofo/Novatek RO, Nextbase Protected, Garmin Saved, Tesla SavedClips/SentryClips, Thinkware evt_rec …
_EVENT_DIRS = {
    "event",
    "events",
    "evt",
    "evt_rec",
    "ro",
    "protected",
    "locked",
    "lock",
    "saved",
    "savedclips",
    "emergency",
    "emer",
    "manual",
    "manual_rec",
    "incident",
    "sos",
    "crash",
}
_PARKING_DIRS = {
    "parking",
    "parking_rec",
    "park",
    "sentryclips",
    "sentry",
    "motion_timelapse_rec",
    "motion",
    "timelapse",
}
# File names: BlackVue 20240131_235959_EF.mp4 (N normal, E event, P parking, M manual; F/R/I camera),
# Thinkware EVT_/PARK_/MAN_ prefixes, Viofo/Novatek …_0001PF.MP4 / …_0001EF.MP4 suffix letters,
# 70mai NO/EV/PA prefixes (NO20240131-235959-000123F.MP4).
_BLACKVUE = re.compile(r"_(?P<k>[NEPMIOABTXG])[FRIO]?(?:[SL])?$", re.IGNORECASE)
_NOVATEK = re.compile(r"^\d{4}_?\d{4}_?\d{6}_\d+(?P<k>[EP])[FRI]$", re.IGNORECASE)
_70MAI = re.compile(r"^(?P<k>NO|EV|PA)\d{8}-\d{6}", re.IGNORECASE)
_EVENT_NAME = re.compile(r"^(evt|event|emer|man|manual|sos|lock)[_\-]|[_\-](evt|event|emer|lock(ed)?)([_\-.]|$)", re.I)
_PARK_NAME = re.compile(r"^(park|parking|pk)[_\-]|[_\-](park|parking)([_\-.]|$)", re.IGNORECASE)


def file_kind(path: str | os.PathLike) -> str:
    """``drive``, ``event`` or ``parking``, from the folder and file names dashcams use."""
    p = Path(path)
    for part in (x.lower() for x in p.parent.parts[-3:]):
        if part in _EVENT_DIRS:
            return "event"
        if part in _PARKING_DIRS:
            return "parking"
    stem = p.stem
    if _EVENT_NAME.search(stem):
        return "event"
    if _PARK_NAME.search(stem):
        return "parking"
    m = _BLACKVUE.search(stem)
    if m and re.match(r"^\d{8}_\d{6}_", stem):
        return {"E": "event", "M": "event", "P": "parking", "I": "event"}.get(m.group("k").upper(), "drive")
    m = _NOVATEK.match(stem) or _70MAI.match(stem)
    if m:
        return {"E": "event", "EV": "event", "P": "parking", "PA": "parking"}.get(m.group("k").upper(), "drive")
    return "drive"


def file_channel(path: str | os.PathLike) -> str:
    """The camera of a multi-camera dashcam that wrote the file (``front``, ``rear``, ``interior``,
    Tesla's ``left_repeater`` …), from its name (:mod:`egovid.dashcam.route.channels`); ``front``
    when the name does not say. Files of different cameras are never joined into one trip (they
    become the channels of one drive: :func:`egovid.dashcam.ingest.fleet.prepare`)."""
    return file_camera(path).channel


@dataclass(frozen=True)
class FileInfo:
    """One input file as the planner sees it: its start (UTC seconds, None if unknown), duration
    (seconds), frame size and rate, and kind."""

    path: Path
    start_utc: float | None
    duration: float
    width: int
    height: int
    fps: float
    kind: str = "drive"
    channel: str = "front"
    resolution: float = 0.0  # seconds: 1 for a clock read from creation_time or a file name


@dataclass
class TripPart:
    """A file within a trip: ``gap_before`` seconds between the end of the previous file and its
    start (0 for the first), and its start on the trip's clock (UTC seconds). A file that seems to
    start before the previous one ended (by up to ``overlap``), or after a gap shorter than its
    clock can tell (creation_time and file names count whole seconds), continues it directly."""

    file: FileInfo
    gap_before: float = 0.0
    start_utc: float | None = None

    def __post_init__(self) -> None:
        if self.start_utc is None:
            self.start_utc = self.file.start_utc


@dataclass
class Trip:
    """Files that are one drive, in order, and the drive's kind."""

    kind: str
    parts: list[TripPart] = field(default_factory=list)

    @property
    def start_utc(self) -> float | None:
        return self.parts[0].file.start_utc

    @property
    def gaps(self) -> list[float]:
        """Seconds between consecutive files (one fewer than the files)."""
        return [p.gap_before for p in self.parts[1:]]


@dataclass
class TripPlan:
    trips: list[Trip]
    skipped: list[tuple[Path, str]]


def _name_key(f: FileInfo) -> str:
    return f.path.name.lower()


def plan_trips(
    files: Iterable[FileInfo],
    *,
    skipped: Iterable[tuple[Path, str]] = (),
    max_gap: float = MAX_GAP_S,
    overlap: float = OVERLAP_S,
    join: bool = True,
) -> TripPlan:
    """Group files into trips (see the module docstring). ``skipped``: files the caller already
    could not use, with the reason (they are passed through into the plan); ``join=False`` makes
    every file a drive of its own."""
    skipped = list(skipped)
    timed = sorted((f for f in files if f.start_utc is not None), key=lambda f: (f.start_utc, _name_key(f)))
    untimed = sorted((f for f in files if f.start_utc is None), key=_name_key)
    trips: list[Trip] = []
    open_trips: dict[str, Trip] = {}
    for f in [*timed, *untimed]:
        if f.kind not in KINDS:
            skipped.append((f.path, f"unknown kind {f.kind!r}"))
            continue
        if f.kind != "drive" or not join:
            trips.append(Trip(f.kind, [TripPart(f)]))
            continue
        open_trip = open_trips.get(f.channel)
        prev = open_trip.parts[-1].file if open_trip is not None else None
        if prev is not None and prev.start_utc is not None and f.start_utc is not None:
            gap = f.start_utc - (prev.start_utc + prev.duration)
            same = (prev.width, prev.height) == (f.width, f.height) and abs(prev.fps - f.fps) < 0.01 * max(f.fps, 1)
            if same and -overlap <= gap <= max_gap:
                last = open_trip.parts[-1]
                if gap < max(f.resolution, prev.resolution):
                    gap = 0.0  # within what the clocks can tell: the recording went on
                open_trip.parts.append(TripPart(f, gap, last.start_utc + prev.duration + gap))
                continue
        open_trips[f.channel] = Trip("drive", [TripPart(f)])
        trips.append(open_trips[f.channel])
    trips.sort(key=lambda t: (t.start_utc is None, t.start_utc or 0.0, _name_key(t.parts[0].file)))
    return TripPlan(trips, skipped)


def iter_trip_frames(paths: list[str | os.PathLike], **kwargs) -> Iterator[Frame]:
    """The frames of a trip's files back to back, as one video: indices continue from file to file
    (``kwargs`` go to :func:`egovid.core.video.iter_frames`, e.g. ``i420=True``). Times are those of
    each file (seconds from its own first frame)."""
    base = 0
    for p in paths:
        n = 0
        for fr in iter_frames(p, **kwargs):
            fr.index = base + fr.index
            n += 1
            yield fr
        base += n
