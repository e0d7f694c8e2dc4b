"""GPS fixes of the cameras egovid reads natively, as rows for :mod:`egovid.dashcam.route.embedded`.

Three sources, each turned into the same rows ``(utc, video_t, lat, lon, speed, bearing)``
(seconds, degrees, m/s; NaN where the source does not say) plus the count of dropped fixes per
reason:

* **GoPro GPMF** (:mod:`egovid.core.camera.gpmf`, every generation's layout), cross-checked fix for
  fix against telemetry-parser's own reading (:mod:`egovid.core.camera.gps_check`). Readers that
  disagree make :func:`gopro_gps` raise :class:`~egovid.core.errors.EgovidError` naming the
  difference: the file's GPS is reported, never one reading guessed. Fixes without a lock
  (``GPSF``/GPS9 fix below 2) or with a DOP above :data:`MAX_DOP` are dropped;
* **Tesla SEI** (:mod:`egovid.core.camera.tesla`): one fix per frame with a position; the message
  has no time of day, so the fixes' UTC is the clip's start (from the caller's clock) plus the
  frame time;
* **ExifTool in file order** (``-ee -a -G3:0 -args``, every brand ExifTool covers): a fix is the run of
  ``GPS*`` tags of one document up to the next repeat of a tag it already holds, so fields that
  ExifTool numbers as different copies (``-G4``) are still paired by where they stand. Tags that
  only the first fix of a document holds while later fixes do not (GoPro's one ``GPSDateTime``,
  ``GPSMeasureMode`` and ``GPSHPositioningError`` per payload) describe the whole document: the
  time is the first fix's and the others follow it evenly over the document's duration.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from egovid.core.camera.gpmf import GpmfGps
from egovid.core.camera.gps_check import GpsAgreement, compare
from egovid.core.camera.tesla import TeslaTelemetry
from egovid.core.errors import EgovidError
from egovid.dashcam.route.tracks import as_float

#: Fixes whose dilution of precision is above this are dropped as imprecise.
MAX_DOP = 5.0
_ARG = re.compile(r"^-(?:(Doc\d+)|[A-Za-z0-9]+)(?::([A-Za-z0-9]+))*:([A-Za-z0-9]+)=(.*)$")
#: GPSSpeed's unit per ExifTool family-0 group, in m/s per unit: ExifTool's QuickTime streams give
#: km/h unless a GPSSpeedRef says otherwise (its tag notes), its GoPro module m/s.
SPEED_UNIT_MS = {"GoPro": 1.0}
KMH = 1 / 3.6


@dataclass
class GpsRows:
    """Fixes as rows ``(utc, video_t, lat, lon, speed, bearing)``, the reader's name, the fixes
    dropped per reason, and (GoPro) the second reader's verdict."""

    rows: list[tuple[float, float, float, float, float, float]]
    reader: str
    dropped: dict[str, int] = field(default_factory=dict)
    check: GpsAgreement | None = None


def _count(dropped: dict[str, int], why: str, n: int = 1) -> None:
    if n:
        dropped[why] = dropped.get(why, 0) + int(n)


def gpmf_rows(gps: GpmfGps, reader: str = "GoPro GPMF") -> GpsRows:
    """Rows of the camera's GPMF fixes (dropping those without a lock, imprecise or untimed)."""
    dropped: dict[str, int] = {}
    fix_ok = ~(np.isfinite(gps.fix) & (gps.fix < 2))
    zero = (np.abs(gps.lat) < 1e-6) & (np.abs(gps.lon) < 1e-6)
    _count(dropped, "no fix", int(np.sum(~fix_ok | zero)))
    ok = fix_ok & ~zero
    precise = ~(np.isfinite(gps.dop) & (gps.dop > MAX_DOP))
    _count(dropped, "imprecise", int(np.sum(ok & ~precise)))
    ok &= precise
    timed = np.isfinite(gps.utc)
    _count(dropped, "no time", int(np.sum(ok & ~timed)))
    ok &= timed
    rows = [
        (float(u), float(v), float(la), float(lo), float(s), math.nan)
        for u, v, la, lo, s in zip(gps.utc[ok], gps.video_t[ok], gps.lat[ok], gps.lon[ok], gps.speed[ok], strict=True)
    ]
    return GpsRows(rows, f"{reader} {gps.layout} ({gps.device})" if gps.device else f"{reader} {gps.layout}", dropped)


def gopro_gps(gps: GpmfGps, second: list | None, name: str = "") -> GpsRows:
    """The GoPro fixes after the cross-check with telemetry-parser's reading ``second`` (see
    :func:`egovid.core.camera.gps_check.compare`); raises :class:`EgovidError` when they differ."""

    verdict = compare(gps, second)
    if verdict.checked and not verdict.agree:
        raise EgovidError(
            f"the GPS of {name or 'the file'} reads differently with egovid and telemetry-parser ({verdict.detail})",
            "give its GPS as a file with --gps, and report the file",
        )
    out = gpmf_rows(gps)
    out.check = verdict
    return out


def tesla_rows(tel: TeslaTelemetry, start_utc: float) -> GpsRows:
    """Rows of a Tesla clip's per-frame positions, UTC = ``start_utc`` + frame time."""
    has = tel.has_position()
    dropped: dict[str, int] = {}
    _count(dropped, "no fix", int(np.sum(~has)))
    c = tel.channels
    rows = [
        (start_utc + float(t), float(t), float(la), float(lo), float(s), float(b))
        for t, la, lo, s, b in zip(
            tel.video_t[has], c["lat"][has], c["lon"][has], c["speed_mps"][has], c["heading_deg"][has], strict=True
        )
    ]
    return GpsRows(rows, "Tesla SEI (time of day from the clip's clock)", dropped)


# -- ExifTool, in file order -------------------------------------------------------------------
def exiftool_records(text: str) -> list[tuple[int, str, str, str]]:
    """ExifTool's ``-args`` output (``-a -G3:0``, :data:`egovid.core.camera.exif.RECORD_ARGS`) as
    ``(document, tag, value, group)`` in file order (document 0: the file's own tags; group: the
    family-0 group, ``GoPro``, ``QuickTime``…, "" where the text has none)."""
    out = []
    for line in text.splitlines():
        m = _ARG.match(line)
        if m:
            doc = int(m.group(1)[3:]) if m.group(1) else 0
            out.append((doc, m.group(3), m.group(4), m.group(2) or ""))
    return out


@dataclass
class ExifDocument:
    """One timed-metadata document: ``meta`` (SampleTime, SampleDuration as text), ``fixes``
    (tag dicts in file order), ``shared`` (tags of the whole document, see the module docstring),
    ``group`` (ExifTool's family-0 group of its GPS tags: which module read them)."""

    doc: int
    meta: dict[str, str]
    fixes: list[dict[str, str]]
    shared: dict[str, str]
    group: str = ""


def exiftool_documents(records: list[tuple[int, str, str, str]]) -> list[ExifDocument]:
    """The documents of ``records`` with their fixes paired by position."""
    by_doc: dict[int, list[tuple[str, str]]] = {}
    groups: dict[int, str] = {}
    for doc, tag, value, group in records:
        by_doc.setdefault(doc, []).append((tag, value))
        if tag.startswith("GPS"):
            groups.setdefault(doc, group)
    out = []
    for doc in sorted(by_doc):
        if doc == 0:
            continue  # the container's own tags (a single GPSPosition is no track)
        meta: dict[str, str] = {}
        fixes: list[dict[str, str]] = []
        cur: dict[str, str] = {}
        for tag, value in by_doc[doc]:
            if tag in ("SampleTime", "SampleDuration"):
                meta.setdefault(tag, value)
            elif tag.startswith("GPS"):
                if tag in cur:
                    fixes.append(cur)
                    cur = {}
                cur[tag] = value
        if cur:
            fixes.append(cur)
        fixes = [f for f in fixes if "GPSLatitude" in f or "GPSLongitude" in f or len(fixes) == 1]
        shared: dict[str, str] = {}
        if len(fixes) > 1:
            later = set().union(*(f.keys() for f in fixes[1:]))
            shared = {k: v for k, v in fixes[0].items() if k not in later}
        out.append(ExifDocument(doc, meta, fixes, shared, groups.get(doc, "")))
    return out


def speed_ms(tags: dict, group: str) -> float:
    """A fix's speed in m/s from ExifTool's tags: GPSSpeed in the unit of GPSSpeedRef (K km/h, M
    mph, N knots), else of the reading module (``group``, :data:`SPEED_UNIT_MS`: GoPro m/s, the
    QuickTime streams km/h); else the horizontal velocity (CAMM's GPSVelocityEast/North, m/s);
    NaN if none or the unit is unknown."""
    if "GPSSpeed" not in tags:
        ve, vn = as_float(tags.get("GPSVelocityEast")), as_float(tags.get("GPSVelocityNorth"))
        return math.hypot(ve, vn) if math.isfinite(ve) and math.isfinite(vn) else math.nan
    v, ref = as_float(tags["GPSSpeed"]), tags.get("GPSSpeedRef")
    if ref is None:
        factor = SPEED_UNIT_MS.get(group, KMH)
    else:
        factor = {"K": KMH, "M": 0.44704, "N": 1852 / 3600}.get(str(ref).strip().upper()[:1])
    return v * factor if factor is not None and math.isfinite(v) else math.nan


def bearing_deg(tags: dict) -> float:
    """A fix's course over ground in degrees from north: GPSTrack where true (GPSTrackRef T or
    none), else the direction of CAMM's horizontal velocity; NaN if neither."""
    if "GPSTrack" in tags:
        return as_float(tags["GPSTrack"]) if str(tags.get("GPSTrackRef", "T")).upper()[:1] == "T" else math.nan
    ve, vn = as_float(tags.get("GPSVelocityEast")), as_float(tags.get("GPSVelocityNorth"))
    if not (math.isfinite(ve) and math.isfinite(vn)) or math.hypot(ve, vn) < 0.5:
        return math.nan  # no direction when standing still
    return math.degrees(math.atan2(ve, vn)) % 360.0


def exiftool_rows(records: list[tuple[int, str, str, str]], parse_time, name: str = "") -> GpsRows:
    """Rows of ExifTool's fixes; ``parse_time(text) -> UTC seconds | None`` reads ``GPSDateTime``
    (and ``GPSDateStamp`` + ``GPSTimeStamp``)."""
    dropped: dict[str, int] = {}
    rows = []
    for d in exiftool_documents(records):
        n = len(d.fixes)
        if n == 0:
            continue
        t0, dur = as_float(d.meta.get("SampleTime")), as_float(d.meta.get("SampleDuration"))
        share = [k * dur / n if math.isfinite(dur) else 0.0 for k in range(n)]
        own = [_fix_time(f, parse_time) for f in d.fixes]
        doc_time = _fix_time(d.shared, parse_time) if d.shared else None
        for k, f in enumerate(d.fixes):
            g = {**d.shared, **f}
            lat, lon = as_float(g.get("GPSLatitude")), as_float(g.get("GPSLongitude"))
            status = str(g.get("GPSStatus", "A")).strip().upper()[:1]
            mode = as_float(g.get("GPSMeasureMode"))
            if not (math.isfinite(lat) and math.isfinite(lon)) or (abs(lat) < 1e-6 and abs(lon) < 1e-6):
                _count(dropped, "no fix")
                continue
            if status == "V" or (math.isfinite(mode) and mode < 2):
                _count(dropped, "no fix")
                continue
            dop = as_float(g.get("GPSHPositioningError", g.get("GPSDOP")))
            if math.isfinite(dop) and MAX_DOP < dop < 99.99:
                _count(dropped, "imprecise")
                continue
            utc = own[k] if "GPSDateTime" in f or "GPSTimeStamp" in f else None
            if utc is None and doc_time is not None:
                utc = doc_time + share[k]
            if utc is None:
                _count(dropped, "no time")
                continue
            vt = t0 + share[k] if math.isfinite(t0) else math.nan
            rows.append((utc, vt, lat, lon, speed_ms(g, d.group), bearing_deg(g)))
    return GpsRows(rows, f"ExifTool ({name})" if name else "ExifTool", dropped)


def _fix_time(tags: dict, parse_time) -> float | None:
    if "GPSDateTime" in tags:
        return parse_time(str(tags["GPSDateTime"]))
    if "GPSDateStamp" in tags and "GPSTimeStamp" in tags:
        ts = str(tags["GPSTimeStamp"]).strip()
        if re.fullmatch(r"\d+(\.\d+)?", ts):  # seconds of the day (-n on some formats)
            s = float(ts)
            ts = f"{int(s // 3600):02d}:{int(s % 3600 // 60):02d}:{s % 60:09.6f}"
        return parse_time(f"{tags['GPSDateStamp']} {ts}")
    return None
