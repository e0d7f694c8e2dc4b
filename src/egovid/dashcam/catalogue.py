"""The archive's catalogue: drives, paths, path sequences and encoded segments.

A small repository interface (:class:`Catalogue`) with an SQLite implementation
(:class:`SqliteCatalogue`, the embedded default: one file, WAL journal, an R*Tree index over path
chunks for spatial look-up). Every ingest runs inside one :meth:`Catalogue.transaction`, so a
crash or an error leaves the catalogue as it was. Arrays (path points, per-frame path positions,
alignment maps) are stored as little-endian binary blobs.

Records:

* **drive** — one ingested video (name, source, UTC start, size, frame count, fps);
* **path** — a directional polyline (points every 5 m); paths never overlap;
* **sequence** — the frames of a drive on one path, with each frame's position along the path
  (metres) and the sequence's illumination features; points to the segment holding its frames;
* **segment** — an encoded bitstream (content-addressed blob): intra (a root) or joint (coded
  against another drive, with the reference frame index of every frame).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import sqlite3
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SCHEMA_VERSION = 1


@dataclass
class Drive:
    id: int
    name: str
    source: str
    gps_source: str
    created: str
    start_utc: float
    fps: float
    width: int
    height: int
    frames: int


@dataclass
class PathRec:
    id: int
    points: np.ndarray
    created_by: int | None

    @property
    def length_m(self) -> float:
        return float(np.sum(np.hypot(*np.diff(self.points, axis=0).T))) if len(self.points) > 1 else 0.0


@dataclass
class Sequence:
    id: int
    drive_id: int
    path_id: int
    frame_start: int
    frame_end: int
    positions: np.ndarray  # metres along the path, one per frame
    illum: np.ndarray
    segment_id: int


@dataclass
class Segment:
    id: int
    drive_id: int
    frame_start: int
    frame_end: int
    mode: str  # "intra" | "joint"
    ref_drive_id: int | None
    refmap: np.ndarray  # reference drive frame per frame (-1: keyframe / none)
    align: dict
    blob: str
    bytes: int
    params: dict


def _arr(blob: bytes | None, dtype, shape=(-1,)) -> np.ndarray:
    if blob is None:
        return np.zeros(0, dtype)
    return np.frombuffer(blob, dtype=np.dtype(dtype).newbyteorder("<")).astype(dtype).reshape(shape)


def _blob(a: np.ndarray, dtype) -> bytes:
    return np.ascontiguousarray(a, dtype=np.dtype(dtype).newbyteorder("<")).tobytes()


class Catalogue(ABC):
    """Repository interface of the archive catalogue."""

    @abstractmethod
    def transaction(self) -> contextlib.AbstractContextManager: ...

    @abstractmethod
    def get_meta(self, key: str) -> str | None: ...

    @abstractmethod
    def set_meta(self, key: str, value: str) -> None: ...

    @abstractmethod
    def add_drive(
        self,
        name: str,
        source: str,
        gps_source: str,
        start_utc: float,
        fps: float,
        width: int,
        height: int,
        frames: int,
    ) -> int: ...

    @abstractmethod
    def drives(self) -> list[Drive]: ...

    @abstractmethod
    def drive(self, key: int | str) -> Drive | None: ...

    @abstractmethod
    def add_path(self, points: np.ndarray, created_by: int | None) -> int: ...

    @abstractmethod
    def update_path(self, path_id: int, points: np.ndarray) -> None: ...

    @abstractmethod
    def path(self, path_id: int) -> PathRec: ...

    @abstractmethod
    def paths(self) -> list[PathRec]: ...

    @abstractmethod
    def paths_near(self, xmin: float, ymin: float, xmax: float, ymax: float) -> list[int]: ...

    @abstractmethod
    def add_sequence(
        self,
        drive_id: int,
        path_id: int,
        frame_start: int,
        frame_end: int,
        positions: np.ndarray,
        illum: np.ndarray,
        segment_id: int,
    ) -> int: ...

    @abstractmethod
    def update_sequence(
        self, seq_id: int, path_id: int, frame_start: int, frame_end: int, positions: np.ndarray
    ) -> None: ...

    @abstractmethod
    def sequences(self, *, drive_id: int | None = None, path_id: int | None = None) -> list[Sequence]: ...

    @abstractmethod
    def add_segment(
        self,
        drive_id: int,
        frame_start: int,
        frame_end: int,
        mode: str,
        ref_drive_id: int | None,
        refmap: np.ndarray,
        align: dict,
        blob: str,
        nbytes: int,
        params: dict,
    ) -> int: ...

    @abstractmethod
    def segments(self, drive_id: int) -> list[Segment]: ...

    @abstractmethod
    def segment(self, segment_id: int) -> Segment: ...

    @abstractmethod
    def close(self) -> None: ...


_DDL = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS drives (
  id INTEGER PRIMARY KEY, name TEXT NOT NULL UNIQUE, source TEXT, gps_source TEXT, created TEXT NOT NULL,
  start_utc REAL NOT NULL, fps REAL NOT NULL, width INTEGER NOT NULL, height INTEGER NOT NULL,
  frames INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS paths (
  id INTEGER PRIMARY KEY, created_by INTEGER REFERENCES drives(id), points BLOB NOT NULL);
CREATE VIRTUAL TABLE IF NOT EXISTS path_index USING rtree(id, min_x, max_x, min_y, max_y, +path_id INTEGER);
CREATE TABLE IF NOT EXISTS segments (
  id INTEGER PRIMARY KEY, drive_id INTEGER NOT NULL REFERENCES drives(id), frame_start INTEGER NOT NULL,
  frame_end INTEGER NOT NULL, mode TEXT NOT NULL CHECK (mode IN ('intra', 'joint')),
  ref_drive_id INTEGER REFERENCES drives(id), refmap BLOB, align TEXT, blob TEXT NOT NULL,
  bytes INTEGER NOT NULL, params TEXT);
CREATE TABLE IF NOT EXISTS sequences (
  id INTEGER PRIMARY KEY, drive_id INTEGER NOT NULL REFERENCES drives(id),
  path_id INTEGER NOT NULL REFERENCES paths(id), frame_start INTEGER NOT NULL, frame_end INTEGER NOT NULL,
  positions BLOB NOT NULL, illum BLOB, segment_id INTEGER NOT NULL REFERENCES segments(id));
CREATE INDEX IF NOT EXISTS seq_path ON sequences(path_id);
CREATE INDEX IF NOT EXISTS seq_drive ON sequences(drive_id);
CREATE INDEX IF NOT EXISTS seg_drive ON segments(drive_id);
"""

_CHUNK = 16  # path points per R*Tree entry


class SqliteCatalogue(Catalogue):
    """The embedded catalogue: one SQLite file (WAL journal, foreign keys, R*Tree index)."""

    def __init__(self, path: str | Path, *, create: bool = False) -> None:
        self.file = Path(path)
        self._db = sqlite3.connect(str(self.file), isolation_level=None, timeout=30.0)
        self._db.execute("PRAGMA foreign_keys = ON")
        self._db.execute("PRAGMA journal_mode = WAL")
        self._db.execute("PRAGMA synchronous = FULL")
        self._depth = 0
        if create:
            with self.transaction():
                for stmt in _DDL.split(";"):
                    if stmt.strip():
                        self._db.execute(stmt)
                self.set_meta("schema_version", str(SCHEMA_VERSION))

    # -- transactions ---------------------------------------------------------------------------
    @contextlib.contextmanager
    def transaction(self) -> Iterator[None]:
        if self._depth:
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
            return
        self._depth = 1
        self._db.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        else:
            self._db.execute("COMMIT")
        finally:
            self._depth = 0

    def _q(self, sql: str, args=()) -> sqlite3.Cursor:
        return self._db.execute(sql, args)

    # -- meta -----------------------------------------------------------------------------------
    def get_meta(self, key: str) -> str | None:
        row = self._q("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return row[0] if row else None

    def set_meta(self, key: str, value: str) -> None:
        self._q(
            "INSERT INTO meta(key, value) VALUES(?, ?) ON CONFLICT(key) DO UPDATE SET value = excluded.value",
            (key, value),
        )

    # -- drives ---------------------------------------------------------------------------------
    def add_drive(self, name, source, gps_source, start_utc, fps, width, height, frames) -> int:
        created = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
        cur = self._q(
            "INSERT INTO drives(name, source, gps_source, created, start_utc, fps, width, height, frames) "
            "VALUES(?,?,?,?,?,?,?,?,?)",
            (name, source, gps_source, created, start_utc, fps, width, height, frames),
        )
        return int(cur.lastrowid)

    def _drive(self, row) -> Drive:
        return Drive(*row)

    def drives(self) -> list[Drive]:
        cols = "id, name, source, gps_source, created, start_utc, fps, width, height, frames"
        return [self._drive(r) for r in self._q(f"SELECT {cols} FROM drives ORDER BY id")]

    def drive(self, key: int | str) -> Drive | None:
        cols = "id, name, source, gps_source, created, start_utc, fps, width, height, frames"
        if isinstance(key, int) or (isinstance(key, str) and key.isdigit()):
            row = self._q(f"SELECT {cols} FROM drives WHERE id = ?", (int(key),)).fetchone()
            if row is None and isinstance(key, str):
                row = self._q(f"SELECT {cols} FROM drives WHERE name = ?", (key,)).fetchone()
        else:
            row = self._q(f"SELECT {cols} FROM drives WHERE name = ?", (key,)).fetchone()
        return self._drive(row) if row else None

    # -- paths ----------------------------------------------------------------------------------
    def _index_path(self, path_id: int, points: np.ndarray) -> None:
        self._q("DELETE FROM path_index WHERE path_id = ?", (path_id,))
        for a in range(0, max(len(points) - 1, 1), _CHUNK):
            chunk = points[a : a + _CHUNK + 1]
            self._q(
                "INSERT INTO path_index(min_x, max_x, min_y, max_y, path_id) VALUES(?,?,?,?,?)",
                (
                    float(chunk[:, 0].min()),
                    float(chunk[:, 0].max()),
                    float(chunk[:, 1].min()),
                    float(chunk[:, 1].max()),
                    path_id,
                ),
            )

    def add_path(self, points: np.ndarray, created_by: int | None) -> int:
        cur = self._q("INSERT INTO paths(created_by, points) VALUES(?, ?)", (created_by, _blob(points, "<f8")))
        pid = int(cur.lastrowid)
        self._index_path(pid, np.asarray(points))
        return pid

    def update_path(self, path_id: int, points: np.ndarray) -> None:
        self._q("UPDATE paths SET points = ? WHERE id = ?", (_blob(points, "<f8"), path_id))
        self._index_path(path_id, np.asarray(points))

    def path(self, path_id: int) -> PathRec:
        row = self._q("SELECT id, points, created_by FROM paths WHERE id = ?", (path_id,)).fetchone()
        if row is None:
            raise KeyError(path_id)
        return PathRec(row[0], _arr(row[1], np.float64, (-1, 2)), row[2])

    def paths(self) -> list[PathRec]:
        return [
            PathRec(r[0], _arr(r[1], np.float64, (-1, 2)), r[2])
            for r in self._q("SELECT id, points, created_by FROM paths ORDER BY id")
        ]

    def paths_near(self, xmin, ymin, xmax, ymax) -> list[int]:
        rows = self._q(
            "SELECT DISTINCT path_id FROM path_index WHERE max_x >= ? AND min_x <= ? AND max_y >= ? AND min_y <= ?",
            (xmin, xmax, ymin, ymax),
        )
        return sorted(int(r[0]) for r in rows)

    # -- sequences ------------------------------------------------------------------------------
    def add_sequence(self, drive_id, path_id, frame_start, frame_end, positions, illum, segment_id) -> int:
        cur = self._q(
            "INSERT INTO sequences(drive_id, path_id, frame_start, frame_end, positions, illum, segment_id) "
            "VALUES(?,?,?,?,?,?,?)",
            (drive_id, path_id, frame_start, frame_end, _blob(positions, "<f4"), _blob(illum, "<f8"), segment_id),
        )
        return int(cur.lastrowid)

    def update_sequence(self, seq_id, path_id, frame_start, frame_end, positions) -> None:
        self._q(
            "UPDATE sequences SET path_id = ?, frame_start = ?, frame_end = ?, positions = ? WHERE id = ?",
            (path_id, frame_start, frame_end, _blob(positions, "<f4"), seq_id),
        )

    def sequences(self, *, drive_id=None, path_id=None) -> list[Sequence]:
        sql = "SELECT id, drive_id, path_id, frame_start, frame_end, positions, illum, segment_id FROM sequences"
        cond, args = [], []
        if drive_id is not None:
            cond.append("drive_id = ?")
            args.append(drive_id)
        if path_id is not None:
            cond.append("path_id = ?")
            args.append(path_id)
        if cond:
            sql += " WHERE " + " AND ".join(cond)
        sql += " ORDER BY drive_id, frame_start"
        return [
            Sequence(r[0], r[1], r[2], r[3], r[4], _arr(r[5], np.float32), _arr(r[6], np.float64), r[7])
            for r in self._q(sql, args)
        ]

    # -- segments -------------------------------------------------------------------------------
    def add_segment(
        self, drive_id, frame_start, frame_end, mode, ref_drive_id, refmap, align, blob, nbytes, params
    ) -> int:
        cur = self._q(
            "INSERT INTO segments(drive_id, frame_start, frame_end, mode, ref_drive_id, refmap, align, blob, bytes, "
            "params) VALUES(?,?,?,?,?,?,?,?,?,?)",
            (
                drive_id,
                frame_start,
                frame_end,
                mode,
                ref_drive_id,
                _blob(refmap, "<i4"),
                json.dumps(align),
                blob,
                nbytes,
                json.dumps(params),
            ),
        )
        return int(cur.lastrowid)

    def _segment(self, r) -> Segment:
        return Segment(
            r[0],
            r[1],
            r[2],
            r[3],
            r[4],
            r[5],
            _arr(r[6], np.int32),
            json.loads(r[7] or "{}"),
            r[8],
            r[9],
            json.loads(r[10] or "{}"),
        )

    def segments(self, drive_id: int) -> list[Segment]:
        cols = "id, drive_id, frame_start, frame_end, mode, ref_drive_id, refmap, align, blob, bytes, params"
        return [
            self._segment(r)
            for r in self._q(f"SELECT {cols} FROM segments WHERE drive_id = ? ORDER BY frame_start", (drive_id,))
        ]

    def segment(self, segment_id: int) -> Segment:
        cols = "id, drive_id, frame_start, frame_end, mode, ref_drive_id, refmap, align, blob, bytes, params"
        row = self._q(f"SELECT {cols} FROM segments WHERE id = ?", (segment_id,)).fetchone()
        if row is None:
            raise KeyError(segment_id)
        return self._segment(row)

    def close(self) -> None:
        self._db.close()
