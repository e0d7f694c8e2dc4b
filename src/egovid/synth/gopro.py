"""Synthetic GoPro files: GPMF telemetry written from GoPro's public format, muxed into an MP4.

For the GPS layouts of cameras nobody here recorded with, a small file is written the way the
camera writes it (github.com/gopro/gpmf-parser describes the format): a video track and a
``gpmd`` metadata track (handler "GoPro MET"), one GPMF payload per second of video. Each payload
holds a ``DEVC`` with the camera's device name and a GPS ``STRM`` in the generation's layout
(:data:`LAYOUTS`):

* HERO5 Black: ``GPS5`` at 18 Hz with ``GPSU`` written as a 16-character ``c`` string;
* HERO6 to HERO10, MAX, Fusion: the same with ``GPSU`` of type ``U`` (and ``STMP``, the payload's
  microsecond time stamp, from HERO7 and on the Fusion);
* HERO11 Black: a ``GPS5`` stream and a ``GPS9`` stream (10 Hz, per-fix days since 2000 and
  seconds of the day, DOP and fix type, ``TYPE lllllllSS``);
* HERO13 Black: ``GPS9`` only.

The fixes follow a known path (:class:`GoProTruth`), so readers can be checked against it and
against each other; a payload may be written without a fix (``GPSF 0``) or without a precision
(``GPSP 9999``), as cameras do before a lock.
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

from egovid.core.camera.gpmf import GPS9_EPOCH

EARTH_R = 6371008.8


@dataclass(frozen=True)
class GoProLayout:
    """How one GoPro generation writes its GPS: ``device`` (DVNM), which streams (``gps5``,
    ``gps9``), the type of ``GPSU`` (``"c"`` or ``"U"``), whether payloads carry ``STMP``, and the
    fix rates (Hz)."""

    camera: str
    device: str
    gps5: bool = True
    gps9: bool = False
    gpsu_type: str = "U"
    stmp: bool = False
    gps5_hz: float = 18.0
    gps9_hz: float = 10.0


#: Every GoPro generation with a GPS, by short name.
LAYOUTS = {
    "hero5": GoProLayout("HERO5 Black", "Camera", gpsu_type="c"),
    "hero6": GoProLayout("HERO6 Black", "Hero6 Black"),
    "hero7": GoProLayout("HERO7 Black", "HERO7 Black", stmp=True),
    "hero8": GoProLayout("HERO8 Black", "HERO8 Black", stmp=True),
    "hero9": GoProLayout("HERO9 Black", "HERO9 Black", stmp=True),
    "hero10": GoProLayout("HERO10 Black", "HERO10 Black", stmp=True),
    "hero11": GoProLayout("HERO11 Black", "HERO11 Black", gps9=True, stmp=True, gps5_hz=10.0),
    "hero13": GoProLayout("HERO13 Black", "HERO13 Black", gps5=False, gps9=True, stmp=True),
    "max": GoProLayout("MAX", "GoPro Max", stmp=True),
    "fusion": GoProLayout("Fusion", "FUSION", stmp=True),
}


# -- KLV writing -------------------------------------------------------------------------------
def klv(key: str, type_char: str, size: int, repeat: int, data: bytes) -> bytes:
    """One GPMF item (header, value, padding to 32 bits)."""
    if len(key) != 4 or len(data) != size * repeat:
        raise ValueError(f"{key}: {len(data)} bytes is not {size} x {repeat}")
    pad = (-len(data)) % 4
    return key.encode("ascii") + struct.pack(">cBH", type_char.encode("latin-1"), size, repeat) + data + b"\0" * pad


def nest(key: str, *children: bytes) -> bytes:
    """A nesting item (type 0) holding ``children``; its size field counts 4-byte words."""
    body = b"".join(children)
    return key.encode("ascii") + struct.pack(">BBH", 0, 4, len(body) // 4) + body


def text(key: str, value: str) -> bytes:
    """A ``c`` string item."""
    b = value.encode("latin-1")
    return klv(key, "c", 1, len(b), b)


def numbers(key: str, type_char: str, rows) -> bytes:
    """A numeric item: ``rows`` (repeat, fields), or a flat list of ``repeat`` single values."""
    fmt = {"b": "b", "B": "B", "s": "h", "S": "H", "l": "i", "L": "I", "f": "f", "d": "d", "J": "Q", "j": "q"}[
        type_char
    ]
    a = np.asarray(rows)
    a = a.reshape(-1, 1) if a.ndim == 1 else a
    per = struct.calcsize(">" + fmt)
    data = b"".join(struct.pack(">" + fmt * a.shape[1], *r.tolist()) for r in a)
    return klv(key, type_char, per * a.shape[1], a.shape[0], data)


def _gpsu(t: float) -> str:
    d = dt.datetime.fromtimestamp(t, dt.UTC)
    return d.strftime("%y%m%d%H%M%S") + f".{round(d.microsecond / 1000) % 1000:03d}"


# -- the path and the payloads -------------------------------------------------------------------
@dataclass
class GoProTruth:
    """What a synthetic file holds: per fix ``utc`` (s), ``video_t`` (s), ``lat``/``lon`` (degrees),
    ``alt`` (m), ``speed`` (m/s), ``payload`` index, ``stream`` (``"GPS5"``/``"GPS9"``); and per
    payload its ``fix`` type and ``dop`` (NaN: none reported)."""

    utc: np.ndarray
    video_t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    speed: np.ndarray
    payload: np.ndarray
    stream: np.ndarray
    fix: list[int]
    dop: list[float]
    layout: GoProLayout


def _path(t: np.ndarray, origin: tuple[float, float], speed: float) -> tuple[np.ndarray, ...]:
    """A gentle curve at ``speed`` m/s: lat, lon (degrees), alt (m) at times ``t`` (s)."""
    heading = np.radians(30.0 + 8.0 * t)
    x = np.cumsum(np.concatenate([[0.0], np.diff(t)]) * speed * np.sin(heading))
    y = np.cumsum(np.concatenate([[0.0], np.diff(t)]) * speed * np.cos(heading))
    lat = origin[0] + np.degrees(y / EARTH_R)
    lon = origin[1] + np.degrees(x / (EARTH_R * math.cos(math.radians(origin[0]))))
    return lat, lon, 120.0 + 0.5 * t


def gps_payloads(
    layout: GoProLayout,
    seconds: int,
    *,
    start_utc: float,
    origin: tuple[float, float] = (46.5191, 6.5668),
    speed: float = 6.0,
    no_fix: tuple[int, ...] = (),
    no_precision: tuple[int, ...] = (),
    payload_s: float = 1.001,
) -> tuple[list[bytes], GoProTruth]:
    """The GPMF payloads of ``seconds`` payloads of ``payload_s`` seconds, and their truth.

    ``no_fix``: payloads written with ``GPSF 0`` (no lock); ``no_precision``: with ``GPSP 9999``."""
    payloads: list[bytes] = []
    cols: dict[str, list] = {k: [] for k in ("utc", "video_t", "lat", "lon", "alt", "speed", "payload", "stream")}
    fixes, dops = [], []
    for p in range(seconds):
        t0 = p * payload_s
        fix = 0 if p in no_fix else 3
        dop = math.nan if p in no_precision else 1.2 + 0.1 * p
        fixes.append(fix)
        dops.append(dop)
        streams = []
        for name, on, hz in (("GPS5", layout.gps5, layout.gps5_hz), ("GPS9", layout.gps9, layout.gps9_hz)):
            if not on:
                continue
            n = round(hz * payload_s)
            vt = t0 + np.arange(n) * payload_s / n
            utc = start_utc + vt
            lat, lon, alt = _path(vt, origin, speed)
            spd = np.full(n, speed)
            streams.append(_gps_stream(name, layout, utc, lat, lon, alt, spd, fix, dop, t0))
            for k, v in zip(
                ("utc", "video_t", "lat", "lon", "alt", "speed"), (utc, vt, lat, lon, alt, spd), strict=True
            ):
                cols[k].append(v)
            cols["payload"].append(np.full(n, p))
            cols["stream"].append(np.full(n, name))
        devc = nest(
            "DEVC",
            numbers("DVID", "L", [1]),
            text("DVNM", layout.device),
            numbers("TICK", "L", [int(t0 * 1000)]),
            *streams,
        )
        payloads.append(devc)
    truth = GoProTruth(
        **{k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}, fix=fixes, dop=dops, layout=layout
    )
    return payloads, truth


def _gps_stream(name, layout, utc, lat, lon, alt, spd, fix, dop, t0) -> bytes:
    gpsp = 9999 if math.isnan(dop) else round(dop * 100)
    head = []
    if layout.stmp:
        head.append(numbers("STMP", "J", [int(t0 * 1e6)]))
    head.append(numbers("TSMP", "L", [len(utc)]))
    if name == "GPS5":
        u = _gpsu(float(utc[0]))
        gpsu = klv("GPSU", layout.gpsu_type, 16, 1, u.encode("ascii")[:16].ljust(16, b"0"))
        rows = np.column_stack(
            [np.round(lat * 1e7), np.round(lon * 1e7), np.round(alt * 1e3), np.round(spd * 1e3), np.round(spd * 1e2)]
        ).astype(np.int64)
        return nest(
            "STRM",
            *head,
            text("STNM", "GPS (Lat., Long., Alt., 2D speed, 3D speed)"),
            numbers("GPSF", "L", [fix]),
            gpsu,
            numbers("GPSP", "S", [gpsp]),
            text("UNIT", "degdegm\0m/sm/s"),
            numbers("SCAL", "l", [10000000, 10000000, 1000, 1000, 100]),
            numbers("GPS5", "l", rows),
        )
    days = np.floor((utc - GPS9_EPOCH) / 86400.0)
    secs = utc - GPS9_EPOCH - days * 86400.0
    rows = np.column_stack(
        [
            np.round(lat * 1e7), np.round(lon * 1e7), np.round(alt * 1e3), np.round(spd * 1e3), np.round(spd * 1e2),
            days, np.round(secs * 1e3), np.full(len(utc), gpsp), np.full(len(utc), fix),
        ]
    ).astype(np.int64)  # fmt: skip
    data = b"".join(struct.pack(">lllllllHH", *r.tolist()) for r in rows)
    return nest(
        "STRM",
        *head,
        text("STNM", "GPS (Lat., Long., Alt., 2D, 3D, days, secs, DOP, fix)"),
        text("TYPE", "lllllllSS"),
        numbers("SCAL", "l", [10000000, 10000000, 1000, 1000, 100, 1, 1000, 100, 1]),
        klv("GPS9", "?", struct.calcsize(">lllllllHH"), len(rows), data),
    )


# -- the file --------------------------------------------------------------------------------------
def write_gopro_clip(
    path: str | os.PathLike,
    generation: str,
    *,
    seconds: int = 3,
    start_utc: float | None = None,
    size: tuple[int, int] = (160, 90),
    fps: float = 29.97,
    **gps,
) -> GoProTruth:
    """Write a small MP4 with a video track and the ``gpmd`` track of ``generation`` (a key of
    :data:`LAYOUTS`), ``seconds`` payloads long; returns what it holds. ``gps`` goes to
    :func:`gps_payloads` (``no_fix``, ``no_precision``, ``origin``, ``speed``)."""
    import av

    layout = LAYOUTS[generation]
    start = start_utc if start_utc is not None else dt.datetime(2024, 5, 17, 9, 30, 12, tzinfo=dt.UTC).timestamp()
    payloads, truth = gps_payloads(layout, seconds, start_utc=start, **gps)
    out = Path(path)
    payload_ms = 1001
    with av.open(str(out), "w", format="mp4") as c:
        v = c.add_stream("libx264", rate=fractions.Fraction(round(fps * 1000), 1000))
        v.width, v.height, v.pix_fmt = size[0], size[1], "yuv420p"
        v.options = {"preset": "ultrafast"}
        d = c.add_data_stream(codec_name="bin_data")
        d.codec_tag = "gpmd"
        d.time_base = fractions.Fraction(1, 1000)
        d.metadata["handler_name"] = "GoPro MET"
        rng = np.random.default_rng(0)
        n_frames = int(seconds * payload_ms / 1000 * fps)
        pending = list(enumerate(payloads))
        for i in range(n_frames):
            img = rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
            frame = av.VideoFrame.from_ndarray(img, format="rgb24")
            frame.pts = i
            for pkt in v.encode(frame):
                c.mux(pkt)
            while pending and pending[0][0] * payload_ms <= i / fps * 1000:
                k, data = pending.pop(0)
                pkt = av.Packet(data)
                pkt.stream = d
                pkt.pts = pkt.dts = k * payload_ms
                pkt.duration = payload_ms
                pkt.time_base = fractions.Fraction(1, 1000)
                c.mux(pkt)
        for pkt in v.encode():
            c.mux(pkt)
    return truth
