"""GPS recorded inside the video file by the camera itself.

Readers, tried in this order by :func:`read_embedded_gps`:

* **NMEA sentences in a text track** (some dashcams write ``$GPRMC``/``$GNGGA`` lines as subtitle
  samples): the track's packets are demuxed with PyAV, each packet's presentation time is the fix's
  video time, and the sentences are parsed with pynmea2 (:func:`fixes_from_nmea_samples`);
* **GoPro GPMF** (:mod:`egovid.core.camera.gpmf`, HERO5 GPS5 through HERO13 GPS9, MAX, Fusion),
  cross-checked fix for fix with telemetry-parser's own reading: readers that disagree are
  reported (an error), never one of them guessed;
* **ExifTool** (``-ee``: Novatek/Viofo, BlackVue, Garmin, Nextbase, Thinkware, Kenwood, the Karma
  drone's GPS, DJI, Insta360, CAMM, …) through the one pyexiftool wrapper,
  :mod:`egovid.core.camera.exif`, in file order; :func:`fixes_from_exiftool` pairs each fix's
  fields by where they stand (:mod:`egovid.dashcam.route.camera_gps`).

Tesla's per-frame SEI telemetry has no time of day; the ingest reads it with the file's clock
(:mod:`egovid.dashcam.ingest.sources`).

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
import os
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import av
import numpy as np

from egovid.core.camera.exif import read_records
from egovid.core.camera.gpmf import read_gpmf_gps
from egovid.core.camera.gps_check import read_telemetry_parser_gps
from egovid.core.times import plausible_utc
from egovid.dashcam.route.camera_gps import GpsRows, exiftool_records, exiftool_rows, gopro_gps
from egovid.dashcam.route.tracks import GpsTrack, finish_track, nmea_fixes

_NMEA_LINE = re.compile(r"\$[A-Z]{2}[A-Z]{3},[^\r\n$]*")
#: ExifTool 12.57 with ``-api QuickTimeUTC`` writes the fraction of a GoPro Karma GPSDateTime after
#: the zone it adds (``19:27:59+00:00.54713``): moved back in front of the zone before parsing.
_FRACTION_AFTER_ZONE = re.compile(r"(:\d\d)(Z|[+\-]\d\d:?\d\d)(\.\d+)$")
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
    """``YYYY:MM:DD HH:MM:SS[.fff][Z|±HH:MM]`` (ExifTool's GPSDateTime; also with the fraction
    after the zone, :data:`_FRACTION_AFTER_ZONE`) → UTC seconds since the epoch; a time without
    zone is UTC (GPS time is); None if unreadable or implausible."""
    m = _GPS_TIME.match(_FRACTION_AFTER_ZONE.sub(r"\1\3\2", str(text).strip()))
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


def fixes_from_exiftool(args_text: str, source: str = "") -> EmbeddedGps | None:
    """Fixes from ExifTool's ``-ee -a -G3:0 -args`` text of a file (:meth:`ExifTool.records
    <egovid.core.camera.exif.ExifTool.records>`); None if there is no GPS position in it.

    ExifTool puts each timed-metadata sample in a document ``DocN`` with its ``SampleTime`` and
    ``SampleDuration`` (seconds on the video clock); a fix is the run of its GPS tags in file
    order (see :func:`egovid.dashcam.route.camera_gps.exiftool_rows`, which also spreads a
    document's one time over its fixes, GoPro GPS5, and drops void, imprecise and untimed fixes).
    """
    return from_rows(exiftool_rows(exiftool_records(args_text), parse_gps_time, source))


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
    track = finish_track(a[:, 0], a[:, 2], a[:, 3], a[:, 4], a[:, 5], reader, dropped)
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


def from_rows(rows: GpsRows) -> EmbeddedGps | None:
    """An :class:`EmbeddedGps` of a camera reader's rows (:mod:`egovid.dashcam.route.camera_gps`);
    None with fewer than two plausible fixes."""
    return _embedded(rows.rows, rows.reader, rows.dropped)


def read_embedded_gps(video: str | os.PathLike) -> EmbeddedGps | None:
    """The video's own GPS, from the first reader that finds fixes: NMEA in a text track; the
    GoPro GPMF track (every generation's layout, cross-checked fix for fix with telemetry-parser:
    a disagreement raises :class:`~egovid.core.errors.EgovidError`); ExifTool's embedded streams,
    paired in file order. None if the file holds no usable GPS. (Tesla's per-frame SEI has no
    time of day: :func:`egovid.dashcam.ingest.sources.examine` reads it with the file's clock.)"""
    name = Path(video).name
    samples = text_track_samples(video)
    if samples:
        found = fixes_from_nmea_samples(samples, name)
        if found is not None:
            return found
    gpmf = read_gpmf_gps(video)
    if gpmf is not None:
        found = from_rows(gopro_gps(gpmf, read_telemetry_parser_gps(video), name))
        if found is not None:
            return found
    return fixes_from_exiftool(read_records(video), name)
