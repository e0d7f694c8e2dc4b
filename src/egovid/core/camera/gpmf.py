"""GoPro's GPMF telemetry (the ``gpmd`` metadata track): KLV decoding and the camera's GPS.

GPMF (GoPro's public format, github.com/gopro/gpmf-parser) is a tree of key-length-value items,
big-endian and 32-bit aligned: a four-character key, a type character, a structure size (bytes
per sample, 8 bits) and a repeat count (16 bits), then ``size * repeat`` bytes padded to four.
Type 0 nests further items (``DEVC`` device, ``STRM`` stream); ``?`` is a structure described by
the stream's preceding ``TYPE``. Within one nest, ``SCAL`` (divisors), ``TYPE``, ``UNIT``/``SIUN``
apply to the items that follow them ("sticky" properties).

The camera's GPS, in every generation's layout:

* **GPS5** (HERO5 through HERO11, MAX, Fusion): rows of latitude, longitude (degrees·1e7),
  altitude (m), 2-D and 3-D speed (m/s), scaled by ``SCAL``; one ``GPSU`` per payload (UTC,
  ``yymmddhhmmss.sss``, written as type ``c`` by HERO5 and ``U`` later), one ``GPSF`` fix type
  (0 none, 2 2-D, 3 3-D) and one ``GPSP`` precision (DOP·100) per payload. A fix's UTC is the
  payload's GPSU plus its share of the payload's duration (the fixes are evenly spaced over the
  payload, as ExifTool and GoPro's own tools take them);
* **GPS9** (HERO11 and later, HERO13): rows described by ``TYPE`` (normally ``lllllllSS``) of
  latitude, longitude, altitude, 2-D speed, 3-D speed, days since 2000-01-01, seconds of the day
  (ms resolution), DOP and fix type: each fix carries its own UTC, fix and precision. A HERO11
  writes both streams; GPS9 is preferred where present.

A fix's video time is its payload's presentation time plus its share of the payload's duration.
A precision of 9999 (``GPSP``, or GPS9's DOP field) is GoPro's "none reported" and kept as
unknown (NaN), not as DOP 99.99.
The Karma drone's own position streams (``GLPI``/``GPRI``) are not the camera's GPS and are left
to ExifTool.
"""

from __future__ import annotations

import datetime as dt
import math
import os
import re
import struct
from dataclasses import dataclass, field

import numpy as np

#: Struct formats of GPMF's numeric type characters (big-endian).
_NUMERIC = {
    "b": "b", "B": "B", "s": "h", "S": "H", "l": "i", "L": "I",
    "f": "f", "d": "d", "j": "q", "J": "Q", "q": "i", "Q": "q",
}  # fmt: skip
#: Q15.16 / Q31.32 fixed-point types: divide the integer by this.
_FIXED = {"q": 65536.0, "Q": 4294967296.0}
#: UTC of GPS9's day count origin (2000-01-01), seconds since the epoch.
GPS9_EPOCH = dt.datetime(2000, 1, 1, tzinfo=dt.UTC).timestamp()
#: GoPro's GPSP when the receiver reports no precision.
GPSP_UNKNOWN = 9999


@dataclass(frozen=True)
class Klv:
    """One GPMF item: ``key`` (four characters), ``type`` (a type character, ``"\\0"`` for a
    nest), ``size`` bytes per sample, ``repeat`` samples, ``data`` the unpadded value bytes,
    ``children`` the nested items (type ``"\\0"``)."""

    key: str
    type: str
    size: int
    repeat: int
    data: bytes
    children: tuple[Klv, ...] = ()


def parse_klv(buf: bytes, *, depth: int = 0) -> tuple[Klv, ...]:
    """The items of a GPMF buffer (nested items parsed too). A truncated or corrupt tail ends the
    list: what was read before it is kept."""
    out: list[Klv] = []
    pos, n = 0, len(buf)
    while pos + 8 <= n:
        key = buf[pos : pos + 4]
        typ, size, repeat = buf[pos + 4], buf[pos + 5], struct.unpack_from(">H", buf, pos + 6)[0]
        length = size * repeat
        end = pos + 8 + length
        if end > n or not all(32 <= c < 127 for c in key):
            break
        data = bytes(buf[pos + 8 : end])
        k = key.decode("ascii")
        children = parse_klv(data, depth=depth + 1) if typ == 0 and depth < 8 else ()
        out.append(Klv(k, chr(typ), size, repeat, data, children))
        pos += 8 + ((length + 3) & ~3)
    return tuple(out)


def expand_type(type_def: str) -> str:
    """A ``TYPE`` string with its arrays written out: ``"f[3]L"`` → ``"fffL"``."""
    return re.sub(r"(.)\[(\d+)\]", lambda m: m.group(1) * int(m.group(2)), type_def)


def values(item: Klv, type_def: str | None = None) -> np.ndarray | list[str]:
    """An item's samples: (repeat, fields) float64 for numeric and complex (``?`` with
    ``type_def``) types; a list of strings for ``c``, ``U`` and ``F``. Raises ``ValueError``
    for a type it cannot decode."""
    t = item.type
    if t in ("c", "U", "F"):
        width = max(len(item.data) if item.size == 1 else item.size, 1)  # c 1 n: one string of n
        chunks = [item.data[i : i + width] for i in range(0, len(item.data), width)]
        return [c.split(b"\0", 1)[0].decode("latin-1") for c in chunks]
    if t == "?":
        if not type_def:
            raise ValueError(f"{item.key}: complex structure without a TYPE")
        fields = expand_type(type_def)
    elif t in _NUMERIC:
        per = struct.calcsize(">" + _NUMERIC[t])
        if item.size % per:
            raise ValueError(f"{item.key}: size {item.size} is no multiple of type {t!r}")
        fields = t * (item.size // per)
    else:
        raise ValueError(f"{item.key}: type {t!r} is not decoded")
    fmt = ">" + "".join(_NUMERIC.get(c, "") for c in fields)
    if len(fmt) - 1 != len(fields) or struct.calcsize(fmt) != item.size:
        raise ValueError(f"{item.key}: TYPE {type_def!r} does not describe {item.size} bytes")
    rows = np.array(list(struct.iter_unpack(fmt, item.data[: item.size * item.repeat])), dtype=float)
    rows = rows.reshape(item.repeat, len(fields))
    for k, c in enumerate(fields):
        if c in _FIXED:
            rows[:, k] /= _FIXED[c]
    return rows


def _scale(items: dict[str, Klv], n: int) -> np.ndarray:
    """The stream's ``SCAL`` divisors broadcast to ``n`` fields (1 where absent or zero)."""
    s = items.get("SCAL")
    if s is None:
        return np.ones(n)
    v = np.asarray(values(s), float).ravel()
    if len(v) == 1:
        v = np.full(n, v[0])
    v = np.concatenate([v, np.ones(max(0, n - len(v)))])[:n]
    return np.where(v == 0, 1.0, v)


def parse_gpsu(text: str | bytes) -> float | None:
    """GPSU ``yymmddhhmmss.sss`` (years 20xx) → UTC seconds since the epoch; None if unreadable."""
    s = text.decode("latin-1") if isinstance(text, bytes) else str(text)
    m = re.match(r"^\s*(\d\d)(\d\d)(\d\d)(\d\d)(\d\d)(\d\d(?:\.\d+)?)", s)
    if not m:
        return None
    y, mo, d, h, mi = (int(m.group(i)) for i in range(1, 6))
    try:
        t = dt.datetime(2000 + y, mo, d, h, mi, tzinfo=dt.UTC).timestamp()
    except ValueError:
        return None
    return t + float(m.group(6))


@dataclass
class GpmfGps:
    """The camera's GPS fixes of one file, in file order (arrays of equal length N).

    ``utc`` seconds since the epoch (NaN where the payload has no time), ``video_t`` seconds from
    the first video frame, ``lat``/``lon`` degrees, ``alt`` metres, ``speed``/``speed3d`` m/s,
    ``fix`` 0/2/3, ``dop`` dilution of precision (NaN unknown), ``payload`` the index of the
    payload each fix came from; ``layout`` ``"GPS5"`` or ``"GPS9"``; ``device`` the device name.
    """

    utc: np.ndarray
    video_t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    speed: np.ndarray
    speed3d: np.ndarray
    fix: np.ndarray
    dop: np.ndarray
    payload: np.ndarray
    layout: str
    device: str = ""
    notes: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.lat)


@dataclass(frozen=True)
class PayloadGps:
    """GPS of one payload: ``rows`` (n, 8) lat, lon, alt, speed, speed3d, utc (NaN: from GPSU),
    fix, dop; ``gpsu`` the payload's UTC (or None); ``layout``; ``device`` its device name."""

    rows: np.ndarray
    gpsu: float | None
    layout: str
    device: str


def payload_gps(payload: bytes) -> list[PayloadGps]:
    """The GPS streams of one GPMF payload (one entry per stream with GPS5 or GPS9 rows)."""
    out: list[PayloadGps] = []

    def walk(items: tuple[Klv, ...], device: str) -> None:
        name = next((values(k)[0] for k in items if k.key == "DVNM" and k.type == "c"), device)
        for it in items:
            if it.key == "STRM":
                found = _stream_gps(it.children, name)
                if found is not None:
                    out.append(found)
            elif it.children:
                walk(it.children, name)

    walk(parse_klv(payload), "")
    return out


def _stream_gps(items: tuple[Klv, ...], device: str) -> PayloadGps | None:
    """GPS rows of one ``STRM`` (GPS9 over GPS5 when a stream, unusually, has both). ``SCAL`` and
    ``TYPE`` apply to the rows after them; GPSU, GPSF and GPSP describe the whole payload wherever
    in the stream they stand."""
    sticky: dict[str, Klv] = {}
    found: dict[str, tuple[Klv, dict[str, Klv], str | None]] = {}
    type_def = None
    for it in items:
        if it.key in ("GPS5", "GPS9"):
            found.setdefault(it.key, (it, dict(sticky), type_def))
        elif it.key == "TYPE":
            type_def = values(it)[0] if it.type == "c" else None
        else:
            sticky[it.key] = it
    if not found:
        return None
    gpsu = None
    if "GPSU" in sticky:
        try:
            gpsu = parse_gpsu(values(sticky["GPSU"])[0])
        except (ValueError, IndexError):
            gpsu = None
    fix = _first_number(sticky.get("GPSF"))
    dop = _first_number(sticky.get("GPSP"))
    dop = math.nan if dop is None or dop >= GPSP_UNKNOWN else dop / 100.0
    if "GPS9" in found:
        it, props, tdef = found["GPS9"]
        raw = values(it, tdef or "lllllllSS")
        if raw.shape[1] < 9:
            raise ValueError(f"GPS9 has {raw.shape[1]} fields, 9 expected")
        v = raw / _scale(props, raw.shape[1])
        utc = GPS9_EPOCH + v[:, 5] * 86400.0 + v[:, 6]
        dops = np.where(raw[:, 7] >= GPSP_UNKNOWN, math.nan, v[:, 7])
        rows = np.column_stack([v[:, :5], utc, v[:, 8], dops])
        return PayloadGps(rows, gpsu, "GPS9", device)
    it, props, _ = found["GPS5"]
    raw = values(it)
    if raw.shape[1] < 5:
        raise ValueError(f"GPS5 has {raw.shape[1]} fields, 5 expected")
    v = raw[:, :5] / _scale(props, raw.shape[1])[:5]
    n = len(v)
    fixes = np.full(n, math.nan if fix is None else fix)
    return PayloadGps(np.column_stack([v, np.full(n, math.nan), fixes, np.full(n, dop)]), gpsu, "GPS5", device)


def _first_number(item: Klv | None) -> float | None:
    if item is None:
        return None
    try:
        v = values(item)
        return float(np.asarray(v, float).ravel()[0])
    except (ValueError, IndexError, TypeError):
        return None


def gps_from_payloads(payloads: list[tuple[float, float, bytes]]) -> GpmfGps | None:
    """The camera's GPS over a file's payloads ``(start, duration, bytes)`` (seconds from the first
    video frame); None when no payload has GPS5 or GPS9 rows. Payloads that cannot be decoded are
    skipped and noted."""
    per: list[tuple[int, float, float, PayloadGps]] = []
    notes: list[str] = []
    for k, (t0, dur, data) in enumerate(payloads):
        try:
            found = payload_gps(data)
        except ValueError as exc:
            notes.append(f"payload {k}: {exc}")
            continue
        per.extend((k, t0, dur, g) for g in found)
    if not per:
        return None
    layout = "GPS9" if any(g.layout == "GPS9" for *_, g in per) else "GPS5"
    per = [p for p in per if p[3].layout == layout]
    cols: list[list[np.ndarray]] = [[] for _ in range(10)]
    for k, t0, dur, g in per:
        n = len(g.rows)
        if n == 0:
            continue
        share = np.arange(n) / n * (dur if math.isfinite(dur) and dur > 0 else 0.0)
        utc = g.rows[:, 5].copy()
        if layout == "GPS5":
            utc = (g.gpsu + share) if g.gpsu is not None else np.full(n, math.nan)
        for c, arr in enumerate((utc, t0 + share, *g.rows[:, :5].T, g.rows[:, 6], g.rows[:, 7], np.full(n, k))):
            cols[c].append(np.asarray(arr, float))
    if not cols[0]:
        return None
    a = [np.concatenate(c) for c in cols]
    return GpmfGps(
        utc=a[0], video_t=a[1], lat=a[2], lon=a[3], alt=a[4], speed=a[5], speed3d=a[6], fix=a[7], dop=a[8],
        payload=a[9].astype(int), layout=layout, device=per[0][3].device, notes=notes,
    )  # fmt: skip


# -- I/O edge ----------------------------------------------------------------------------------
def gpmd_payloads(video: str | os.PathLike) -> list[tuple[float, float, bytes]]:
    """The payloads of the file's GPMF track: ``(start, duration, bytes)`` with times in seconds
    from the first video frame; empty when the file has no ``gpmd`` track (or cannot be read)."""
    import av

    try:
        container = av.open(str(video))
    except (av.error.FFmpegError, OSError):
        return []
    with container as c:
        video_streams = c.streams.video
        v0 = 0.0
        if video_streams and video_streams[0].start_time is not None and video_streams[0].time_base:
            v0 = float(video_streams[0].start_time * video_streams[0].time_base)
        tracks = [s for s in c.streams if s.type == "data" and _is_gpmd(s)]
        if not tracks:
            return []
        out = []
        try:
            for pkt in c.demux(tracks[0]):
                if pkt.size == 0 or pkt.pts is None:
                    continue
                tb = float(pkt.time_base)
                out.append((pkt.pts * tb - v0, (pkt.duration or 0) * tb, bytes(pkt)))
        except (av.error.FFmpegError, OSError):
            pass  # a damaged tail: the payloads read so far
    return out


def _is_gpmd(stream) -> bool:
    tag = getattr(stream, "codec_tag", "") or ""
    handler = str(stream.metadata.get("handler_name", ""))
    return tag == "gpmd" or "GoPro MET" in handler


def read_gpmf_gps(video: str | os.PathLike) -> GpmfGps | None:
    """The camera's own GPS of a GoPro file (GPS9 where written, else GPS5); None when none."""
    return gps_from_payloads(gpmd_payloads(video))
