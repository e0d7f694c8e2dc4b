"""GPS recorded inside the video file by the camera itself.

Two readers, tried in this order by :func:`read_embedded_gps`:

* **NMEA sentences in a text track** (some dashcams write ``$GPRMC``/``$GNGGA`` lines as subtitle
  samples): the track's packets are demuxed with PyAV, each packet's presentation time is the fix's
  video time, and the sentences are parsed with pynmea2 (:func:`fixes_from_nmea_samples`);
* **ExifTool** (``-ee``: Novatek/Viofo, BlackVue, Garmin, Nextbase, Thinkware, Kenwood, GoPro GPMF
  incl. the Karma drone's GPS, DJI, Insta360, CAMM, …) through the one pyexiftool wrapper,
  :mod:`egovid.core.camera.exif`; :func:`fixes_from_exiftool` turns its tags into fixes.

Both give an :class:`EmbeddedGps`: the fixes as a :class:`~egovid.dashcam.route.tracks.GpsTrack` (UTC
seconds, degrees) and, where the file says it, each fix's time on the video's own clock (seconds
from the first frame; timed metadata samples carry it). Those pairs are what makes GPS time the
video's time base (see :mod:`egovid.dashcam.route.clock`).

Fixes without a position fix are dropped and counted: status V (void), measure mode below 2-D,
horizontal dilution of precision above 5, the (0, 0) position that cameras write before a fix,
and times outside 2000-2100 (a GPS week roll-over or an unset clock).
"""

from __future__ import annotations

import datetime as dt
import itertools
import math
import os
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import av
import numpy as np

from egovid.core.camera.exif import read_tags
from egovid.core.times import plausible_utc
from egovid.dashcam.route.tracks import GpsTrack, _finish, as_float, nmea_fixes

MAX_HDOP = 5.0
_KEY = re.compile(r"^(?:Doc(\d+):)?(?:Copy(\d+):)?([A-Za-z0-9]+)$")
_NMEA_LINE = re.compile(r"\$[A-Z]{2}[A-Z]{3},[^\r\n$]*")
_GPS_TIME = re.compile(r"^(\d{4})[:\-](\d\d)[:\-](\d\d)[ T](\d\d):(\d\d):(\d\d(?:\.\d+)?)\s*(Z|[+\-]\d\d:?\d\d)?$")


@dataclass
class EmbeddedGps:
    """GPS fixes read from a video file.

    ``track``: the valid fixes (UTC, degrees; speed m/s and bearing degrees derived where absent);
    ``video_t``: for each fix of ``track``, its time in seconds from the video's first frame, or NaN
    where the file does not say; ``reader``: which reader found them; ``dropped``: fixes dropped
    per reason.
    """

    track: GpsTrack
    video_t: np.ndarray
    reader: str
    dropped: dict[str, int] = field(default_factory=dict)

    @property
    def timed(self) -> bool:
        """True when at least two fixes carry their video time (GPS time can then be the time base)."""
        return int(np.isfinite(self.video_t).sum()) >= 2

    def start_utc(self) -> float:
        """UTC (seconds since the epoch) of the video's first frame from the fixes' video times:
        the median of ``utc - video_t`` over the timed fixes (robust to a late or early sample)."""
        ok = np.isfinite(self.video_t)
        if ok.sum() < 1:
            raise ValueError("no fix carries its video time")
        return float(np.median(self.track.t[ok] - self.video_t[ok]))


def parse_gps_time(text: str) -> float | None:
    """``YYYY:MM:DD HH:MM:SS[.fff][Z|±HH:MM]`` (ExifTool's GPSDateTime) → UTC seconds since the
    epoch; a time without zone is UTC (GPS time is); None if unreadable or implausible."""
    m = _GPS_TIME.match(str(text).strip())
    if not m:
        return None
    y, mo, d, h, mi = (int(m.group(i)) for i in range(1, 6))
    sec = float(m.group(6))
    try:
        t = dt.datetime(y, mo, d, h, mi, tzinfo=dt.UTC).timestamp() + sec
    except ValueError:
        return None
    zone = m.group(7)
    if zone and zone != "Z":
        sign = -1 if zone[0] == "-" else 1
        hh, mm = int(zone[1:3]), int(zone[-2:])
        t -= sign * (hh * 3600 + mm * 60)
    return t if plausible_utc(t) else None


def _speed_ms(speed, ref) -> float:
    """ExifTool's GPSSpeed in m/s given GPSSpeedRef (K km/h, M mph, N knots); NaN if the unit is unknown."""
    factor = {"K": 1 / 3.6, "M": 0.44704, "N": 0.514444}.get(str(ref).strip().upper()[:1] if ref else "")
    v = as_float(speed)
    return v * factor if factor is not None and math.isfinite(v) else math.nan


def fixes_from_exiftool(tags: dict, source: str = "") -> EmbeddedGps | None:
    """Fixes from ExifTool's tags of a file read with ``-ee -a -G3:4 -n`` (keys such as
    ``Doc2:Copy5:GPSLatitude``); None if there is no GPS position in them.

    ExifTool puts each timed-metadata sample in a document ``DocN`` with its ``SampleTime`` and
    ``SampleDuration`` (seconds on the video clock) and numbers repeated tags ``CopyM``; the fixes of
    one document are told apart by that number (the one without a number is the document's last).
    A fix's UTC is its own ``GPSDateTime`` (or ``GPSDateStamp`` + ``GPSTimeStamp``); where a document
    has one time for several fixes (GoPro GPS5), the fixes are spread evenly over the sample's
    duration from it. Video times: the document's sample time, fixes spread evenly over its duration.
    """
    dropped = {"no fix": 0, "imprecise": 0, "no time": 0}
    rows: list[tuple[float, float, float, float, float, float]] = []  # utc, video_t, lat, lon, speed, bearing
    for doc, samples in sorted(_documents(tags).items()):
        if doc == 0:
            continue  # the container's own tags (a single GPSPosition is no track)
        meta = {k: v for s in samples.values() for k, v in s.items() if k in ("SampleTime", "SampleDuration")}
        fixes = [s for _, s in sorted(samples.items()) if "GPSLatitude" in s and "GPSLongitude" in s]
        if not fixes:
            continue
        n = len(fixes)
        t0, dur = as_float(meta.get("SampleTime")), as_float(meta.get("SampleDuration"))
        times = [_fix_time(s) for s in fixes]
        given = [t for t in times if t is not None]
        if len(given) == 1 and n > 1 and math.isfinite(dur):  # one time per payload (GoPro GPSU)
            times = [given[0] + k * dur / n for k in range(n)]
        elif len(given) == n and n > 1 and any(b < a for a, b in itertools.pairwise(given)):
            order = np.argsort(given, kind="stable")  # trust the fixes' own times over tag order
            fixes, times = [fixes[i] for i in order], [given[i] for i in order]
        for k, (s, utc) in enumerate(zip(fixes, times, strict=True)):
            why = _unusable(s, utc)
            if why is not None:
                dropped[why] += 1
                continue
            vt = (
                t0 + k * dur / n
                if math.isfinite(t0) and math.isfinite(dur)
                else (t0 if math.isfinite(t0) else math.nan)
            )
            bearing = as_float(s.get("GPSTrack")) if str(s.get("GPSTrackRef", "T")).upper()[:1] == "T" else math.nan
            lat, lon = as_float(s.get("GPSLatitude")), as_float(s.get("GPSLongitude"))
            rows.append((utc, vt, lat, lon, _speed_ms(s.get("GPSSpeed"), s.get("GPSSpeedRef")), bearing))
    return _embedded(rows, f"ExifTool ({source})" if source else "ExifTool", {k: v for k, v in dropped.items() if v})


def _documents(tags: dict) -> dict[int, dict[float, dict[str, object]]]:
    """ExifTool's tags by document (``DocN``; 0 for the container's own) and copy (``CopyM``; inf
    for the one without a number), the tag names without those prefixes."""
    docs: dict[int, dict[float, dict[str, object]]] = {}
    for key, value in tags.items():
        m = _KEY.match(key)
        if not m:
            continue
        doc = int(m.group(1) or 0)
        copy = float(m.group(2)) if m.group(2) else math.inf
        docs.setdefault(doc, {}).setdefault(copy, {})[m.group(3)] = value
    return docs


def _unusable(sample: dict, utc: float | None) -> str | None:
    """Why one fix of ExifTool's is dropped ("no fix", "imprecise", "no time"), None if it is
    kept: no position or the (0, 0) of no fix yet, status V or a measure mode below 2-D, a
    horizontal dilution of precision above :data:`MAX_HDOP`, no time."""
    lat, lon = as_float(sample.get("GPSLatitude")), as_float(sample.get("GPSLongitude"))
    if not (math.isfinite(lat) and math.isfinite(lon)) or (abs(lat) < 1e-6 and abs(lon) < 1e-6):
        return "no fix"
    mode = as_float(sample.get("GPSMeasureMode"))
    if str(sample.get("GPSStatus", "A")).strip().upper()[:1] == "V" or (math.isfinite(mode) and mode < 2):
        return "no fix"
    dop = as_float(sample.get("GPSHPositioningError", sample.get("GPSDOP")))
    if math.isfinite(dop) and dop > MAX_HDOP:
        return "imprecise"
    return "no time" if utc is None else None


def _fix_time(sample: dict) -> float | None:
    if "GPSDateTime" in sample:
        return parse_gps_time(str(sample["GPSDateTime"]))
    if "GPSDateStamp" in sample and "GPSTimeStamp" in sample:
        ts = str(sample["GPSTimeStamp"]).strip()
        if re.fullmatch(r"\d+(\.\d+)?", ts):  # seconds of the day (-n on some formats)
            s = float(ts)
            ts = f"{int(s // 3600):02d}:{int(s % 3600 // 60):02d}:{s % 60:09.6f}"
        return parse_gps_time(f"{sample['GPSDateStamp']} {ts}")
    return None


def fixes_from_nmea_samples(samples: Iterable[tuple[float, str]], source: str = "") -> EmbeddedGps | None:
    """Fixes from NMEA 0183 text samples: (video time in seconds, text of the sample) pairs, as a
    text track holds them, merged as a log file's are (:func:`~egovid.dashcam.route.tracks.nmea_fixes`:
    RMC with a fix, GGA positions at RMC's date; bad checksums dropped and counted). A fix's video
    time is its sample's."""
    dropped = {"checksum": 0, "no fix": 0, "unparsable": 0}
    lines = ((vt, line) for vt, text in samples for line in _NMEA_LINE.findall(text))
    rows = nmea_fixes(lines, dropped, "no fix")
    name = f"NMEA text track ({source})" if source else "NMEA text track"
    return _embedded(rows, name, {k: v for k, v in dropped.items() if v})


def _embedded(rows: list[tuple], reader: str, dropped: dict[str, int]) -> EmbeddedGps | None:
    rows = [r for r in rows if plausible_utc(r[0])]
    if len(rows) < 2:
        return None
    a = np.array(sorted(rows, key=lambda r: r[0]), dtype=float)
    keep = np.concatenate([[True], np.diff(a[:, 0]) > 0])
    a = a[keep]
    if len(a) < 2:
        return None
    track = _finish(a[:, 0], a[:, 2], a[:, 3], a[:, 4], a[:, 5], reader, dropped)
    return EmbeddedGps(track, a[:, 1], reader, dropped)


# -- I/O edge ----------------------------------------------------------------------------------
def text_track_samples(video: str | os.PathLike) -> list[tuple[float, str]]:
    """(presentation time in seconds from the first video frame, text) of every sample of the
    file's subtitle/text and data tracks that holds NMEA sentences (``$GP…``/``$GN…``)."""
    out: list[tuple[float, str]] = []
    with av.open(str(video)) as c:
        if not c.streams.video:
            return out
        v = c.streams.video[0]
        v0 = float((v.start_time or 0) * v.time_base) if v.time_base else 0.0
        streams = [s for s in c.streams if s.type in ("subtitle", "data")]
        if not streams:
            return out
        for pkt in c.demux(*streams):
            if pkt.size == 0 or pkt.pts is None:
                continue
            raw = bytes(pkt)
            if b"$G" not in raw:
                continue
            text = raw.decode("ascii", errors="replace")
            out.append((float(pkt.pts * pkt.time_base) - v0, text))
    return out


def read_embedded_gps(video: str | os.PathLike) -> EmbeddedGps | None:
    """The video's own GPS: NMEA in a text track first, else ExifTool's embedded streams; None if
    the file holds no usable GPS."""
    name = Path(video).name
    samples = text_track_samples(video)
    if samples:
        found = fixes_from_nmea_samples(samples, name)
        if found is not None:
            return found
    return fixes_from_exiftool(read_tags(video, embedded=True, duplicates=True), name)
