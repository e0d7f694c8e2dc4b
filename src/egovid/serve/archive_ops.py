"""The web app's one door into the dashcam archive: every call to the archive's library functions
(open, list, tracks, decode, find, clip, lock, forget) is made here, so the app, the CLI and the
tests run the same operations.

Each thread that asks opens the archive once (an SQLite connection belongs to its thread; a
PostgreSQL connection is cheap to keep): :class:`ArchiveOps` keeps one per thread and closes them
all at the end. Drives are named by their catalogue id in the API; a forgotten drive (a hidden
reference) is never listed, streamed, found or changed.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.video import ColourTags
from egovid.dashcam.archive import readings
from egovid.dashcam.archive.fleetstore import FleetStore
from egovid.dashcam.archive.store import open_archive
from egovid.dashcam.clip import plan_clip, write_clip
from egovid.dashcam.extract import SegmentSnapshot, drive_frames, read_ahead, reference_segments
from egovid.dashcam.find import Query, search
from egovid.dashcam.forget import forget, set_lock
from egovid.dashcam.mapview import simplified_track
from egovid.dashcam.report import archive_report
from egovid.dashcam.route.clock import iso
from egovid.dashcam.route.tracks import derive_speed_bearing
from egovid.serve.streams import StreamSource


class DriveNotFoundError(EgovidError):
    """No such (live) drive."""


def _iso(t: float) -> str:

    return iso(t)


class ArchiveOps:
    """An open archive for the web app (see the module docstring)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self._local = threading.local()
        self._opened: list = []
        self._lock = threading.Lock()
        self._open()  # a bad archive is an error now, before the server starts

    # -- opening ----------------------------------------------------------------------------------
    def _open(self):
        got = getattr(self._local, "archive", None)
        if got is None:
            ar = open_archive(self.root)
            got = (ar, FleetStore(ar.catalogue))
            self._local.archive = got
            with self._lock:
                self._opened.append(ar)
        return got

    def close(self) -> None:
        with self._lock:
            for ar in self._opened:
                with contextlib.suppress(Exception):  # a connection of a thread that is gone
                    ar.close()
            self._opened.clear()

    def _drive(self, drive_id: int):
        ar, fleet = self._open()
        d = ar.catalogue.drive(int(drive_id))
        if d is None or fleet.meta(d.id).state != "live":
            raise DriveNotFoundError(
                f"no drive {drive_id} in the archive", "reload the page: the list shows the drives there are"
            )
        return d

    # -- what the archive holds -------------------------------------------------------------------
    def overview(self) -> dict:
        """Every live drive (id, name, kind, lock, start, length, size, storage, saving, paths,
        simplified track for the map) and the archive's totals."""

        ar, fleet = self._open()
        rep = archive_report(ar)
        by_name = {r["drive"]: r for r in rep["drives"]}
        lengths = {p["path"]: p["length_m"] for p in rep["paths"]}
        rows = []
        for d in fleet.live_drives():
            meta = fleet.meta(d.id)
            r = by_name.get(d.name, {})
            segs = ar.segments(d.id)
            track = fleet.track(d.id)
            pts = np.round(simplified_track(track[1], track[2], 2.0), 7).tolist() if track is not None else []
            paths = sorted({s.path_id for s in ar.catalogue.sequences(drive_id=d.id)})
            rows.append({
                "id": d.id, "name": d.name, "kind": meta.kind, "channel": meta.channel,
                "locked": meta.locked, "lock_note": meta.lock_note,
                "start_utc": d.start_utc, "start": _iso(d.start_utc), "day": _iso(d.start_utc)[:10],
                "duration": d.frames / d.fps, "frames": d.frames, "fps": d.fps, "width": d.width, "height": d.height,
                "video_bytes": sum(s.bytes for s in segs), "streams_bytes": meta.streams_bytes,
                "bytes": sum(s.bytes for s in segs) + meta.streams_bytes,
                "modes": sorted({s.mode for s in segs}), "joint_frames": r.get("joint_frames", 0),
                "saving": r.get("saving_on_joint_frames"), "references": r.get("references", []),
                "paths": paths, "parts": len(fleet.parts(d.id)), "track": pts,
            })  # fmt: skip
        return {
            "archive": self.root.resolve().name,
            "drives": rows,
            "paths": [{"id": k, "length_m": v} for k, v in sorted(lengths.items())],
            "stored_bytes": sum(r["bytes"] for r in rows),
            "blob_bytes": rep["blob_bytes"],
        }

    def track(self, drive_id: int) -> dict:
        """The GPS fixes of a drive on its video clock: ``t`` (seconds from the drive's first frame),
        ``lat``/``lon`` (degrees), ``speed`` (m/s) and ``accel`` (m/s², along the track): those the
        car recorded where it did (a Tesla's readings: its speed and acceleration along its x axis,
        taken at each fix's time; ``speed_source`` says which), else derived from the positions
        (smoothed over ~5 fixes, as ingest does for logs without speed)."""

        d = self._drive(drive_id)
        ar, fleet = self._open()
        track = fleet.track(d.id)
        if track is None:
            return {"drive": d.id, "t": [], "lat": [], "lon": [], "speed": [], "accel": [], "source": "none"}
        t, lat, lon = track
        futc = fleet.frame_utc(d.id, d.fps)
        video_t = np.interp(t, futc, np.arange(len(futc)) / d.fps)
        speed, _ = derive_speed_bearing(t, lat, lon, None, None)
        accel = np.gradient(speed, t) if len(t) > 1 else np.zeros(len(t))
        speed_source = "gps"
        rec = readings.get(ar.catalogue, d.id)
        if rec is not None and len(rec) and "speed_mps" in rec.channels and "accel_x" in rec.channels:
            ok = np.isfinite(rec.channels["speed_mps"]) & np.isfinite(rec.channels["accel_x"])
            if ok.any():
                speed = np.interp(video_t, rec.t[ok], rec.channels["speed_mps"][ok])
                accel = np.interp(video_t, rec.t[ok], rec.channels["accel_x"][ok])
                speed_source = f"recorded ({rec.source})"
        return {
            "drive": d.id,
            "t": np.round(video_t, 3).tolist(),
            "lat": np.round(lat, 7).tolist(),
            "lon": np.round(lon, 7).tolist(),
            "speed": np.round(speed, 2).tolist(),
            "accel": np.round(accel, 2).tolist(),
            "utc0": float(futc[0]) if len(futc) else d.start_utc,
            "source": "gps",
            "speed_source": speed_source,
        }

    # -- decoding -----------------------------------------------------------------------------------
    def stream_source(self, drive_id: int) -> StreamSource:
        """The drive as a :class:`StreamSource`: the segments of the drive and of every drive it is
        coded against, taken now (a snapshot: the producer thread never opens the catalogue), and
        the archive's checked decoder (every random-access run compared with the encoder's digest),
        run in a thread of its own up to 8 frames ahead of the encoder. Chunks are one
        random-access period long (24 frames when the drive has none)."""

        d = self._drive(drive_id)
        ar, fleet = self._open()
        snapshot = SegmentSnapshot(ar.blobs, reference_segments(ar.catalogue, [d.id]))
        segs = snapshot.segments(d.id)
        refresh = [int(s.params.get("refresh") or 0) for s in segs]
        chunk = next((r for r in refresh if r > 0), 24)
        meta = fleet.meta(d.id)

        def frames(first: int) -> Iterator[np.ndarray]:
            # decoded in a thread of its own, a few frames ahead: decoding overlaps the encoder
            return read_ahead(drive_frames(snapshot, d, first, d.frames), 8)

        return StreamSource(d.id, d.width, d.height, d.fps, d.frames, chunk, frames,
                            ColourTags(**meta.colour) if meta.colour else None)  # fmt: skip

    # -- find and clip ----------------------------------------------------------------------------
    def find(
        self,
        near: tuple[float, float] | None = None,
        radius: float = 50.0,
        bbox: tuple[float, float, float, float] | None = None,
        t_from: float | None = None,
        t_to: float | None = None,
    ) -> list[dict]:
        """``dashcam find``: the stretches matching every criterion given (degrees, metres, UTC
        seconds), each with its drive id and its start and end on the drive's video clock (s)."""

        ar, fleet = self._open()
        found = search(ar, Query(near=near, radius=radius, bbox=bbox, t_from=t_from, t_to=t_to))
        ids = {d.name: d for d in fleet.live_drives()}
        out = []
        for s in found:
            d = ids[s.drive]
            out.append({**s.to_dict(), "id": d.id, "t0": s.frame_start / d.fps, "t1": s.frame_end / d.fps})
        return out

    def clip(self, drive_id: int, t: float, before: float, after: float, out: Path) -> dict:
        """``dashcam clip``: ``before`` / ``after`` seconds around second ``t`` of the drive's video
        clock, written to ``out`` (an .mp4, its .gpx beside it); returns what ``write_clip`` wrote."""

        d = self._drive(drive_id)
        ar, fleet = self._open()
        futc = fleet.frame_utc(d.id, d.fps)
        if not (np.isfinite(t) and 0 <= t <= d.frames / d.fps):
            raise EgovidError(f"second {t} is not in drive {d.name}", f"give 0-{d.frames / d.fps:.1f} s")
        at = float(futc[min(int(t * d.fps), len(futc) - 1)])
        plan = plan_clip(ar, at=at, drive=str(d.id), before=before, after=after)
        return write_clip(ar, plan, out)

    # -- changes ------------------------------------------------------------------------------------
    def set_lock(self, drive_id: int, locked: bool, note: str | None = None) -> dict:
        """``dashcam lock`` / ``unlock`` one drive."""

        ar, _ = self._open()
        (d,) = set_lock(ar, [str(int(self._drive(drive_id).id))], locked, note)
        return {"id": d.id, "name": d.name, "locked": locked, "lock_note": note if locked else None}

    def forget(self, drive_ids: list[int], *, dry_run: bool) -> dict:
        """``dashcam forget`` the drives (``dry_run``: only what it would do: the drives forgotten,
        those kept as hidden references and the live drives coded against them, bytes freed)."""

        for i in drive_ids:
            self._drive(i)
        ar, _ = self._open()
        return forget(ar, [str(int(i)) for i in drive_ids], verify=True, dry_run=dry_run).to_dict()
