"""``dashcam find``: which stretches of which drives were near a place, inside a box, or in a time
window.

The catalogue's spatial index (:meth:`~egovid.dashcam.archive.fleetstore.FleetStore.candidates`: an SQLite
R*Tree, or PostGIS / a GiST index in PostgreSQL, over chunks of each drive's GPS track in longitude,
latitude and time) names the drives that may match; :func:`stretches` then decides frame by frame
on the drive's own track: each frame's position is the GPS track interpolated at the frame's UTC
time, its distance to ``--near`` is measured on a local tangent plane (metres), and consecutive
matching frames (gaps under ``bridge_s`` seconds bridged: GPS jitter at the edge of the radius)
become one stretch.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from egovid.core.errors import EgovidError
from egovid.dashcam.archive.fleetstore import FleetStore
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.route.clock import iso
from egovid.dashcam.route.tracks import project


@dataclass(frozen=True)
class Query:
    """What to look for; every given criterion must hold. ``near``: (lat, lon) degrees with
    ``radius`` metres; ``bbox``: (west, south, east, north) degrees; ``t_from`` / ``t_to``: UTC
    seconds."""

    near: tuple[float, float] | None = None
    radius: float = 50.0
    bbox: tuple[float, float, float, float] | None = None
    t_from: float | None = None
    t_to: float | None = None

    def __post_init__(self) -> None:
        if self.near is None and self.bbox is None and self.t_from is None and self.t_to is None:
            raise EgovidError("nothing to find", "give --near LAT,LON, --bbox W,S,E,N or --from/--to TIME")
        if self.near is not None:
            lat, lon = self.near
            if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90 and abs(lon) <= 180):
                raise EgovidError(
                    f"--near {lat},{lon} is not a position", "write LAT,LON in degrees, e.g. 48.137,11.575"
                )
        if not (math.isfinite(self.radius) and 0 < self.radius <= 100_000):
            raise EgovidError(f"--radius {self.radius} m is not usable", "give metres between 0 and 100000")
        if self.bbox is not None:
            w, s, e, n = self.bbox
            if not all(map(math.isfinite, self.bbox)) or not (-180 <= w < e <= 180 and -90 <= s < n <= 90):
                raise EgovidError(
                    f"--bbox {','.join(f'{v:g}' for v in self.bbox)} is not a box",
                    "write WEST,SOUTH,EAST,NORTH in degrees with west < east and south < north",
                )
        if self.t_from is not None and self.t_to is not None and self.t_to <= self.t_from:
            raise EgovidError("--to is not after --from", "give a time window that ends after it starts")

    def box(self) -> tuple[float, float, float, float] | None:
        """The (west, south, east, north) degrees that hold every match (for the spatial index)."""
        boxes = []
        if self.bbox is not None:
            boxes.append(self.bbox)
        if self.near is not None:
            lat, lon = self.near
            dlat = math.degrees(self.radius / 6371008.8)
            dlon = dlat / max(math.cos(math.radians(lat)), 1e-6)
            boxes.append((lon - dlon, lat - dlat, lon + dlon, lat + dlat))
        if not boxes:
            return None
        w, s, e, n = (
            max(b[0] for b in boxes),
            max(b[1] for b in boxes),
            min(b[2] for b in boxes),
            min(b[3] for b in boxes),
        )
        return (w, s, e, n) if w <= e and s <= n else (0.0, 0.0, -1.0, -1.0)


@dataclass
class Stretch:
    """A stretch of a drive that matches: its frames [frame_start, frame_end), UTC start and end
    (seconds), the closest distance to ``--near`` (metres; None without it) and the position of the
    closest (or first) frame."""

    drive: str
    kind: str
    frame_start: int
    frame_end: int
    start_utc: float
    end_utc: float
    distance_m: float | None
    lat: float
    lon: float

    @property
    def frames(self) -> int:
        return self.frame_end - self.frame_start

    def to_dict(self) -> dict:
        d = asdict(self)
        d.update(frames=self.frames, start=iso(self.start_utc), end=iso(self.end_utc))
        return d


def frame_positions(frame_utc: np.ndarray, t: np.ndarray, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """(N, 2) lat/lon (degrees) of each frame: the track interpolated at the frames' UTC times (held
    at the ends)."""
    return np.stack([np.interp(frame_utc, t, lat), np.interp(frame_utc, t, lon)], axis=1)


def _runs(mask: np.ndarray, bridge: int) -> list[tuple[int, int]]:
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        return []
    cuts = np.flatnonzero(np.diff(idx) > bridge + 1)
    starts = np.concatenate([[idx[0]], idx[cuts + 1]])
    ends = np.concatenate([idx[cuts], [idx[-1]]]) + 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def stretches(
    q: Query,
    drive: str,
    kind: str,
    frame_utc: np.ndarray,
    t: np.ndarray,
    lat: np.ndarray,
    lon: np.ndarray,
    *,
    fps: float = 30.0,
    bridge_s: float = 1.0,
) -> list[Stretch]:
    """The stretches of one drive matching ``q``. ``frame_utc``: UTC seconds of each frame; ``t``,
    ``lat``, ``lon``: the drive's GPS fixes."""
    n = len(frame_utc)
    mask = np.ones(n, bool)
    if q.t_from is not None:
        mask &= frame_utc >= q.t_from
    if q.t_to is not None:
        mask &= frame_utc < q.t_to
    pos = frame_positions(frame_utc, t, lat, lon)
    if q.bbox is not None:
        w, s, e, nn = q.bbox
        mask &= (pos[:, 1] >= w) & (pos[:, 1] <= e) & (pos[:, 0] >= s) & (pos[:, 0] <= nn)
    dist = None
    if q.near is not None:
        xy = project(pos[:, 0], pos[:, 1], q.near)
        dist = np.hypot(xy[:, 0], xy[:, 1])
        mask &= dist <= q.radius
    out = []
    for f0, f1 in _runs(mask, max(0, round(bridge_s * fps))):
        k = f0 + int(np.argmin(dist[f0:f1])) if dist is not None else f0
        out.append(
            Stretch(
                drive,
                kind,
                f0,
                f1,
                float(frame_utc[f0]),
                float(frame_utc[f1 - 1]),
                float(dist[k]) if dist is not None else None,
                float(pos[k, 0]),
                float(pos[k, 1]),
            )
        )
    return out


def search(archive: Archive, q: Query) -> list[Stretch]:
    """``egovid dashcam find``: every matching stretch of the archive's live drives, by start time:
    the spatial index names the candidates (:meth:`FleetStore.candidates`), each candidate's own
    track decides."""
    fleet = FleetStore(archive.catalogue)
    near = (q.near[0], q.near[1], q.radius) if q.near is not None else None
    ids = set(fleet.candidates(q.box(), q.t_from, q.t_to, near))
    out: list[Stretch] = []
    for d in fleet.live_drives():
        if d.id not in ids:
            continue
        track = fleet.track(d.id)
        if track is None:
            continue
        kind = fleet.meta(d.id).kind
        out += stretches(q, d.name, kind, fleet.frame_utc(d.id, d.fps), *track, fps=d.fps)
    return sorted(out, key=lambda s: (s.start_utc, s.drive))
