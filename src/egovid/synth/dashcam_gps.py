"""Synthetic dashcam and 360-camera files whose GPS is laid out as the cameras write it.

For layouts nobody here has a file of, a small MP4 (PyAV, a few seconds of 160x90 video) gets the
camera's GPS added with :mod:`egovid.synth.mp4box`, byte for byte as ExifTool 12.57's parser
(``Image/ExifTool/QuickTimeStream.pl`` and ``QuickTime.pm``) reads it:

* ``novatek`` (Viofo A119S and most Novatek dashcams; ExifTool's ``ProcessFreeGPS`` type 1J): one
  ``freeGPS `` block per second, at the end of ``mdat`` (cameras interleave them with the video), listed as
  (offset, size) pairs in a ``gps `` box inside ``moov`` (ExifTool's ``GPSDataList``). A block:
  big-endian size, ``freeGPS ``, then at byte 48 six little-endian uint32 (hour, minute,
  second, year - 2000, month, day, UTC), status ``A``, ``N``/``S``, ``E``/``W``, and float32
  latitude and longitude in DDMM.MMMM, speed in knots and track in degrees;
* ``novatek-doubles`` (Transcend DrivePro 230): the same plus float64 latitude and longitude at
  bytes 112 and 128 and altitude at 160, which ExifTool prefers when they agree with the floats;
* ``viofo-a119v3`` (type 1C): the time's six uint32 at byte 16 (year - 2000), ``A`` at byte 40,
  float32 DDMM.MMMM latitude, longitude, knots and track from byte 44;
* ``nextbase`` (Nextbase 512GW; type 1B): the camera's date and time as 14 ASCII digits at byte
  52 and the fix as ``$GPRMC``/``$GPGGA`` text from byte 80 of the block;
* ``garmin`` (Garmin dashcams): a text track (handler ``text``) of ``PNDM`` samples, one per
  second: speed in mph (uint16) and latitude/longitude in semicircles (int32, big-endian), no
  time (ExifTool dates them as the file's CreateDate + the sample's time);
* ``blackvue`` (Pittasoft): a top-level ``free`` box holding ``sttm`` (the recording's start, ms
  since 1970, big-endian int64) and ``gps `` (NMEA text, one ``[ms]$GPRMC`` and ``[ms]$GPGGA``
  line pair per second, the bracket the fix's time on the same clock as ``sttm``);
* ``camm6`` / ``camm5`` (Google's Camera Motion Metadata, written by Insta360 and Street View
  apps): a ``camm`` data track, one sample per fix, a little-endian record: reserved uint16,
  type uint16, then for type 6 the fix's time (float64), fix type (int32), latitude and
  longitude (float64), altitude and accuracies and velocities (float32); for type 5 latitude,
  longitude, altitude as float64 and no time. ``epoch`` says whether type 6 counts seconds from
  1970 (what Insta360 writes, per ExifTool) or, as the specification says, GPS time since
  1980-01-06 (GPS time runs :data:`GPS_LEAP_S` seconds ahead of UTC).

:class:`DashcamGpsTruth` holds the fixes as they are stored (DDMM float32 rounding included), so a
reader's output can be compared with them to 1e-6 degrees.
"""

from __future__ import annotations

import datetime as dt
import fractions
import math
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from egovid.core.camera.camm import GPS, GPS_MIN
from egovid.synth.camm import camm_record
from egovid.synth.gopro import _path
from egovid.synth.mp4box import add_boxes, add_to_mdat, box, set_handler

KNOT = 1852.0 / 3600.0  # m/s
MPH = 0.44704  # m/s
#: Seconds from 1970-01-01 to the GPS epoch (1980-01-06).
GPS_EPOCH_UNIX = 315964800.0
#: GPS time minus UTC since 2017 (leap seconds).
GPS_LEAP_S = 18.0

FREEGPS = ("novatek", "novatek-doubles", "viofo-a119v3", "nextbase")
LAYOUTS = (*FREEGPS, "blackvue", "garmin", "camm6", "camm5")


@dataclass
class DashcamGpsTruth:
    """What a synthetic file holds, per fix: ``utc`` (s since 1970), ``video_t`` (s from the
    first frame; NaN where the layout does not say), ``lat``/``lon`` (degrees, as stored),
    ``speed`` (m/s; NaN where not stored), ``track`` (degrees; NaN where not stored); ``layout``;
    ``start_utc`` the first frame's UTC (s)."""

    utc: np.ndarray
    video_t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    speed: np.ndarray
    track: np.ndarray
    layout: str
    start_utc: float


def ddmm(deg: np.ndarray) -> np.ndarray:
    """Degrees → the NMEA/Novatek DDMM.MMMM number (absolute value)."""
    a = np.abs(np.asarray(deg, dtype=float))
    d = np.floor(a)
    return d * 100.0 + (a - d) * 60.0


def from_ddmm(v: np.ndarray) -> np.ndarray:
    """DDMM.MMMM → degrees (absolute), as ExifTool's ``ConvertLatLon`` does."""
    v = np.asarray(v, dtype=float)
    d = np.floor(v / 100.0)
    return d + (v - d * 100.0) / 60.0


def _f32(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float32).astype(float)


# -- Novatek freeGPS -------------------------------------------------------------------------
def novatek_block(layout: str, utc: float, lat: float, lon: float, knots: float, track: float, alt: float) -> bytes:
    """One ``freeGPS `` block (a ``free`` box, 256 bytes) of ``layout`` (one of :data:`FREEGPS`);
    ``utc`` whole seconds."""
    t = dt.datetime.fromtimestamp(utc, dt.UTC)
    when = (t.hour, t.minute, t.second, t.year - 2000, t.month, t.day)
    refs = b"A" + (b"N" if lat >= 0 else b"S") + (b"E" if lon >= 0 else b"W") + b"\0"
    la, lo = float(ddmm(lat)), float(ddmm(lon))
    body = bytearray(256 - 8)  # after the box header; "GPS " first
    body[0:4] = b"GPS "
    body[4:8] = struct.pack("<I", 0x4C)
    if layout in ("novatek", "novatek-doubles"):
        at = 48 - 8
        body[at : at + 24] = struct.pack("<6I", *when)
        body[at + 24 : at + 28] = refs
        body[at + 28 : at + 44] = struct.pack("<4f", la, lo, knots, track)
        if layout == "novatek-doubles":
            body[0x70 - 8 : 0x78 - 8] = struct.pack("<d", la)
            body[0x80 - 8 : 0x88 - 8] = struct.pack("<d", lo)
            body[0xA0 - 8 : 0xA8 - 8] = struct.pack("<d", alt)
    elif layout == "nextbase":
        at = 52 - 8
        body[at : at + 14] = t.strftime("%Y%m%d%H%M%S").encode("ascii")  # the camera's clock
        rmc, gga = nmea_fix(utc, lat, lon, knots, track, alt)
        text = f"{rmc}\r\n{gga}\r\n".encode("ascii")
        body[80 - 8 : 80 - 8 + len(text)] = text
    elif layout == "viofo-a119v3":
        at = 16 - 8
        body[at : at + 24] = struct.pack("<6I", *when)
        body[40 - 8 : 44 - 8] = refs
        body[44 - 8 : 60 - 8] = struct.pack("<4f", la, lo, knots, track)
    else:
        raise ValueError(f"not a freeGPS layout: {layout}")
    return box("free", bytes(body))


def gps_data_list(entries: list[tuple[int, int]]) -> bytes:
    """The ``gps `` box of ``moov``: version word, count, then (offset, size) big-endian pairs."""
    payload = struct.pack(">II", 0x101, len(entries)) + b"".join(struct.pack(">II", o, s) for o, s in entries)
    return box("gps ", payload)


# -- BlackVue NMEA -----------------------------------------------------------------------------
def nmea(body: str) -> str:
    """``$body*CS`` with its checksum."""
    cs = 0
    for ch in body.encode("ascii"):
        cs ^= ch
    return f"${body}*{cs:02X}"


def _nmea_pos(deg: float, width: int, pos: str, neg: str) -> tuple[str, str]:
    m = float(ddmm(deg))
    return f"{m:0{width + 6}.5f}", pos if deg >= 0 else neg


def nmea_fix(utc: float, lat: float, lon: float, knots: float, track: float, alt: float) -> tuple[str, str]:
    """The ``$GPRMC`` and ``$GPGGA`` sentences of one fix (minutes to 5 decimals, time to 10 ms)."""
    d = dt.datetime.fromtimestamp(float(utc), dt.UTC)
    hms = d.strftime("%H%M%S") + f".{round(d.microsecond / 1e4):02d}"
    la, ns = _nmea_pos(lat, 4, "N", "S")
    lo, ew = _nmea_pos(lon, 5, "E", "W")
    rmc = nmea(f"GPRMC,{hms},A,{la},{ns},{lo},{ew},{knots:.3f},{track:.2f},{d:%d%m%y},,,A")
    return rmc, nmea(f"GPGGA,{hms},{la},{ns},{lo},{ew},1,09,0.90,{alt:.1f},M,47.3,M,,")


def nmea_truth(lat, lon, knots, track) -> tuple[np.ndarray, ...]:
    """What :func:`nmea_fix` stores: degrees from 5-decimal minutes, m/s from 3-decimal knots,
    course to 2 decimals."""
    s_lat, s_lon = from_ddmm(np.round(ddmm(lat), 5)), from_ddmm(np.round(ddmm(lon), 5))
    return np.sign(lat) * s_lat, np.sign(lon) * s_lon, np.round(knots, 3) * KNOT, np.round(track, 2)


def blackvue_gps_text(utc, lat, lon, knots, track, alt, start_ms: int, void: tuple[int, ...] = ()) -> str:
    """The NMEA text of BlackVue's ``gps `` box: per fix ``[ms]$GPRMC`` and ``[ms]$GPGGA``;
    fixes in ``void`` written with status V and no position (before a lock)."""
    lines = []
    for k, u in enumerate(utc):
        d = dt.datetime.fromtimestamp(float(u), dt.UTC)
        hms = d.strftime("%H%M%S") + f".{round(d.microsecond / 1e4):02d}"
        ms = start_ms + round((float(u) - start_ms / 1000.0) * 1000.0)
        if k in void:
            lines.append(f"[{ms}]" + nmea(f"GPRMC,{hms},V,,,,,,,{d:%d%m%y},,,N"))
            lines.append(f"[{ms}]" + nmea(f"GPGGA,{hms},,,,,0,00,99.99,,,,,,"))
            continue
        rmc, gga = nmea_fix(float(u), lat[k], lon[k], knots[k], track[k], alt[k])
        lines += [f"[{ms}]{rmc}", f"[{ms}]{gga}"]
    return "\r\n".join(lines) + "\r\n"


# -- Garmin -----------------------------------------------------------------------------------
def garmin_pndm(mph: int, lat_semi: int, lon_semi: int) -> bytes:
    """A Garmin ``PNDM`` text-track sample (big-endian): 4-byte size, ``PNDM``, 4 unknown bytes,
    speed (uint16, mph), 2 bytes, latitude and longitude (int32 semicircles, 2^31 = 180 deg)."""
    body = b"PNDM" + b"\0" * 4 + struct.pack(">H2xii", mph, lat_semi, lon_semi) + b"\0" * 8
    return struct.pack(">I", 4 + len(body)) + body


# -- CAMM ----------------------------------------------------------------------------------------
def camm6(t: float, fix: int, lat: float, lon: float, alt: float, v_east: float, v_north: float) -> bytes:
    """A CAMM type 6 record (60 bytes, little-endian)."""
    return camm_record(GPS, t, fix, lat, lon, alt, 2.5, 4.0, v_east, v_north, 0.0, 0.3)


def camm5(lat: float, lon: float, alt: float) -> bytes:
    """A CAMM type 5 record (28 bytes, little-endian)."""
    return camm_record(GPS_MIN, lat, lon, alt)


# -- the file ----------------------------------------------------------------------------------
def _video(path: Path, seconds: float, start_utc: float, size, fps: float, samples=None, tag: str = "") -> None:
    """A small H.264 MP4 (creation time ``start_utc``) and, if ``samples`` ((ms, bytes) pairs),
    a data track of codec tag ``tag`` holding them (1 ms time base)."""
    import av

    with av.open(str(path), "w", format="mp4") as c:
        c.metadata["creation_time"] = dt.datetime.fromtimestamp(start_utc, dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.000000Z")
        v = c.add_stream("libx264", rate=fractions.Fraction(round(fps * 1000), 1000))
        v.width, v.height, v.pix_fmt = size[0], size[1], "yuv420p"
        v.options = {"preset": "ultrafast"}
        d = None
        if samples:
            d = c.add_data_stream(codec_name="bin_data")
            d.codec_tag = tag
            d.metadata["handler_name"] = {"camm": "CameraMetadataMotionHandler"}.get(
                tag, "DataHandler"
            )  # not FFmpeg's "GoPro MET"
            d.time_base = fractions.Fraction(1, 1000)
        pending = list(samples or [])
        for i in range(round(seconds * fps)):
            img = np.zeros((size[1], size[0], 3), np.uint8)
            img[:, (4 * i) % size[0] :] = (90, 140, 200)  # a moving edge: tiny after encoding
            frame = av.VideoFrame.from_ndarray(img, "rgb24")
            frame.pts = i
            for pkt in v.encode(frame):
                c.mux(pkt)
            while pending and pending[0][0] <= i / fps * 1000:
                ms, data = pending.pop(0)
                pkt = av.Packet(data)
                pkt.stream = d
                pkt.pts = pkt.dts = ms
                pkt.time_base = fractions.Fraction(1, 1000)
                c.mux(pkt)
        for pkt in v.encode():
            c.mux(pkt)
        for ms, data in pending:  # a sample at the clip's end
            pkt = av.Packet(data)
            pkt.stream = d
            pkt.pts = pkt.dts = ms
            pkt.time_base = fractions.Fraction(1, 1000)
            c.mux(pkt)


def write_dashcam_gps_clip(
    path: str | os.PathLike,
    layout: str,
    *,
    seconds: int = 4,
    start_utc: float | None = None,
    origin: tuple[float, float] = (46.5191, 6.5668),
    speed: float = 12.0,
    void: tuple[int, ...] = (),
    epoch: str = "unix",
    clock_h: float = 0.0,
    hz: float = 1.0,
    size: tuple[int, int] = (160, 90),
    fps: float = 30.0,
) -> DashcamGpsTruth:
    """Write a small MP4 whose GPS is in ``layout`` (one of :data:`LAYOUTS`, see the module
    docstring): ``seconds`` of video, fixes at ``hz`` (1 Hz for the dashcams; CAMM any rate)
    along a curve from ``origin`` (degrees) at ``speed`` m/s, starting at ``start_utc`` (whole
    seconds; default 2024-05-17 09:30:12 UTC). ``void``: fix indices written without a fix
    (BlackVue status V, CAMM fix type 0), left out of the truth. ``epoch`` (camm6): ``"unix"``
    or ``"gps"``. ``clock_h``: the camera's clock minus UTC in hours, written into the container's
    creation time (a dashcam set to local time; not for ``garmin``/``camm5``, whose fixes ExifTool
    dates by that clock). Returns the stored fixes."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; one of {', '.join(LAYOUTS)}")
    if clock_h and layout in ("garmin", "camm5"):
        raise ValueError(f"{layout}: its fixes are dated by the camera clock; clock_h must be 0")
    out = Path(path)
    start = start_utc if start_utc is not None else dt.datetime(2024, 5, 17, 9, 30, 12, tzinfo=dt.UTC).timestamp()
    n = round(seconds * hz) + 1  # a fix at either end of the clip, as the cameras write
    vt = np.arange(n) / hz
    utc = start + vt
    lat, lon, alt = _path(vt, origin, speed)
    heading = np.degrees(np.radians(30.0 + 8.0 * vt)) % 360.0
    knots = np.full(n, speed / KNOT)
    keep = np.array([k not in void for k in range(n)])
    nan = np.full(n, np.nan)

    if layout in FREEGPS:
        _video(out, seconds, start + clock_h * 3600.0, size, fps)
        blocks = [
            novatek_block(layout, float(u), la, lo, kn, tr, al)
            for u, la, lo, kn, tr, al in zip(utc, lat, lon, knots, heading, alt, strict=True)
        ]
        sizes = [len(b) for b in blocks]
        add_to_mdat(out, blocks, lambda offsets: gps_data_list(list(zip(offsets, sizes, strict=True))))
        if layout == "nextbase":
            truth = (utc, nan, *nmea_truth(lat, lon, knots, heading))
        else:
            s = (lambda v: v) if layout == "novatek-doubles" else _f32
            s_lat, s_lon = from_ddmm(s(ddmm(lat))), from_ddmm(s(ddmm(lon)))
            truth = (utc, nan, np.sign(lat) * s_lat, np.sign(lon) * s_lon, _f32(knots) * KNOT, _f32(heading))
    elif layout == "blackvue":
        _video(out, seconds, start + clock_h * 3600.0, size, fps)
        start_ms = round(start * 1000)
        text = blackvue_gps_text(utc, lat, lon, knots, heading, alt, start_ms, void).encode("ascii")
        free = box("free", box("sttm", struct.pack(">Q", start_ms)) + box("gps ", text + b"\0" * 64))
        add_boxes(out, b"", [free])  # (real files have it before mdat: ExifTool reads it anywhere)
        truth = (utc, vt, *nmea_truth(lat, lon, knots, heading))
    elif layout == "garmin":
        mph = np.round(speed / MPH * np.ones(n))
        semi = np.round(np.column_stack([lat, lon]) * 2**31 / 180.0).astype(np.int64)
        samples = [(round(vt[k] * 1000), garmin_pndm(int(mph[k]), *semi[k])) for k in range(n)]
        _video(out, seconds, start + clock_h * 3600.0, size, fps, samples, "text")
        set_handler(out, "meta", "text")
        s_lat, s_lon = semi[:, 0] * 180.0 / 2**31, semi[:, 1] * 180.0 / 2**31
        truth = (utc, vt, s_lat, s_lon, mph * MPH, nan)
    else:
        samples = []
        for k in range(n):
            if layout == "camm6":
                t = utc[k] if epoch == "unix" else utc[k] - GPS_EPOCH_UNIX + GPS_LEAP_S
                h = math.radians(heading[k])
                rec = camm6(
                    float(t),
                    0 if k in void else 3,
                    float(lat[k]),
                    float(lon[k]),
                    float(alt[k]),
                    speed * math.sin(h),
                    speed * math.cos(h),
                )
            else:
                rec = camm5(float(lat[k]), float(lon[k]), float(alt[k]))
            samples.append((round(vt[k] * 1000), rec))
        _video(out, seconds, start + clock_h * 3600.0, size, fps, samples, "camm")
        set_handler(out, "meta", "camm")  # PyAV writes "meta"; the specification says "camm"
        if layout == "camm6":
            h = np.radians(heading)
            truth = (utc, vt, lat, lon, np.hypot(_f32(speed * np.sin(h)), _f32(speed * np.cos(h))), heading)
        else:
            truth = (utc, vt, lat, lon, nan, nan)
    cols = [np.asarray(c, dtype=float)[keep] for c in truth]
    return DashcamGpsTruth(*cols, layout=layout, start_utc=start)
