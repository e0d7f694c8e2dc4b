"""Camera Motion Metadata (CAMM): the IMU, exposure and GPS records of Google's Street View format.

CAMM (developers.google.com/streetview/publish/camm-spec) is how Insta360 cameras, Street View
apps and other 360° and phone recorders carry their gyro and accelerometer in an MP4: a metadata
track whose handler is ``camm`` (Insta360 and others) or ``meta`` with sample entry ``camm``
(the spec's own layout). Each sample holds one or more records, all little-endian::

    uint16 reserved (0); uint16 type; payload

===== ========================================================== =================================
type  payload                                                    egovid reads it as
===== ========================================================== =================================
0     float angle_axis[3]: camera-to-world rotation vector, rad  orientation quaternions
1     int32 pixel_exposure_time, rolling_shutter_skew_time (ns)   exposure; readout time
2     float gyro[3], rad/s                                        gyro
3     float acceleration[3], m/s²                                 accelerometer
4     float position[3] (application-defined units)               position
5     double latitude, longitude (°), altitude (m)                GPS (minimal)
6     double time_gps_epoch (s), int32 fix (0/2/3), double lat,   GPS (full)
      lon (°), float altitude (m), horizontal/vertical accuracy
      (m), velocity east/north/up (m/s), speed accuracy (m/s)
7     float magnetic_field[3], µT                                 magnetometer
===== ========================================================== =================================

The spec has one record per sample; Insta360 packs several (a gyro and an accelerometer reading,
or a burst of gyro readings) into one. Every record is read: the ``k``-th of the ``n`` records of
one type in a sample is timed at ``t + k·d/n`` (``t`` the sample's presentation time, ``d`` its
duration), so a burst is spread over its sample and records of different types share the
sample's time. A record of an unknown type ends its sample (its length is not known).

**Axes.** The spec's camera frame is X right, Y down, Z forward (right-handed; rotations positive
counter-clockwise, i.e. by the right-hand rule) and the world's Y points down along gravity:
egovid's camera convention (:mod:`egovid.core.rotations`), so the records are given as stored,
with no remapping. Gyro rates are the camera's angular velocity in its own axes; the
accelerometer reads the specific force (``a - g``: at rest, 9.81 m/s² *up*, i.e. ``-9.81`` along
a level camera's y). Writers that store raw IMU axes instead are still synced, because
:func:`egovid.core.motion.gyro.sync_gyro` estimates the IMU-to-camera mapping from the video.

**Time.** Samples are timed by the track's ``stts`` (and ``ctts``) in its ``mdhd`` time scale,
placed on the movie's timeline by the edit list, and given in seconds from the video track's
first presented frame (the clock of egovid's frame times).

The camera's own telemetry read by telemetry-parser (:mod:`egovid.core.camera.telemetry`) comes
first; this reader fills in what it lacks (telemetry-parser 0.3 reads nothing from a ``camm``
handler track and only the first record of each ``meta`` sample).
"""

from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass, field

import numpy as np

from egovid.core.camera.imu import ImuSamples, OrientationSamples
from egovid.core.video.isobmff import Track, read_tracks

#: Record types.
ANGLE_AXIS, EXPOSURE, GYRO, ACCEL, POSITION, GPS_MIN, GPS, MAGNETIC = range(8)
#: Payload layout of each record type (little-endian struct formats, after the 4-byte header).
RECORD_FORMATS = {
    ANGLE_AXIS: "<3f",
    EXPOSURE: "<2i",
    GYRO: "<3f",
    ACCEL: "<3f",
    POSITION: "<3f",
    GPS_MIN: "<3d",
    GPS: "<di2d7f",
    MAGNETIC: "<3f",
}
_STRUCTS = {k: struct.Struct(f) for k, f in RECORD_FORMATS.items()}
_HEADER = struct.Struct("<HH")
#: Some writers (Google's mp4v2 example) store the exposure record as two int64.
_EXPOSURE_64 = struct.Struct("<2q")
#: Names of the fields of the GPS record (type 6), in order.
GPS_FIELDS = (
    "time_gps_epoch", "fix", "lat", "lon", "alt", "horizontal_accuracy", "vertical_accuracy",
    "velocity_east", "velocity_north", "velocity_up", "speed_accuracy",
)  # fmt: skip


def parse_sample(data: bytes) -> tuple[list[tuple[int, tuple]], int]:
    """The records of one CAMM sample as ``(type, values)`` in order, and the number of bytes
    left unread (an unknown type or a cut record ends the sample)."""
    out: list[tuple[int, tuple]] = []
    pos, n = 0, len(data)
    if n == 4 + _EXPOSURE_64.size and _HEADER.unpack_from(data, 0)[1] == EXPOSURE:
        return [(EXPOSURE, _EXPOSURE_64.unpack_from(data, 4))], 0
    while pos + 4 <= n:
        _, kind = _HEADER.unpack_from(data, pos)
        s = _STRUCTS.get(kind)
        if s is None or pos + 4 + s.size > n:
            break
        out.append((kind, s.unpack_from(data, pos + 4)))
        pos += 4 + s.size
    return out, n - pos


@dataclass(frozen=True)
class CammStream:
    """The records of one type: ``times`` (N,) seconds from the first video frame, ``values``
    (N, fields) float64 in the record's units (see the module table)."""

    times: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return len(self.times)


@dataclass(frozen=True)
class Camm:
    """Everything a file's CAMM track holds: ``streams`` by record type (only types present);
    ``track_id`` and ``handler`` of the track; ``samples`` how many samples were read and
    ``records`` how many records; ``notes`` what could not be read."""

    streams: dict[int, CammStream]
    track_id: int
    handler: str
    samples: int
    records: int
    notes: list[str] = field(default_factory=list)

    def stream(self, kind: int) -> CammStream | None:
        """The records of type ``kind`` (None where the track has none)."""
        return self.streams.get(kind)

    def imu(self) -> ImuSamples | None:
        """Gyro (and accelerometer) as :class:`ImuSamples` in camera axes (see the module's
        *Axes*); None without at least two finite gyro records. Repeated times are dropped."""
        g = self.streams.get(GYRO)
        if g is None:
            return None
        order = np.argsort(g.times, kind="stable")
        t, w = g.times[order], g.values[order]
        keep = np.concatenate([[True], np.diff(t) > 0]) & np.all(np.isfinite(w), axis=1)
        if keep.sum() < 2:
            return None
        a = self.streams.get(ACCEL)
        accel = accel_times = None
        if a is not None and len(a) >= 2:
            o = np.argsort(a.times, kind="stable")
            ok = np.all(np.isfinite(a.values[o]), axis=1)
            accel, accel_times = a.values[o][ok], a.times[o][ok]
        return ImuSamples(t[keep], w[keep], accel, accel_times)

    def readout_ms(self) -> float | None:
        """The frame readout time (first to last row, ms) from the exposure records' rolling
        shutter skew (median of the non-zero ones); None where none."""
        e = self.streams.get(EXPOSURE)
        if e is None:
            return None
        skew = e.values[:, 1]
        skew = skew[np.isfinite(skew) & (skew != 0)]
        return float(np.median(skew)) / 1e6 if len(skew) else None

    def orientation(self) -> OrientationSamples | None:
        """The camera-to-world orientations of the angle-axis records as unit quaternions
        ``(w, x, y, z)`` in camera axes; None without at least two."""
        r = self.streams.get(ANGLE_AXIS)
        if r is None or len(r) < 2:
            return None
        from scipy.spatial.transform import Rotation

        ok = np.all(np.isfinite(r.values), axis=1)
        q = Rotation.from_rotvec(r.values[ok]).as_quat()[:, [3, 0, 1, 2]]
        order = np.argsort(r.times[ok], kind="stable")
        return OrientationSamples(r.times[ok][order], q[order]) if ok.sum() >= 2 else None


def is_camm(track: Track) -> bool:
    """A CAMM track: handler ``camm``, or sample entry ``camm`` (the spec's ``meta`` track)."""
    return track.handler == "camm" or track.sample_entry == "camm"


def _dtype(kind: int) -> np.dtype:
    """The numpy record type of a payload of ``kind`` (from :data:`RECORD_FORMATS`)."""
    chars = re.sub(r"(\d+)(\w)", lambda m: m.group(2) * int(m.group(1)), RECORD_FORMATS[kind][1:])
    return np.dtype([(f"v{k}", {"f": "<f4", "d": "<f8", "i": "<i4"}[c]) for k, c in enumerate(chars)])


_DTYPES = {k: _dtype(k) for k in RECORD_FORMATS}


def decode_samples(
    buf: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, times: np.ndarray, durations: np.ndarray
) -> tuple[dict[int, CammStream], int, list[str]]:
    """The records of the samples at ``offsets`` (``sizes`` bytes) of ``buf`` (the file as uint8)
    presented at ``times`` for ``durations`` (s), by type, in file order, timed as the module
    says; also the number of records and notes on samples not read in full.

    Samples of one size that hold the same records as the first of them (a camera writes the same
    packing throughout) are decoded together as numpy records; the others one by one
    (:func:`parse_sample`: the one reading of the layout either way)."""
    parts: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}  # kind: (key, times, values)

    def add(kind: int, key: np.ndarray, t: np.ndarray, v: np.ndarray) -> None:
        parts.setdefault(kind, []).append((key, t, v))

    total, slow = 0, []
    for size in np.unique(sizes):
        idx = np.flatnonzero(sizes == size)
        o = int(offsets[idx[0]])
        recs, left = parse_sample(bytes(buf[o : o + size]))
        layout, p = [], 0
        for kind, _ in recs:
            layout.append((p, kind))
            p += 4 + _STRUCTS[kind].size
        if left or not recs or p != size:
            slow.extend(idx.tolist())
            continue
        rows = buf[offsets[idx][:, None] + np.arange(size)]
        same = np.ones(len(idx), bool)
        for p, kind in layout:
            same &= (rows[:, p + 2].astype(np.int64) | rows[:, p + 3].astype(np.int64) << 8) == kind
        slow.extend(idx[~same].tolist())
        idx, rows = idx[same], rows[same]
        counts = {kind: sum(1 for _, k in layout if k == kind) for _, kind in layout}
        seen: dict[int, int] = {}
        for j, (p, kind) in enumerate(layout):
            i = seen.get(kind, 0)
            seen[kind] = i + 1
            dt = _DTYPES[kind]
            rec = np.ascontiguousarray(rows[:, p + 4 : p + 4 + dt.itemsize]).view(dt).reshape(-1)
            vals = np.column_stack([rec[name].astype(float) for name in dt.names])
            add(kind, idx * 4096 + j, times[idx] + i * durations[idx] / counts[kind], vals)
        total += len(idx) * len(layout)
    notes: list[str] = []
    for k in sorted(slow):
        o = int(offsets[k])
        recs, left = parse_sample(bytes(buf[o : o + int(sizes[k])]))
        if left:
            notes.append(f"sample {k}: {left} bytes not read (unknown record type or cut record)")
        counts = {}
        for kind, _ in recs:
            counts[kind] = counts.get(kind, 0) + 1
        seen = {}
        for j, (kind, v) in enumerate(recs):
            i = seen.get(kind, 0)
            seen[kind] = i + 1
            t = times[k] + i * durations[k] / counts[kind]
            add(kind, np.array([k * 4096 + j]), np.array([t]), np.asarray(v, float)[None])
        total += len(recs)
    streams = {}
    for kind in sorted(parts):
        key, t, v = (np.concatenate([x[c] for x in parts[kind]]) for c in range(3))
        order = np.argsort(key, kind="stable")
        streams[kind] = CammStream(t[order].astype(float), v[order])
    return streams, total, notes[:20]


def read_camm(path: str | os.PathLike) -> Camm | None:
    """The CAMM track of an MP4/MOV file (the first, where there are several); None when the file
    has none or cannot be read as ISO-BMFF. Times are seconds from the video's first frame."""
    tracks, data = read_tracks(path)
    if data is None:
        return None
    try:
        track = next((t for t in tracks if is_camm(t)), None)
        if track is None:
            return None
        video = next((t for t in tracks if t.handler == "vide"), None)
        t0 = video.first_presentation_s() if video is not None else 0.0
        t, kept = track.presentation_times()
        inside = kept & (track.offsets + track.sizes <= len(data))
        buf = np.frombuffer(data, np.uint8)
        try:
            streams, total, notes = decode_samples(
                buf, track.offsets[inside], track.sizes[inside], t[inside] - t0,
                track.durations[inside] / track.timescale,
            )  # fmt: skip
        finally:
            del buf  # no view of the map may outlive it
    finally:
        data.close()
    cut = int((kept & ~inside).sum())
    if cut:
        notes.append(f"{cut} samples lie past the end of the file (cut)")
    n = int(inside.sum())
    return Camm(streams, track.track_id, track.handler, n, total, notes)
