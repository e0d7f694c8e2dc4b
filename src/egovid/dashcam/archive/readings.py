"""The readings a car recorded beside its video (speed, acceleration, steering, pedals …), kept per
drive in the catalogue table ``drive_readings``.

One row per drive: the sample times on the drive's media clock (``t``: seconds from its first
frame, the clock of ``extract --start`` and of the archived audio) and in UTC, the names of the
channels, every channel's values (float64, exactly as read: Tesla's float32 fields widened without
rounding), all in one zlib-compressed little-endian block, where they came from, and a summary
(:func:`summarise`: maximum speed and accelerations) that ``report`` and the web app read without
decompressing anything.

The table is not part of the fleet tables' versions: it is created, with the ``readings_schema``
mark in ``meta``, by the first commit of a drive that has readings (:func:`ensure_table`). An
archive without it (every archive before, and every archive of cameras that record none) is read
as it is: no drive has readings, nothing is created or written.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from egovid.dashcam.archive.catalogue import Catalogue

READINGS_SCHEMA = 1
META_KEY = "readings_schema"

_TABLE = """
CREATE TABLE IF NOT EXISTS drive_readings (
  drive_id {REF} PRIMARY KEY REFERENCES drives(id), samples INTEGER NOT NULL, channels TEXT NOT NULL,
  data {BLOB} NOT NULL, source TEXT, summary TEXT)
"""

#: Units of the channels egovid knows (others are stored and written out all the same).
UNITS = {
    "speed_mps": "m/s",
    "accel_x": "m/s², the car's front/back axis",
    "accel_y": "m/s², its left/right axis",
    "accel_z": "m/s², its up/down axis (as the car reports it)",
    "steering_deg": "degrees",
    "accelerator": "0..1",
    "brake": "0/1",
    "blinker_left": "0/1",
    "blinker_right": "0/1",
    "gear": "0 park, 1 drive, 2 reverse, 3 neutral",
    "autopilot": "0 none, 1 FSD, 2 autosteer, 3 TACC",
    "lat": "degrees",
    "lon": "degrees",
    "heading_deg": "degrees",
    "frame_seq_no": "the camera's frame number",
    "version": "the message's version",
}


@dataclass
class DriveReadings:
    """A drive's readings: ``t`` (N,) seconds on the drive's media clock, ``utc`` (N,) UTC seconds,
    ``channels`` name → (N,) float64 values (NaN: not in that sample; units in :data:`UNITS`),
    ``source`` (e.g. ``Tesla SEI``)."""

    t: np.ndarray
    utc: np.ndarray
    channels: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""

    def __len__(self) -> int:
        return len(self.t)

    def between(self, t0: float, t1: float) -> DriveReadings:
        """The samples with ``t0 <= t < t1`` (seconds on the drive's clock)."""
        keep = (self.t >= t0) & (self.t < t1)
        return DriveReadings(self.t[keep], self.utc[keep], {k: v[keep] for k, v in self.channels.items()}, self.source)


def join(first: DriveReadings | None, second: DriveReadings | None) -> DriveReadings | None:
    """``second`` after ``first`` (a file appended to a drive): the union of their channels (NaN
    where one lacks a channel), samples of ``second`` before ``first``'s last left out."""
    if first is None or not len(first):
        return second
    if second is None or not len(second):
        return first
    keep = second.t > first.t[-1]
    names = list(first.channels) + [k for k in second.channels if k not in first.channels]
    n1, n2 = len(first), int(np.count_nonzero(keep))

    def col(k: str) -> np.ndarray:
        a, b = first.channels.get(k), second.channels.get(k)
        return np.concatenate([np.full(n1, np.nan) if a is None else a, np.full(n2, np.nan) if b is None else b[keep]])

    source = first.source if second.source in ("", first.source) else f"{first.source}; {second.source}"
    return DriveReadings(
        np.concatenate([first.t, second.t[keep]]),
        np.concatenate([first.utc, second.utc[keep]]),
        {k: col(k) for k in names},
        source,
    )


def _max(a: np.ndarray | None) -> float | None:
    if a is None or not len(a) or not np.isfinite(a).any():
        return None
    return float(np.nanmax(a))


def summarise(r: DriveReadings) -> dict:
    """What a report says of a drive's readings: sample count and span (s), the channels, the
    maximum speed (m/s), the maximum |acceleration| along each axis and in the road's plane
    (hypot(x, y); m/s²) and the maximum |steering angle| (degrees); None where a channel is absent."""
    ch = r.channels

    def absmax(name: str) -> float | None:
        return _max(np.abs(ch[name])) if name in ch else None

    plane = np.hypot(ch["accel_x"], ch["accel_y"]) if "accel_x" in ch and "accel_y" in ch else None
    return {
        "source": r.source,
        "samples": len(r),
        "seconds": float(r.t[-1] - r.t[0]) if len(r) else 0.0,
        "channels": list(ch),
        "max_speed_mps": _max(ch.get("speed_mps")),
        "max_abs_accel_mps2": {a: absmax(f"accel_{a}") for a in "xyz"},
        "max_horizontal_accel_mps2": _max(plane),
        "max_abs_steering_deg": absmax("steering_deg"),
    }


# -- encoding ----------------------------------------------------------------------------------
def encode(r: DriveReadings) -> tuple[str, bytes]:
    """(channel names as JSON, the zlib-compressed float64 block: t, utc, then each channel)."""
    block = np.stack([r.t, r.utc, *r.channels.values()]).astype("<f8")
    return json.dumps(list(r.channels)), zlib.compress(block.tobytes(), 6)


def decode(samples: int, names: str, data: bytes, source: str = "") -> DriveReadings:
    """The readings :func:`encode` stored."""
    cols = json.loads(names)
    block = np.frombuffer(zlib.decompress(bytes(data)), "<f8").reshape(len(cols) + 2, samples).astype(np.float64)
    return DriveReadings(block[0].copy(), block[1].copy(), {k: block[i + 2].copy() for i, k in enumerate(cols)}, source)


# -- the table ---------------------------------------------------------------------------------
def has_table(cat: Catalogue) -> bool:
    """Whether the catalogue has the readings table (read only)."""
    return cat.get_meta(META_KEY) is not None


def create_table(cat: Catalogue) -> None:
    """The readings table's DDL alone (a backup's copy, whose ``meta`` rows come with the data)."""
    cat._q(_TABLE.format(**cat._TYPES))


def ensure_table(cat: Catalogue) -> None:
    """Create the readings table where it is missing, and mark it (inside the caller's transaction)."""
    if has_table(cat):
        return
    create_table(cat)
    cat.set_meta(META_KEY, str(READINGS_SCHEMA))


def put(cat: Catalogue, drive_id: int, r: DriveReadings) -> None:
    """Store (or replace) a drive's readings, inside the caller's transaction."""
    if not len(r):
        return
    ensure_table(cat)
    names, data = encode(r)
    cat._q("DELETE FROM drive_readings WHERE drive_id = ?", (drive_id,))
    cat._q(
        "INSERT INTO drive_readings(drive_id, samples, channels, data, source, summary) VALUES(?,?,?,?,?,?)",
        (drive_id, len(r), names, data, r.source, json.dumps(summarise(r))),
    )


def append(cat: Catalogue, drive_id: int, r: DriveReadings | None) -> None:
    """Add the readings of a file appended to a drive after the drive's own (inside the caller's
    transaction)."""
    if r is None or not len(r):
        return
    joined = join(get(cat, drive_id), r)
    if joined is not None:
        put(cat, drive_id, joined)


def get(cat: Catalogue, drive_id: int) -> DriveReadings | None:
    """A drive's readings; None when it has none."""
    if not has_table(cat):
        return None
    sql = "SELECT samples, channels, data, source FROM drive_readings WHERE drive_id = ?"
    row = cat._q(sql, (drive_id,)).fetchone()
    return None if row is None else decode(int(row[0]), row[1], row[2], row[3] or "")


def summaries(cat: Catalogue) -> dict[int, dict]:
    """Drive id → :func:`summarise` of its readings, for every drive that has some (read from the
    stored summaries: nothing is decompressed)."""
    if not has_table(cat):
        return {}
    return {int(i): json.loads(s) for i, s in cat._q("SELECT drive_id, summary FROM drive_readings") if s}


def delete(cat: Catalogue, drive_ids: Iterable[int]) -> None:
    """Drop the readings of ``drive_ids`` (forgotten drives), inside the caller's transaction."""
    if not has_table(cat):
        return
    for i in drive_ids:
        cat._q("DELETE FROM drive_readings WHERE drive_id = ?", (int(i),))
