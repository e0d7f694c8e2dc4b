"""A drive's recorded readings (:mod:`egovid.dashcam.archive.readings`): made from a camera's
telemetry at ingest, written out as CSV (``egovid dashcam extract --readings``) and drawn as a
figure (``egovid dashcam report --figures``).

So far one source records them: a Tesla's per-frame SEI (:mod:`egovid.core.camera.tesla`; speed,
acceleration along three axes, steering, pedals, gear, blinkers, autopilot, position, heading).
"""

from __future__ import annotations

import csv
import datetime as dt
import os
from pathlib import Path

import numpy as np

from egovid.core.camera.tesla import TeslaTelemetry
from egovid.core.errors import EgovidError
from egovid.core.files import atomic_path
from egovid.dashcam.archive import readings as table
from egovid.dashcam.archive.readings import DriveReadings
from egovid.dashcam.archive.store import Archive

TESLA_SOURCE = "Tesla SEI"


def from_tesla(tel: TeslaTelemetry, offset_s: float, start_utc: float) -> DriveReadings:
    """Readings of one Tesla file placed on a drive: its first frame ``offset_s`` seconds into the
    drive's media clock and at UTC ``start_utc`` (seconds); every decoded channel, values as read."""
    t = np.asarray(tel.video_t, np.float64)
    channels = {k: np.asarray(v, np.float64).copy() for k, v in tel.channels.items()}
    return DriveReadings(offset_s + t, start_utc + t, channels, TESLA_SOURCE)


# -- CSV ---------------------------------------------------------------------------------------
def _cell(v: float) -> str:
    """A value as CSV text that reads back to the same float64: empty for NaN, integers without a
    point, others as Python's shortest round-trip repr."""
    if not np.isfinite(v):
        return ""
    if float(v).is_integer() and abs(v) < 2**53:
        return str(int(v))
    return repr(float(v))


def _iso(utc: float) -> str:
    return dt.datetime.fromtimestamp(utc, dt.UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def write_csv(r: DriveReadings, path: str | os.PathLike) -> Path:
    """Write readings as CSV (atomically): ``t_s`` (seconds into the drive), ``utc`` (ISO 8601,
    milliseconds), then one column per channel (units: :data:`~egovid.dashcam.archive.readings.UNITS`)."""
    names = list(r.channels)
    cols = [r.channels[k] for k in names]
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", "utc", *names])
        for i in range(len(r)):
            w.writerow([_cell(r.t[i]), _iso(float(r.utc[i])), *(_cell(c[i]) for c in cols)])
    return Path(path)


def read_csv(path: str | os.PathLike) -> DriveReadings:
    """Readings from a CSV :func:`write_csv` wrote (``utc`` back to seconds; empty cells NaN)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    head, body = rows[0], rows[1:]

    def num(x: str) -> float:
        return float(x) if x else np.nan

    cols = list(zip(*body, strict=True)) if body else [()] * len(head)
    utc = [dt.datetime.fromisoformat(x.replace("Z", "+00:00")).timestamp() for x in cols[1]]
    return DriveReadings(
        np.array([num(x) for x in cols[0]]),
        np.array(utc, np.float64),
        {k: np.array([num(x) for x in c]) for k, c in zip(head[2:], cols[2:], strict=True)},
    )


def drive_readings(archive: Archive, drive_id: int, t0: float = 0.0, t1: float = np.inf) -> DriveReadings | None:
    """The readings of a drive between ``t0`` and ``t1`` seconds into it; None when it has none."""
    r = table.get(archive.catalogue, drive_id)
    return None if r is None else r.between(t0, t1)


def require_readings(archive: Archive, drive_id: int, name: str) -> None:
    """:class:`EgovidError` when drive ``name`` has no recorded readings (before any work)."""
    if drive_id not in table.summaries(archive.catalogue):
        raise EgovidError(
            f"drive {name} has no recorded readings (speed, acceleration …)",
            "only cameras that record them in the video (Tesla, firmware 2025.44.25+) have them; leave --readings out",
        )
