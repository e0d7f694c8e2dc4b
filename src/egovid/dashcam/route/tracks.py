"""GPS tracks: GPX (gpxpy), NMEA 0183 (pynmea2) and CSV, projected to metres.

Every reader returns a :class:`GpsTrack` of valid fixes sorted by time: UTC seconds since the
epoch, latitude/longitude in degrees, speed in m/s and bearing in degrees (derived from the
positions where the file has none). NMEA sentences with a bad checksum, RMC fixes flagged void
(status V) or dead-reckoned / estimated (mode E) and GGA fixes of quality 0 or 6 are dropped and
counted; gaps longer than ``max_gap`` seconds are reported so the caller can split the track.

For matching, positions are projected to metres on a local equirectangular plane around a fixed
origin (the archive's), accurate to well under a metre over tens of kilometres.
"""

from __future__ import annotations

import csv
import datetime as dt
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import gpxpy
import numpy as np
import pynmea2

from egovid.core.errors import EgovidError
from egovid.core.times import iso_to_utc, utc_seconds

EARTH_R = 6371008.8
KNOT = 0.514444  # m/s
GPS_EXTENSIONS = (".gpx", ".nmea", ".csv")  # of a GPS log beside its video
_FIX = "give a GPX file, an NMEA 0183 log (.nmea/.txt) or a CSV with time,lat,lon[,speed,bearing]"


@dataclass
class GpsTrack:
    """Valid GPS fixes sorted by time (t: UTC seconds since the epoch)."""

    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    speed: np.ndarray
    bearing: np.ndarray
    source: str = ""
    dropped: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t)

    def gaps(self, max_gap: float = 5.0) -> list[tuple[float, float]]:
        """(start, end) UTC seconds of gaps longer than ``max_gap`` seconds."""
        d = np.diff(self.t)
        return [(float(self.t[i]), float(self.t[i + 1])) for i in np.flatnonzero(d > max_gap)]

    def xy(self, origin: tuple[float, float]) -> np.ndarray:
        """(N, 2) east/north metres around ``origin`` (lat, lon degrees)."""
        return project(self.lat, self.lon, origin)

    def motion_at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Speed (m/s) and bearing (degrees) interpolated at UTC times ``t`` (seconds)."""
        b = np.unwrap(np.radians(self.bearing))
        return np.interp(t, self.t, self.speed), np.degrees(np.interp(t, self.t, b)) % 360.0

    def between(self, t0: float, t1: float) -> GpsTrack:
        """The fixes with ``t0 <= t <= t1`` (UTC seconds)."""
        k = (self.t >= t0) & (self.t <= t1)
        return GpsTrack(self.t[k], self.lat[k], self.lon[k], self.speed[k], self.bearing[k], self.source, self.dropped)


def project(lat, lon, origin: tuple[float, float]) -> np.ndarray:
    """Latitude/longitude (degrees) → (N, 2) east/north metres on a plane tangent at ``origin``."""
    lat0, lon0 = origin
    x = np.radians(np.asarray(lon, dtype=float) - lon0) * EARTH_R * math.cos(math.radians(lat0))
    y = np.radians(np.asarray(lat, dtype=float) - lat0) * EARTH_R
    return np.stack([x, y], axis=-1)


def _derive(t: np.ndarray, lat: np.ndarray, lon: np.ndarray, speed, bearing) -> tuple[np.ndarray, np.ndarray]:
    """Speed and bearing where the file has none: from positions smoothed over ~5 fixes, since
    differentiating raw fixes turns metres of noise into metres per second."""
    xy = project(lat, lon, (float(lat[0]), float(lon[0])))
    if len(t) < 2:
        return np.zeros(len(t)), np.zeros(len(t))
    if len(t) >= 5:
        k = np.ones(5) / 5.0
        xy = np.stack([np.convolve(np.pad(xy[:, i], 2, mode="edge"), k, mode="valid") for i in range(2)], axis=1)
    v = np.gradient(xy, t, axis=0)
    spd = np.hypot(v[:, 0], v[:, 1])
    brg = np.degrees(np.arctan2(v[:, 0], v[:, 1])) % 360.0
    sp = np.where(np.isfinite(speed), speed, spd) if speed is not None else spd
    be = np.where(np.isfinite(bearing), bearing, brg) if bearing is not None else brg
    return sp, be


def _finish(t, lat, lon, speed, bearing, source, dropped) -> GpsTrack:
    t = np.asarray(t, dtype=float)
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    # NaN or infinite times or positions are no fixes (a NaN origin would poison the archive).
    finite = np.isfinite(t) & np.isfinite(lat) & np.isfinite(lon)
    if not finite.all():
        dropped = {**dropped, "not finite": int((~finite).sum())}
    t, lat, lon = t[finite], lat[finite], lon[finite]
    speed, bearing = np.asarray(speed, dtype=float)[finite], np.asarray(bearing, dtype=float)[finite]
    if len(t) < 2:
        raise EgovidError(f"{source} has {len(t)} valid GPS fix(es); at least 2 are needed", _FIX)
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.concatenate([[True], np.diff(t) > 0])  # drop duplicate timestamps (RMC+GGA pairs)
    arrays = [a[order][keep] for a in (lat, lon, speed, bearing)]
    lat, lon, speed, bearing = arrays
    t = t[keep]
    if np.any(np.abs(lat) > 90) or np.any(np.abs(lon) > 180):
        raise EgovidError(f"{source} has latitudes/longitudes out of range", "check the file's columns")
    speed, bearing = _derive(t, lat, lon, speed, bearing)
    return GpsTrack(t, lat, lon, speed, bearing, source, dropped)


def read_gpx(path: Path) -> GpsTrack:
    try:
        gpx = gpxpy.parse(path.read_text(encoding="utf-8", errors="replace"))
    except Exception as exc:
        raise EgovidError(f"{path} is not a valid GPX file ({str(exc)[:80]})", _FIX) from None
    t, lat, lon, sp = [], [], [], []
    dropped = {"no time": 0}
    for track in gpx.tracks:
        for seg in track.segments:
            for p in seg.points:
                if p.time is None:
                    dropped["no time"] += 1
                    continue
                t.append(utc_seconds(p.time))
                lat.append(p.latitude)
                lon.append(p.longitude)
                sp.append(p.speed if p.speed is not None else np.nan)
    return _finish(t, lat, lon, sp, np.full(len(t), np.nan), str(path), dropped)


def read_nmea(path: Path) -> GpsTrack:
    dropped = {"checksum": 0, "void or estimated": 0, "unparsable": 0}
    lines = (ln.strip() for ln in path.read_text(encoding="ascii", errors="replace").splitlines())
    rows = nmea_fixes(((math.nan, ln) for ln in lines if ln.startswith("$")), dropped, "void or estimated")
    if not rows:
        raise EgovidError(f"{path} contains no valid NMEA RMC/GGA fixes", _FIX)
    arr = np.array(rows, dtype=float)
    return _finish(arr[:, 0], arr[:, 2], arr[:, 3], arr[:, 4], arr[:, 5], str(path), dropped)


def nmea_fixes(
    sentences: Iterable[tuple[float, str]], dropped: dict[str, int], void: str
) -> list[tuple[float, float, float, float, float, float]]:
    """The fixes of NMEA 0183 sentences, each given with a tag (the video time of the text sample
    it came in, NaN for a log file): rows (UTC seconds, tag, latitude, longitude, speed m/s,
    bearing degrees) sorted by time, one per UTC time.

    The merge rule of every NMEA reader: RMC sentences with a fix (:func:`rmc_has_fix`) give
    date, time, position, speed and course (a later RMC of the same time wins); GGA sentences of
    fix quality 1-5 add positions, dated by the last RMC's date, at times no RMC has (the first
    GGA of a time wins). Sentences with a bad checksum or unparsable are counted in ``dropped``
    (:func:`parse_nmea`), those without a fix under ``dropped[void]``."""
    rmc: dict[float, tuple] = {}
    gga: list[tuple] = []
    day = None
    for tag, line in sentences:
        msg = parse_nmea(line, dropped)
        if msg is None:
            continue
        if msg.sentence_type == "RMC":
            if not rmc_has_fix(msg):
                dropped[void] += 1
                continue
            day = msg.datestamp
            utc = utc_seconds(dt.datetime.combine(msg.datestamp, msg.timestamp))
            speed = as_float(msg.spd_over_grnd) * KNOT
            rmc[utc] = (utc, tag, msg.latitude, msg.longitude, speed, as_float(msg.true_course))
        elif msg.sentence_type == "GGA":
            if not msg.timestamp or str(msg.gps_qual) in ("0", "6", ""):
                dropped[void] += 1
                continue
            gga.append((msg.timestamp, tag, msg.latitude, msg.longitude))
    fixes = dict(rmc)
    for ts, tag, lat, lon in gga if day is not None else ():
        utc = utc_seconds(dt.datetime.combine(day, ts))
        fixes.setdefault(utc, (utc, tag, lat, lon, math.nan, math.nan))
    return [fixes[t] for t in sorted(fixes)]


def as_float(v) -> float:
    """``v`` as a float; NaN when it is missing or not a number."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _parse_time(text: str) -> float:
    s = text.strip()
    try:
        return float(s)  # already epoch seconds
    except ValueError:
        pass
    try:
        return iso_to_utc(s)
    except ValueError:
        raise EgovidError(f"GPS time {s!r} is neither ISO 8601 nor epoch seconds", _FIX) from None


def read_csv(path: Path) -> GpsTrack:
    with open(path, newline="", encoding="utf-8", errors="replace") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise EgovidError(f"GPS file {path} is empty", _FIX)
    header = [h.strip().lower() for h in rows[0]]
    alias = {
        "latitude": "lat",
        "longitude": "lon",
        "lng": "lon",
        "timestamp": "time",
        "course": "bearing",
        "heading": "bearing",
        "speed_mps": "speed",
    }
    header = [alias.get(h, h) for h in header]
    missing = [c for c in ("time", "lat", "lon") if c not in header]
    if missing:
        raise EgovidError(f"GPS CSV {path} lacks column(s) {', '.join(missing)}", _FIX)
    col = {c: header.index(c) for c in ("time", "lat", "lon", "speed", "bearing") if c in header}
    t, lat, lon, sp, be = [], [], [], [], []
    for n, row in enumerate(rows[1:], start=2):
        if not any(x.strip() for x in row):
            continue
        try:
            t.append(_parse_time(row[col["time"]]))
            lat.append(float(row[col["lat"]]))
            lon.append(float(row[col["lon"]]))
            sp.append(float(row[col["speed"]]) if "speed" in col and row[col["speed"]].strip() else np.nan)
            be.append(float(row[col["bearing"]]) if "bearing" in col and row[col["bearing"]].strip() else np.nan)
        except (ValueError, IndexError):
            raise EgovidError(f"{path} line {n} is not a GPS fix: {','.join(row)[:60]}", _FIX) from None
    return _finish(t, lat, lon, sp, be, str(path), {})


def gps_beside(video: Path) -> Path:
    """The GPS file beside a video: same name, extension .gpx, .nmea or .csv (either case)."""
    for ext in GPS_EXTENSIONS:
        for cand in (video.with_suffix(ext), video.with_suffix(ext.upper())):
            if cand.exists():
                return cand
    raise EgovidError(
        f"no GPS track for {video.name}: no {video.stem}.gpx, .nmea or .csv beside it",
        "give the drive's GPS log with --gps FILE",
    )


def read_track(path: str | os.PathLike) -> GpsTrack:
    """Read a GPS track, recognising GPX, NMEA or CSV by content; clear errors otherwise."""
    p = Path(path)
    if not p.exists():
        raise EgovidError(f"GPS file not found: {p}", "check the path")
    if p.stat().st_size == 0:
        raise EgovidError(f"GPS file {p} is empty", _FIX)
    head = p.read_bytes()[:4096]
    if b"\x00" in head:
        raise EgovidError(f"{p} is a binary file, not a GPS track", _FIX)
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff").lstrip()
    if text.startswith("<") and "<gpx" in text[:2000].lower():
        return read_gpx(p)
    if text.startswith("$") or "\n$GP" in text or "\n$GN" in text:
        return read_nmea(p)
    first = text.splitlines()[0].lower() if text else ""
    if "lat" in first and ("lon" in first or "lng" in first):
        return read_csv(p)
    raise EgovidError(f"{p} is not a GPS track this tool reads", _FIX)


def parse_nmea(line: str, dropped: dict) -> object | None:
    """One NMEA 0183 sentence parsed by pynmea2 (checksum checked), or None with the reason
    counted in ``dropped`` ("checksum" or "unparsable")."""
    try:
        return pynmea2.parse(line.strip(), check=True)
    except pynmea2.ChecksumError:
        dropped["checksum"] += 1
    except pynmea2.ParseError:
        dropped["unparsable"] += 1
    return None


def rmc_has_fix(msg) -> bool:
    """An RMC sentence with a valid fix: status A, not an estimated/manual/simulated/no-fix mode,
    with its date and time."""
    mode = getattr(msg, "mode_indicator", None) if len(msg.data) > 11 else None
    return msg.status == "A" and mode not in ("E", "N", "M", "S") and bool(msg.datestamp) and bool(msg.timestamp)
