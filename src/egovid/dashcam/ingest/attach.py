"""What an ingest asks the archive about what it holds already: files by content, and the ends
of archived trips that new loop files may continue.

:class:`Archived` answers :func:`~egovid.dashcam.ingest.sources.plan_ingest`:

* :meth:`Archived.identify`: the file the archive ingested with these bytes (by its sampled and
  full digests, :mod:`egovid.dashcam.archive.identity`), whatever its name was; such a file is left out before it
  is examined (no probe, no decode);
* :meth:`Archived.clock_of`: the UTC start and GPS track of such a file (a file of another camera
  recorded with it takes them);
* :meth:`Archived.tails`: the last file of every live drive (kind ``drive``), as the trip planner
  sees a file (:class:`~egovid.dashcam.route.trips.FileInfo`), so that a new loop file that
  continues an archived trip joins it by the very rule that joins loop files of one ingest
  (:func:`~egovid.dashcam.route.trips.plan_trips`), and is appended to that drive.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from egovid.dashcam.archive.fleetstore import FleetStore, KnownFile
from egovid.dashcam.archive.identity import FileDigest, identify
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.route.tracks import GpsTrack, finish_track
from egovid.dashcam.route.trips import FileInfo

TAIL_PREFIX = "\x00archived drive "  # the path of a tail: no file on any disk is named so


@dataclass(frozen=True)
class DriveTail:
    """The end of an archived drive a new file may continue: its id and name, its frames so far
    (the appended file's first frame gets this index), its files (the appended file's part
    number), its frame rate, its audio/telemetry blob (None: it has none) and its camera."""

    drive_id: int
    name: str
    frames: int
    parts: int
    fps: float
    streams_blob: str | None
    channel: str = "front"


def tail_path(name: str) -> Path:
    """The planner's path of an archived drive's last file (never a real file)."""
    return Path(TAIL_PREFIX + name)


class Archived:
    """The archive's answers to the examination of an ingest's files (see the module docstring)."""

    def __init__(self, archive: Archive, *, dedup: bool = True, verify: bool = False) -> None:
        """``dedup`` False: every file is new (the user named the drive, a deliberate second copy);
        ``verify``: a file its sampled digest recognises is hashed whole and compared as well
        (``--verify-known``)."""
        self.archive = archive
        self.store = FleetStore(archive.catalogue)
        self.dedup = dedup
        self.verify = verify

    def identify(self, path: Path) -> tuple[KnownFile | None, FileDigest | None]:
        """The first file ingested with the bytes of ``path`` (None: a new file, or ``dedup`` is
        off) and the file's full digest where it was taken (see
        :func:`~egovid.dashcam.archive.identity.identify`)."""
        if not self.dedup:
            return None, None
        return identify(self.store, path, verify=self.verify)

    def clock_of(self, known: KnownFile) -> tuple[float, GpsTrack] | None:
        """UTC start (seconds) of an archived file and its drive's GPS track; None when its drive is
        gone or has no track."""
        if known.drive_id is None or known.part is None:
            return None
        parts = {p.part: p for p in self.store.parts(known.drive_id)}
        fix = self.store.track(known.drive_id)
        if known.part not in parts or fix is None or len(fix[0]) < 2:
            return None
        t, lat, lon = fix
        nan = np.full(len(t), np.nan)
        track = finish_track(t, lat, lon, nan, nan, f"the archive's drive {known.drive_name}", {})
        return parts[known.part].start_utc, track

    def tails(self, t0: float, t1: float) -> dict[Path, tuple[FileInfo, DriveTail]]:
        """The last files of the live drives (kind ``drive``) that end between UTC ``t0`` and
        ``t1`` (seconds), by their planner path (:func:`tail_path`)."""
        out: dict[Path, tuple[FileInfo, DriveTail]] = {}
        for did, name, frames, parts, fps, w, h, channel, blob, start, n in self.store.last_parts(t0, t1):
            path = tail_path(name)
            info = FileInfo(path, float(start), int(n) / fps, int(w), int(h), float(fps), "drive", channel, 0.0)
            out[path] = (info, DriveTail(int(did), name, int(frames), int(parts), float(fps), blob,
                                                channel or "front"))  # fmt: skip
        return out
