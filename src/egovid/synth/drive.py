"""Synthetic dashcam drives along one route, with GPS (thesis Part III test content).

A small map of streets (polylines in metres, east/north around a fixed origin) carries the
static scene of :mod:`egovid.synth.street`. A drive is a list of legs (street, start, end); it
has its own speed profile and stops, lane offset and lane changes, light (time of day, sun,
clouds, shadows), parked and oncoming vehicles, and camera vibration. Rendering it writes:

* the video (with its start time as ``creation_time``),
* the GPS track at 1 Hz with realistic noise (correlated drift plus jitter), as GPX, NMEA 0183
  (RMC + GGA, with checksums) or CSV,
* the ground truth per frame (``*.truth.csv``: street, position along it, lateral offset), used to
  score timeline alignment.
"""

from __future__ import annotations

import csv
import datetime as dt
import functools
import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_text
from egovid.core.rotations import rot_x, rot_y, rot_z
from egovid.core.video import VideoWriter
from egovid.synth.street import StreetScene, build_scene, render_kernel

#: Map origin (latitude, longitude in degrees): West Lafayette, Indiana.
ORIGIN = (40.4237, -86.9212)
EARTH_R = 6371008.8


def enu_to_latlon(x: np.ndarray, y: np.ndarray, origin=ORIGIN) -> tuple[np.ndarray, np.ndarray]:
    """East/north metres around ``origin`` → latitude, longitude (degrees)."""
    lat0, lon0 = origin
    lat = lat0 + np.degrees(np.asarray(y) / EARTH_R)
    lon = lon0 + np.degrees(np.asarray(x) / (EARTH_R * math.cos(math.radians(lat0))))
    return lat, lon


@dataclass
class Street:
    """A street: its centre line (M, 2) in metres every 1 m, and the seed of its scene."""

    name: str
    points: np.ndarray
    seed: int

    @property
    def length(self) -> float:
        return float(len(self.points) - 1)

    def at(self, s: np.ndarray, lateral: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 2) and headings (N,) radians (east = 0, counter-clockwise) at arclengths s."""
        s = np.clip(np.asarray(s, dtype=float), 0, self.length)
        i = np.minimum(s.astype(int), len(self.points) - 2)
        f = (s - i)[:, None]
        p = self.points[i] * (1 - f) + self.points[i + 1] * f
        d = self.points[i + 1] - self.points[i]
        heading = np.arctan2(d[:, 1], d[:, 0])
        normal = np.stack([np.sin(heading), -np.cos(heading)], axis=1)  # to the right
        return p + normal * np.asarray(lateral, dtype=float).reshape(-1, 1), heading

    @functools.cached_property
    def scene(self) -> StreetScene:
        return build_scene(self.length, self.seed)


def _polyline(start, heading_deg: float, pieces: list[tuple[float, float]]) -> np.ndarray:
    """Points every metre along (length m, turn deg) pieces: straight if turn is 0, else an arc."""
    pts = [np.asarray(start, dtype=float)]
    h = math.radians(heading_deg)
    for length, turn in pieces:
        n = round(length)
        dh = math.radians(turn) / max(n, 1)
        for _ in range(n):
            h -= dh  # positive turn = to the right (clockwise)
            pts.append(pts[-1] + [math.cos(h), math.sin(h)])
    return np.array(pts)


@functools.cache
def route_map() -> dict[str, Street]:
    """The synthetic town: a main road with a right-hand bend, and a side street leaving it at
    450 m (so drives can share part of a path and split from it)."""
    main = _polyline((0.0, 0.0), 90.0, [(300, 0), (160, 45), (400, 0)])
    branch = main[450]
    side = _polyline(branch, 90.0 - 45.0 - 90.0 + 180.0, [(20, 0), (300, -10)])
    side = np.vstack([main[440:450], side])  # joins the main road just before the turn-off
    return {"main": Street("main", main, 11), "side": Street("side", side, 23)}


@dataclass
class Light:
    """Illumination of a drive: ``gain`` (B, G, R), sun azimuth relative to the street and
    elevation (degrees), shadow darkness (1 = no shadows), cloud cover 0–1, haze distance (m)."""

    gain: tuple[float, float, float] = (1.0, 1.0, 1.0)
    sun_az: float = 60.0
    sun_el: float = 35.0
    shadow_dim: float = 0.55
    cloud_cover: float = 0.3
    haze: float = 600.0

    @classmethod
    def preset(cls, name: str) -> Light:
        presets = {
            "morning": cls((0.85, 0.92, 1.05), -70.0, 15.0, 0.6, 0.2, 400.0),
            "noon": cls((1.08, 1.08, 1.08), 20.0, 65.0, 0.5, 0.25, 700.0),
            "afternoon": cls((0.92, 0.98, 1.1), 75.0, 30.0, 0.55, 0.35, 600.0),
            "cloudy": cls((0.85, 0.82, 0.78), 0.0, 50.0, 1.0, 0.95, 350.0),
            "dusk": cls((0.5, 0.45, 0.5), -80.0, 3.0, 0.9, 0.4, 300.0),
        }
        if name not in presets:
            raise EgovidError(f"unknown light {name!r}", f"choose one of {', '.join(presets)}")
        return presets[name]

    def sun(self) -> np.ndarray:
        az, el = math.radians(self.sun_az), math.radians(self.sun_el)
        return np.array([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])


@dataclass
class DriveSpec:
    """What happens on one drive (all distances in metres, speeds in m/s, times in seconds)."""

    legs: list[tuple[str, float, float]] = field(default_factory=lambda: [("main", 20.0, 300.0)])
    cruise: float = 11.0
    stops: list[tuple[float, float]] = field(default_factory=list)  # (distance from start, wait)
    lane_offset: float = 0.0
    lane_change: tuple[float, float] | None = None  # (start, end) distance along the drive
    light: Light = field(default_factory=Light)
    vehicles: int = 4
    vibration: float = 0.15
    seed: int = 0
    start_time: dt.datetime = dt.datetime(2026, 5, 4, 8, 0, 0, tzinfo=dt.UTC)


@dataclass
class DriveTruth:
    """Per-frame ground truth of a rendered drive."""

    times: np.ndarray
    leg: np.ndarray
    street: list[str]
    s: np.ndarray  # position along the street
    lateral: np.ndarray
    speed: np.ndarray
    yaw: np.ndarray

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["frame", "time", "street", "s", "lateral", "speed"])
        for k in range(len(self.times)):
            w.writerow(
                [
                    k,
                    f"{self.times[k]:.4f}",
                    self.street[k],
                    f"{self.s[k]:.3f}",
                    f"{self.lateral[k]:.3f}",
                    f"{self.speed[k]:.3f}",
                ]
            )
        return buf.getvalue()


def simulate(spec: DriveSpec, fps: float) -> DriveTruth:
    """Kinematics of a drive sampled at the video frame rate."""
    streets = route_map()
    total = sum(abs(e - s) for _, s, e in spec.legs)
    rng = np.random.default_rng(spec.seed)
    stops = sorted(spec.stops)
    dtt = 1.0 / fps
    t, d, v = 0.0, 0.0, min(spec.cruise, 6.0)
    waiting = 0.0
    rows = []
    while d < total:
        if waiting > 0:
            waiting -= dtt
            v = 0.0
            if waiting <= 0:
                stops.pop(0)
        else:
            target = spec.cruise
            if stops:
                gap = stops[0][0] - d
                target = min(target, math.sqrt(max(2 * 1.8 * max(gap - 0.3, 0.0), 0.0)))
                if gap < 0.4 and v < 0.4:
                    waiting, v = stops[0][1], 0.0
                    target = 0.0
            v += float(np.clip(target - v, -2.5 * dtt, 1.8 * dtt))
        rows.append((t, d, v))
        d += v * dtt
        t += dtt
        if t > 3600:
            raise EgovidError("drive simulation did not finish", "check the stops and the speed")
    arr = np.array(rows)
    times, dist, speed = arr[:, 0], arr[:, 1], arr[:, 2]
    legs, names, s_on = [], [], []
    starts = np.cumsum([0.0] + [abs(e - s) for _, s, e in spec.legs])
    for di in dist:
        k = int(np.searchsorted(starts, di, side="right") - 1)
        k = min(k, len(spec.legs) - 1)
        name, s0, s1 = spec.legs[k]
        legs.append(k)
        names.append(name)
        s_on.append(s0 + (di - starts[k]) * (1 if s1 >= s0 else -1))
    lateral = np.full(len(dist), 1.75 + spec.lane_offset)
    if spec.lane_change:
        a, b = spec.lane_change
        u = np.clip((dist - a) / max(b - a, 1e-6), 0, 1)
        lateral = lateral - 3.5 * u * u * (3 - 2 * u)  # into the left lane
    ds = np.gradient(dist)
    yaw = np.degrees(np.arctan2(np.gradient(lateral), np.maximum(ds, 1e-3)))
    yaw = np.where(ds > 1e-3, yaw, 0.0) + rng.normal(0, spec.vibration * 0.5, len(dist))
    for name in set(names):
        if name not in streets:
            raise EgovidError(f"unknown street {name!r}", f"use one of {', '.join(streets)}")
    return DriveTruth(times, np.array(legs), names, np.array(s_on), lateral, speed, yaw)


def _vehicles(spec: DriveSpec, truth: DriveTruth) -> list[tuple[int, float, float, float, tuple]]:
    """(leg, lateral x, z at t=0, speed along z, colour BGR) of the drive's other vehicles."""
    rng = np.random.default_rng(spec.seed + 1000)
    out = []
    for k, (_, s0, s1) in enumerate(spec.legs):
        lo, hi = sorted((s0, s1))
        for _ in range(spec.vehicles):
            parked = rng.random() < 0.5
            x = float(rng.choice([-4.4, 4.4])) if parked else -1.75
            z = float(rng.uniform(lo, hi + 150))
            speed = 0.0 if parked else -float(rng.uniform(7, 14))
            colour = tuple(float(c) for c in rng.uniform(30, 220, 3))
            out.append((k, x, z, speed, colour))
    return out


#: File suffix of each GPS format a drive's track is written in.
GPS_SUFFIXES = {"gpx": ".gpx", "nmea": ".nmea", "csv": ".gps.csv"}
#: Where the side street leaves the main road (metres along it), and where a drive joins it.
SIDE_TURN_M, SIDE_START_M = 445.0, 5.0


def route_legs(route: str, start_m: float, end_m: float) -> list[tuple[str, float, float]]:
    """The legs of a drive along ``route`` (``main``: the main road from ``start_m`` to ``end_m``;
    ``side``: the main road from ``start_m`` to the turn-off, then the side street to ``end_m``,
    at least 50 m)."""
    if route == "main":
        return [("main", start_m, end_m)]
    if route == "side":
        return [("main", start_m, SIDE_TURN_M), ("side", SIDE_START_M, max(end_m, 50.0))]
    raise EgovidError(f"unknown route {route!r}", "choose main or side")


def drive_files(out: str | os.PathLike, gps_format: str = "gpx") -> tuple[Path, Path]:
    """Where a drive rendered to the video ``out`` has its GPS track and its ground truth
    (``<stem>.gpx``/``.nmea``/``.gps.csv`` and ``<stem>.truth.csv``)."""
    out = Path(out)
    if gps_format not in GPS_SUFFIXES:
        raise EgovidError(f"unknown GPS format {gps_format!r}", "choose gpx, nmea or csv")
    return out.with_suffix(GPS_SUFFIXES[gps_format]), out.with_suffix(".truth.csv")


def render_drive(
    spec: DriveSpec,
    out: str | os.PathLike,
    *,
    width: int = 640,
    height: int = 360,
    fps: float = 30.0,
    gps_format: str = "gpx",
    noise_std: float = 1.5,
    crf: int = 14,
    progress=None,
) -> tuple[Path, Path, DriveTruth]:
    """Render a drive to ``out`` (video) with its GPS track and ground truth next to it (see
    :func:`drive_files`); returns (video, gps, truth)."""
    out = Path(out)
    gps_path, truth_path = drive_files(out, gps_format)
    truth = simulate(spec, fps)
    camera = _DriveCamera(spec, truth, width, height)
    cv2.setRNGSeed(spec.seed + 3)
    noise = np.empty((height, width, 3), np.float32)
    writer = VideoWriter(out, width, height, fps, crf=crf, preset="veryfast")
    writer.container.metadata["creation_time"] = spec.start_time.strftime("%Y-%m-%dT%H:%M:%S.000000Z")
    with writer:
        for k in range(len(truth.times)):
            img = camera.render(k)
            if noise_std > 0:
                cv2.randn(noise, 0.0, noise_std)
                img = cv2.add(img, noise, dtype=cv2.CV_8U)
            writer.write(img, truth.times[k])
            if progress is not None:
                progress(k + 1, len(truth.times))
    gps = write_gps(spec, truth, gps_path, gps_format)
    atomic_write_text(truth_path, truth.to_csv())
    return out, gps, truth


class _DriveCamera:
    """The dashcam of one drive: its pose at every frame (lane, heading, vibration) and the other
    vehicles in view; :meth:`render` draws frame k (BGR uint8, no sensor noise)."""

    def __init__(self, spec: DriveSpec, truth: DriveTruth, width: int, height: int) -> None:
        self.spec, self.truth = spec, truth
        self.width, self.height = width, height
        self.streets = route_map()
        self.intr = Intrinsics.from_hfov(width, height, 90.0)
        self.vehicles = _vehicles(spec, truth)
        self.sun = spec.light.sun()
        self.gain = np.array(spec.light.gain)
        rng = np.random.default_rng(spec.seed + 7)
        n = len(truth.times) + 8
        self.pitch_noise = np.convolve(rng.normal(0, spec.vibration, n), np.ones(5) / 5, mode="same")
        self.roll_noise = np.convolve(rng.normal(0, spec.vibration * 0.6, n), np.ones(5) / 5, mode="same")

    def render(self, k: int) -> np.ndarray:
        spec, truth, intr, light = self.spec, self.truth, self.intr, self.spec.light
        street = self.streets[truth.street[k]]
        scene = street.scene
        leg = truth.leg[k]
        forward = spec.legs[leg][2] >= spec.legs[leg][1]
        z = truth.s[k] if forward else street.length - truth.s[k]
        R = rot_y(truth.yaw[k]) @ rot_x(-self.pitch_noise[k]) @ rot_z(self.roll_noise[k]) @ _FLIP
        cam = np.array([truth.lateral[k], 1.3 + 0.01 * self.pitch_noise[k], z])
        vb, vc = self._vehicle_boxes(leg, truth.times[k])
        return render_kernel(
            self.width, self.height, intr.fx, intr.fy, intr.cx, intr.cy, R, cam,
            scene.textures, scene.block_z, scene.block_h, scene.block_tex, scene.tree_z, scene.tree_r, vb, vc,
            scene.road_tex, scene.walk_tex, scene.cloud_tex, scene.leaf_tex, self.gain, self.sun,
            light.shadow_dim, light.cloud_cover, float(spec.seed * 37 % 256), light.haze,
        )  # fmt: skip

    def _vehicle_boxes(self, leg: int, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(V, 6) boxes [x0, x1, y0, y1, z0, z1] in metres and (V, 3) BGR colours of the vehicles
        on ``leg`` at time ``t`` seconds."""
        boxes, colours = [], []
        for vleg, vx, vz, vs, col in self.vehicles:
            if vleg != leg:
                continue
            zc = vz + vs * t
            boxes.append([vx - 0.9, vx + 0.9, 0.0, 1.5, zc - 2.25, zc + 2.25])
            colours.append(col)
        return np.array(boxes, dtype=np.float64).reshape(-1, 6), np.array(colours, dtype=np.float64).reshape(-1, 3)


#: Camera axes (x right, y down) from the street's (y up).
_FLIP = np.diag([1.0, -1.0, 1.0])


def gps_samples(spec: DriveSpec, truth: DriveTruth, rate_hz: float = 1.0, seed_offset: int = 0) -> dict:
    """1 Hz GPS fixes of a drive: UTC times, latitude, longitude, speed (m/s), bearing (degrees)."""
    streets = route_map()
    rng = np.random.default_rng(spec.seed + 500 + seed_offset)
    t_end = truth.times[-1]
    ts = np.arange(-1.0, t_end + 1.5, 1.0 / rate_hz)
    idx = np.clip(np.searchsorted(truth.times, ts), 0, len(truth.times) - 1)
    xy = np.zeros((len(ts), 2))
    heading = np.zeros(len(ts))
    for i, k in enumerate(idx):
        st = streets[truth.street[k]]
        leg = truth.leg[k]
        forward = spec.legs[leg][2] >= spec.legs[leg][1]
        p, h = st.at(np.array([truth.s[k]]), np.array([truth.lateral[k] if forward else -truth.lateral[k]]))
        xy[i] = p[0]
        heading[i] = h[0] if forward else h[0] + math.pi
    drift = np.zeros((len(ts), 2))
    for i in range(1, len(ts)):
        drift[i] = 0.95 * drift[i - 1] + rng.normal(0, 2.5 * math.sqrt(1 - 0.95**2), 2)
    xy = xy + drift + rng.normal(0, 0.5, xy.shape)
    lat, lon = enu_to_latlon(xy[:, 0], xy[:, 1])
    speed = np.maximum(truth.speed[idx] + rng.normal(0, 0.15, len(ts)), 0)
    bearing = (90.0 - np.degrees(heading) + rng.normal(0, 1.5, len(ts))) % 360.0
    times = [spec.start_time + dt.timedelta(seconds=float(t)) for t in ts]
    return {"time": times, "lat": lat, "lon": lon, "speed": speed, "bearing": bearing}


def _nmea(body: str) -> str:
    cs = 0
    for ch in body:
        cs ^= ord(ch)
    return f"${body}*{cs:02X}"


def _dm(value: float, lat: bool) -> tuple[str, str]:
    hemi = ("N" if value >= 0 else "S") if lat else ("E" if value >= 0 else "W")
    v = abs(value)
    deg = int(v)
    minutes = (v - deg) * 60
    return (f"{deg:02d}{minutes:07.4f}" if lat else f"{deg:03d}{minutes:07.4f}"), hemi


def write_gps(spec: DriveSpec, truth: DriveTruth, path: Path, fmt: str = "gpx") -> Path:
    """Write the drive's GPS track as ``gpx``, ``nmea`` or ``csv``."""
    g = gps_samples(spec, truth)
    if fmt == "gpx":
        import gpxpy.gpx

        gpx = gpxpy.gpx.GPX()
        track = gpxpy.gpx.GPXTrack()
        seg = gpxpy.gpx.GPXTrackSegment()
        gpx.tracks.append(track)
        track.segments.append(seg)
        for t, la, lo, sp in zip(g["time"], g["lat"], g["lon"], g["speed"], strict=True):
            seg.points.append(gpxpy.gpx.GPXTrackPoint(float(la), float(lo), elevation=190.0, time=t, speed=float(sp)))
        return atomic_write_text(path, gpx.to_xml(version="1.0"))  # GPX 1.0 carries <speed>
    if fmt == "nmea":
        lines = []
        for t, la, lo, sp, be in zip(g["time"], g["lat"], g["lon"], g["speed"], g["bearing"], strict=True):
            hms = t.strftime("%H%M%S.%f")[:9]
            lat_s, ns = _dm(float(la), True)
            lon_s, ew = _dm(float(lo), False)
            lines.append(
                _nmea(
                    f"GPRMC,{hms},A,{lat_s},{ns},{lon_s},{ew},{sp * 1.943844:.2f},{be:.1f},{t.strftime('%d%m%y')},,,A"
                )
            )
            lines.append(_nmea(f"GPGGA,{hms},{lat_s},{ns},{lon_s},{ew},1,09,0.9,190.0,M,-33.0,M,,"))
        return atomic_write_text(path, "\r\n".join(lines) + "\r\n")
    if fmt == "csv":
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["time", "lat", "lon", "speed", "bearing"])
        for t, la, lo, sp, be in zip(g["time"], g["lat"], g["lon"], g["speed"], g["bearing"], strict=True):
            w.writerow([t.isoformat(), f"{la:.7f}", f"{lo:.7f}", f"{sp:.2f}", f"{be:.1f}"])
        return atomic_write_text(path, buf.getvalue())
    raise EgovidError(f"unknown GPS format {fmt!r}", "choose gpx, nmea or csv")
