"""The archive's catalogue: drives, paths, path sequences and encoded segments.

A small repository interface (:class:`Catalogue`) with two implementations that share their SQL
(:class:`_SqlCatalogue`): :class:`SqliteCatalogue`, the embedded default (one file, WAL journal,
an R*Tree index over path chunks for spatial look-up), and :class:`PostgresCatalogue` (a schema of
its own in a PostgreSQL database, a GiST index over the same chunk boxes), for archives shared by
several machines. :func:`open_catalogue` picks one from the archive's settings. Every ingest runs
inside one :meth:`Catalogue.transaction`, which also serialises writers, so a crash or an error
leaves the catalogue as it was. Arrays (path points, per-frame path positions, alignment maps) are
stored as little-endian binary blobs. The SQLite file is checked before anything may write to it,
and backed up after every commit (:mod:`egovid.dashcam.archive.catalogue_file`).

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
import re
import sqlite3
import uuid
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from egovid.core.errors import EgovidError, user_error
from egovid.dashcam.archive import catalogue_file
from egovid.dashcam.archive.catalogue_file import catalogue_problem, sqlite_uri, unusable_catalogue
from egovid.dashcam.archive.postgres import pg_connect, reason, redact_url

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


def array_from_le(blob: bytes | None, dtype, shape=(-1,)) -> np.ndarray:
    if blob is None:
        return np.zeros(0, dtype)
    return np.frombuffer(blob, dtype=np.dtype(dtype).newbyteorder("<")).astype(dtype).reshape(shape)


def le_bytes(a: np.ndarray, dtype) -> bytes:
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
    def set_drive_frames(self, drive_id: int, frames: int) -> None:
        """A drive's frame count after files were appended to it (inside a transaction)."""

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
    def blob_names(self) -> set[str]:
        """Names of every blob the catalogue refers to (segments, and drives' audio/telemetry)."""

    @abstractmethod
    def streams_blobs(self) -> dict[str, list[int]]:
        """The drives' audio/telemetry blobs (fleetstore.py): blob name -> ids of the drives."""

    @abstractmethod
    def close(self) -> None: ...


_TABLES = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS drives (
  id {ID}, name TEXT NOT NULL UNIQUE, source TEXT, gps_source TEXT, created TEXT NOT NULL,
  start_utc {REAL} NOT NULL, fps {REAL} NOT NULL, width INTEGER NOT NULL, height INTEGER NOT NULL,
  frames INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS paths (
  id {ID}, created_by {REF} REFERENCES drives(id), points {BLOB} NOT NULL);
CREATE TABLE IF NOT EXISTS segments (
  id {ID}, drive_id {REF} NOT NULL REFERENCES drives(id), frame_start INTEGER NOT NULL,
  frame_end INTEGER NOT NULL, mode TEXT NOT NULL CHECK (mode IN ('intra', 'joint')),
  ref_drive_id {REF} REFERENCES drives(id), refmap {BLOB}, align TEXT, blob TEXT NOT NULL,
  bytes {REF} NOT NULL, params TEXT);
CREATE TABLE IF NOT EXISTS sequences (
  id {ID}, drive_id {REF} NOT NULL REFERENCES drives(id),
  path_id {REF} NOT NULL REFERENCES paths(id), frame_start INTEGER NOT NULL, frame_end INTEGER NOT NULL,
  positions {BLOB} NOT NULL, illum {BLOB}, segment_id {REF} NOT NULL REFERENCES segments(id));
CREATE INDEX IF NOT EXISTS seq_path ON sequences(path_id);
CREATE INDEX IF NOT EXISTS seq_drive ON sequences(drive_id);
CREATE INDEX IF NOT EXISTS seg_drive ON segments(drive_id);
"""

_CHUNK = 16  # path points per spatial-index entry


class _SqlCatalogue(Catalogue):
    """The catalogue's SQL, written once for both backends (``?`` placeholders, ``RETURNING id``).
    A backend supplies the connection (:meth:`_q`, :meth:`transaction`), its column types, the
    spatial index of path chunks and the query on it (``_NEAR``: xmin, ymin, xmax, ymax)."""

    _TYPES: ClassVar[dict[str, str]]
    _INDEX_DDL: str
    _NEAR: str
    _depth = 0  # nesting level of transaction()

    def _ddl(self) -> list[str]:
        sql = _TABLES.format(**self._TYPES) + self._INDEX_DDL
        return [x for x in sql.split(";") if x.strip()]

    @abstractmethod
    def _q(self, sql: str, args=()): ...

    @abstractmethod
    def _begin(self) -> None:
        """Open a transaction that holds the catalogue's write lock until it ends."""

    @contextlib.contextmanager
    def transaction(self) -> Iterator[None]:
        if self._depth:  # nested: part of the transaction already open
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
            return
        self._depth = 1
        self._begin()
        try:
            yield
        except BaseException:
            self._q("ROLLBACK")
            raise
        else:
            self._q("COMMIT")
            self._committed()
        finally:
            self._depth = 0

    def _committed(self) -> None:
        """Called after each COMMIT (a backend may keep a backup)."""

    def _insert(self, sql: str, args) -> int:
        return int(self._q(sql + " RETURNING id", args).fetchone()[0])

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
        return self._insert(
            "INSERT INTO drives(name, source, gps_source, created, start_utc, fps, width, height, frames) "
            "VALUES(?,?,?,?,?,?,?,?,?)",
            (name, source, gps_source, created, start_utc, fps, width, height, frames),
        )

    def set_drive_frames(self, drive_id: int, frames: int) -> None:
        self._q("UPDATE drives SET frames = ? WHERE id = ?", (int(frames), drive_id))

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
        pid = self._insert("INSERT INTO paths(created_by, points) VALUES(?, ?)", (created_by, le_bytes(points, "<f8")))
        self._index_path(pid, np.asarray(points))
        return pid

    def update_path(self, path_id: int, points: np.ndarray) -> None:
        self._q("UPDATE paths SET points = ? WHERE id = ?", (le_bytes(points, "<f8"), path_id))
        self._index_path(path_id, np.asarray(points))

    def path(self, path_id: int) -> PathRec:
        row = self._q("SELECT id, points, created_by FROM paths WHERE id = ?", (path_id,)).fetchone()
        if row is None:
            raise KeyError(path_id)
        return PathRec(row[0], array_from_le(row[1], np.float64, (-1, 2)), row[2])

    def paths(self) -> list[PathRec]:
        return [
            PathRec(r[0], array_from_le(r[1], np.float64, (-1, 2)), r[2])
            for r in self._q("SELECT id, points, created_by FROM paths ORDER BY id")
        ]

    def paths_near(self, xmin, ymin, xmax, ymax) -> list[int]:
        rows = self._q(self._NEAR, (xmin, ymin, xmax, ymax))
        return sorted(int(r[0]) for r in rows)

    # -- sequences ------------------------------------------------------------------------------
    def add_sequence(self, drive_id, path_id, frame_start, frame_end, positions, illum, segment_id) -> int:
        return self._insert(
            "INSERT INTO sequences(drive_id, path_id, frame_start, frame_end, positions, illum, segment_id) "
            "VALUES(?,?,?,?,?,?,?)",
            (drive_id, path_id, frame_start, frame_end, le_bytes(positions, "<f4"), le_bytes(illum, "<f8"), segment_id),
        )

    def update_sequence(self, seq_id, path_id, frame_start, frame_end, positions) -> None:
        self._q(
            "UPDATE sequences SET path_id = ?, frame_start = ?, frame_end = ?, positions = ? WHERE id = ?",
            (path_id, frame_start, frame_end, le_bytes(positions, "<f4"), seq_id),
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
            Sequence(
                r[0], r[1], r[2], r[3], r[4], array_from_le(r[5], np.float32), array_from_le(r[6], np.float64), r[7]
            )
            for r in self._q(sql, args)
        ]

    # -- segments -------------------------------------------------------------------------------
    def add_segment(
        self, drive_id, frame_start, frame_end, mode, ref_drive_id, refmap, align, blob, nbytes, params
    ) -> int:
        return self._insert(
            "INSERT INTO segments(drive_id, frame_start, frame_end, mode, ref_drive_id, refmap, align, blob, bytes, "
            "params) VALUES(?,?,?,?,?,?,?,?,?,?)",
            (
                drive_id,
                frame_start,
                frame_end,
                mode,
                ref_drive_id,
                le_bytes(refmap, "<i4"),
                json.dumps(align),
                blob,
                nbytes,
                json.dumps(params),
            ),
        )

    def _segment(self, r) -> Segment:
        return Segment(
            r[0],
            r[1],
            r[2],
            r[3],
            r[4],
            r[5],
            array_from_le(r[6], np.int32),
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

    def blob_names(self) -> set[str]:
        return {r[0] for r in self._q("SELECT DISTINCT blob FROM segments")} | set(self.streams_blobs())

    def streams_blobs(self) -> dict[str, list[int]]:
        out: dict[str, list[int]] = {}
        if self.get_meta("fleet_schema") is None:  # no fleet tables (read-only: nothing is created)
            return out
        for sha, drive_id in self._q("SELECT streams_blob, drive_id FROM drive_meta WHERE streams_blob IS NOT NULL"):
            out.setdefault(sha, []).append(int(drive_id))
        return out


class SqliteCatalogue(_SqlCatalogue):
    """The embedded catalogue: one SQLite file (WAL journal, foreign keys, R*Tree index)."""

    _TYPES: ClassVar[dict[str, str]] = {"ID": "INTEGER PRIMARY KEY", "REF": "INTEGER", "REAL": "REAL", "BLOB": "BLOB"}
    _INDEX_DDL = (
        "CREATE VIRTUAL TABLE IF NOT EXISTS path_index USING rtree(id, min_x, max_x, min_y, max_y, +path_id INTEGER)"
    )
    _NEAR = "SELECT DISTINCT path_id FROM path_index WHERE max_x >= ? AND max_y >= ? AND min_x <= ? AND min_y <= ?"

    def __init__(self, path: str | Path, *, create: bool = False) -> None:
        self.file = Path(path)
        self._saved = -1  # total_changes when the backup was last written
        if not create and not self.file.exists():  # never a fresh empty catalogue beside old blobs
            raise unusable_catalogue(self.file, "missing")
        if not create and self.file.stat().st_size == 0:  # SQLite would take it for a new database
            raise unusable_catalogue(self.file, "empty (0 bytes)")
        try:
            uri = sqlite_uri(self.file, "rwc" if create else "rw")
            self._db = sqlite3.connect(uri, uri=True, isolation_level=None, timeout=30.0)
            self._db.execute("PRAGMA foreign_keys = ON")
            # checked before anything that may write (the journal mode): a damaged file stays as it is
            problem = None if create else catalogue_problem(self._db, SCHEMA_VERSION)
            if problem is None:
                self._db.execute("PRAGMA journal_mode = WAL")
                self._db.execute("PRAGMA synchronous = FULL")
        except sqlite3.DatabaseError as exc:
            raise unusable_catalogue(self.file, f"damaged ({exc})") from None
        if problem is not None:
            self._db.close()
            raise unusable_catalogue(self.file, problem)
        if create:
            with self.transaction():
                for stmt in self._ddl():
                    self._db.execute(stmt)
                self.set_meta("schema_version", str(SCHEMA_VERSION))
        self._saved = self._db.total_changes

    def _committed(self) -> None:
        """Copy the catalogue to its backup after a commit that changed it (``check --repair``
        restores a damaged or deleted catalogue from it)."""
        if self._db.total_changes != self._saved:
            try:
                self.write_backup()
            except BaseException as exc:  # a full disk, say: no backup rather than one silently behind
                catalogue_file.backup_path(self.file).unlink(missing_ok=True)
                if not isinstance(exc, OSError | sqlite3.Error):
                    raise
                why = user_error(exc)
                raise EgovidError(
                    "the change is saved in the catalogue, but its backup could not be written "
                    f"({why.problem if why is not None else exc})",
                    f"free some space, then run `egovid dashcam check {self.file.parent} --repair` to write it",
                ) from exc
            self._saved = self._db.total_changes

    # -- upkeep (``egovid dashcam check``) ------------------------------------------------------
    def write_backup(self) -> Path:
        """Copy the catalogue to its backup file now (:func:`catalogue_file.write_backup`)."""
        return catalogue_file.write_backup(self._db, self.file)

    def has_backup(self) -> bool:
        return catalogue_file.backup_path(self.file).exists()

    def dangling_rows(self) -> list[tuple]:
        """Rows that refer to rows that do not exist (SQLite's foreign-key check: table first)."""
        return self._db.execute("PRAGMA foreign_key_check").fetchall()

    def spatial_index_sound(self) -> bool:
        """True when the R*Tree over the path chunks is intact and indexes exactly the paths."""
        try:
            if self._db.execute("SELECT rtreecheck('path_index')").fetchone()[0] != "ok":
                return False
            indexed = {r[0] for r in self._q("SELECT DISTINCT path_id FROM path_index")}
        except sqlite3.DatabaseError:
            return False
        return indexed == {p.id for p in self.paths()}

    def rebuild_spatial_index(self) -> None:
        """Index every path again, from its points (one transaction)."""
        with self.transaction():
            self._q("DELETE FROM path_index")
            for p in self.paths():
                self._index_path(p.id, p.points)

    def _begin(self) -> None:
        self._db.execute("BEGIN IMMEDIATE")  # takes the write lock now: one ingest at a time

    def _q(self, sql: str, args=()) -> sqlite3.Cursor:
        return self._db.execute(sql, args)

    def close(self) -> None:
        self._db.close()


class PostgresCatalogue(_SqlCatalogue):
    """A catalogue in PostgreSQL (through psycopg 3): the archive's tables in a schema of their own,
    so that several archives can share one database, and a GiST index over the path-chunk boxes.
    ``url``: a libpq URL (``postgresql://USER@HOST:PORT/DB``; a password is better kept in
    ``PGPASSWORD`` or ``~/.pgpass`` than in the URL, which the archive folder records)."""

    _TYPES: ClassVar[dict[str, str]] = {
        "ID": "BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY",
        "REF": "BIGINT",
        "REAL": "DOUBLE PRECISION",
        "BLOB": "BYTEA",
    }
    _INDEX_DDL = """
CREATE TABLE IF NOT EXISTS path_index (
  id BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY, min_x DOUBLE PRECISION NOT NULL,
  max_x DOUBLE PRECISION NOT NULL, min_y DOUBLE PRECISION NOT NULL, max_y DOUBLE PRECISION NOT NULL,
  path_id BIGINT NOT NULL REFERENCES paths(id));
CREATE INDEX IF NOT EXISTS path_index_box ON path_index USING gist (box(point(min_x, min_y), point(max_x, max_y)))
"""
    _NEAR = (
        "SELECT DISTINCT path_id FROM path_index "
        "WHERE box(point(min_x, min_y), point(max_x, max_y)) && box(point(?, ?), point(?, ?))"
    )

    def __init__(self, url: str, schema: str, *, create: bool = False) -> None:
        if not re.fullmatch(r"[a-z_][a-z0-9_]{0,62}", schema):
            raise EgovidError(f"catalogue schema name {schema!r} is not valid", "use lower-case letters, digits, _")
        self.url, self.schema = url, schema
        self._db = pg_connect(url)
        exists = self._db.execute("SELECT 1 FROM pg_namespace WHERE nspname = %s", (schema,)).fetchone()
        if create and exists:
            self.close()
            raise EgovidError(f"schema {schema} already exists in {redact_url(url)}", "choose another archive")
        if not create and not exists:
            self.close()
            raise EgovidError(
                f"the catalogue (schema {schema}) is missing from {redact_url(url)}", "restore the database"
            )
        if create:
            with self.transaction():
                self._db.execute(f'CREATE SCHEMA "{schema}"')
                self._db.execute(f'SET LOCAL search_path TO "{schema}"')
                for stmt in self._ddl():
                    self._db.execute(stmt)
                self.set_meta("schema_version", str(SCHEMA_VERSION))
        self._db.execute(f'SET search_path TO "{schema}"')

    def _begin(self) -> None:
        self._db.execute("BEGIN")
        # One writer at a time per archive, as SQLite's BEGIN IMMEDIATE gives (released at the end).
        self._db.execute("SELECT pg_advisory_xact_lock(hashtext(%s))", (self.schema,))

    def _q(self, sql: str, args=()):
        import psycopg  # only archives kept in PostgreSQL need it

        try:
            return self._db.execute(sql.replace("?", "%s"), args)
        except psycopg.OperationalError as e:  # the server went away or refused mid-way
            raise EgovidError(
                f"lost the PostgreSQL catalogue at {redact_url(self.url)}: {reason(e)}",
                "check the server and run the command again (an interrupted ingest changed nothing)",
            ) from None

    def close(self) -> None:
        self._db.close()


def catalogue_settings(db: str | None) -> dict:
    """The archive's catalogue settings for ``init --db``: None, ``sqlite`` → the embedded SQLite
    file; ``postgresql://…`` (or ``postgres://…``) → PostgreSQL, in a new schema named for this
    archive."""
    if db in (None, "", "sqlite"):
        return {"backend": "sqlite"}
    if re.match(r"postgres(ql)?://", db):
        return {"backend": "postgresql", "url": db, "schema": "egovid_" + uuid.uuid4().hex[:12]}
    raise EgovidError(
        f"catalogue {db!r} is not understood",
        "give postgresql://USER@HOST[:PORT]/DATABASE, or leave --db out for the embedded SQLite",
    )


def open_catalogue(root: Path, settings: dict | None, *, create: bool = False) -> Catalogue:
    """The catalogue of the archive at ``root`` from its settings (:func:`catalogue_settings`;
    None = an archive from before the setting existed, i.e. SQLite)."""
    backend = (settings or {}).get("backend", "sqlite")
    if backend == "sqlite":
        return SqliteCatalogue(Path(root) / "catalogue.sqlite", create=create)
    if backend == "postgresql":
        return PostgresCatalogue(settings["url"], settings["schema"], create=create)
    raise EgovidError(f"catalogue backend {backend!r} is not supported by this egovid", "upgrade egovid")
