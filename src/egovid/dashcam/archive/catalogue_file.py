"""The SQLite catalogue as a file: opening it without changing a damaged one, its health check, the
backup beside it, and salvaging what SQLite can still read.

* The catalogue is checked whenever it is opened (:func:`catalogue_problem`: SQLite's quick check,
  the tables, the schema version). A missing catalogue is an error (:func:`unusable_catalogue`),
  never a fresh empty one: the archive may hold bitstreams only the catalogue can make sense of.
* After every committed write the catalogue is copied (SQLite's online backup) to
  ``catalogue.sqlite.backup`` (:func:`write_backup`): a damaged or deleted catalogue can then be
  restored to its last commit (:func:`restore_backup`), or else salvaged (:func:`salvage`).

Below the catalogue (:mod:`egovid.dashcam.archive.catalogue` opens its file through this module);
``egovid dashcam check --repair`` (:mod:`egovid.dashcam.check`) decides when to restore or salvage.
"""

from __future__ import annotations

import datetime as dt
import os
import sqlite3
import threading
import urllib.parse
from pathlib import Path

from egovid.core.errors import EgovidError
from egovid.core.files import track_temp, untrack_temp

CATALOGUE_FILE = "catalogue.sqlite"
TABLES = ("meta", "drives", "paths", "segments", "sequences")


def repair_fix(root: str | os.PathLike) -> str:
    """The fix that names ``egovid dashcam check ROOT --repair``."""
    return f"run `egovid dashcam check {root} --repair`"


def sqlite_uri(path: Path, mode: str) -> str:
    """An SQLite URI for ``path`` opened with ``mode`` (``ro``, ``rw``: the file must exist;
    ``rwc``: create it). ``rw`` on a read-only disk (an archive on a backup drive, a read-only
    mount) opens it read-only and immutable: SQLite could not create the WAL's shared-memory file
    there, and nothing can change it meanwhile. A write then fails as a read-only file system."""
    uri = f"file:{urllib.parse.quote(str(path))}"
    if mode == "rw" and not os.access(Path(path).parent, os.W_OK):
        wal = Path(f"{path}-wal")
        if wal.exists() and wal.stat().st_size > 0:
            raise EgovidError(
                f"the catalogue {path} is on a read-only disk with an unfinished journal ({wal.name})",
                "copy the archive folder to a writable disk and open it there",
            )
        return f"{uri}?mode=ro&immutable=1"
    return f"{uri}?mode={mode}"


def catalogue_problem(db: sqlite3.Connection, newest_schema: int) -> str | None:
    """Why an open SQLite catalogue cannot be used, or None: SQLite's quick check, the tables a
    catalogue has, and a schema version this egovid knows (at most ``newest_schema``)."""
    try:
        rows = [r[0] for r in db.execute("PRAGMA quick_check").fetchall()]
        if rows != ["ok"]:
            return "damaged (" + "; ".join(str(r) for r in rows[:3]) + ")"
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        missing = [t for t in TABLES if t not in tables]
        if missing:
            return "empty" if not tables else f"damaged (no table {', '.join(missing)})"
        row = db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
    except sqlite3.DatabaseError as exc:
        return f"damaged ({' '.join(str(exc).split())})"
    if row is None or not str(row[0]).isdigit():
        return "damaged (no schema version)"
    if int(row[0]) > newest_schema:
        return f"from a newer egovid (schema {row[0]}; this egovid reads up to {newest_schema})"
    return None


def file_problem(path: Path, newest_schema: int) -> str | None:
    """Why the catalogue file at ``path`` cannot be used (missing, empty, unreadable, or
    :func:`catalogue_problem`), or None. Opens it without writing anything."""
    if not path.exists():
        return "missing"
    if path.stat().st_size == 0:
        return "empty (0 bytes)"
    try:
        db = sqlite3.connect(sqlite_uri(path, "rw"), uri=True)
    except sqlite3.DatabaseError as exc:
        return f"unreadable ({exc})"
    try:
        return catalogue_problem(db, newest_schema)
    finally:
        db.close()


def local_blob_count(root: Path) -> int:
    """Bitstream files in the archive folder's own blob store (0 when it keeps them elsewhere)."""
    folder = root / "blobs"
    return sum(1 for p in folder.rglob("*") if p.is_file() and not p.name.startswith(".")) if folder.exists() else 0


def unusable_catalogue(path: Path, problem: str) -> EgovidError:
    """The error for a catalogue that cannot be opened (missing, damaged, empty, too new)."""
    root = path.parent
    if problem.startswith("from a newer egovid"):
        return EgovidError(f"the catalogue {path} is {problem}", "upgrade egovid")
    blobs = local_blob_count(root)
    held = f" while the archive holds {blobs} bitstream(s)" if blobs else ""
    backup = " (restores its last backup)" if backup_path(path).exists() else ""
    return EgovidError(f"the catalogue {path} is {problem}{held}", repair_fix(root) + backup)


def backup_path(catalogue: Path) -> Path:
    """Where the backup of an SQLite catalogue file lives: beside it, ``NAME.backup``."""
    return catalogue.with_name(catalogue.name + ".backup")


def write_backup(db: sqlite3.Connection, catalogue: Path) -> Path:
    """Copy the catalogue behind ``db`` to :func:`backup_path` (SQLite's online backup into a
    temporary file, renamed into place: a crash leaves the previous backup)."""
    target = backup_path(catalogue)
    tmp = track_temp(target.with_name(f".{target.name}.part-{os.getpid()}-{threading.get_ident()}"))
    try:
        dst = sqlite3.connect(str(tmp))
        try:
            db.backup(dst)
            dst.execute("PRAGMA journal_mode = DELETE")  # one self-contained file
        finally:
            dst.close()
        os.replace(tmp, target)
    except BaseException:
        for side in ("", "-wal", "-shm", "-journal"):  # SQLite's own files beside it too
            tmp.with_name(tmp.name + side).unlink(missing_ok=True)
        raise
    finally:
        untrack_temp(tmp)
    return target


def set_aside(path: Path) -> Path:
    """Move a damaged catalogue file (and its ``-wal``/``-shm``) to ``NAME.damaged-STAMP`` beside
    it, never deleting it; returns the new name."""
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    kept = path.with_name(f"{path.name}.damaged-{stamp}")
    os.replace(path, kept)
    for extra in ("-wal", "-shm"):
        side = path.with_name(path.name + extra)
        if side.exists():
            os.replace(side, kept.with_name(kept.name + extra))
    return kept


def restore_backup(path: Path, newest_schema: int) -> bool:
    """Copy the backup of ``path`` (:func:`backup_path`) to ``path`` if it is sound; True if done."""
    backup = backup_path(path)
    if not backup.exists():
        return False
    try:
        db = sqlite3.connect(sqlite_uri(backup, "ro"), uri=True)
        try:
            sound = catalogue_problem(db, newest_schema) is None
            if sound:
                dst = sqlite3.connect(str(path))
                db.backup(dst)
                dst.close()
        finally:
            db.close()
    except sqlite3.DatabaseError:
        sound = False
    return sound


def salvage(damaged: Path, target: Path, newest_schema: int) -> bool:
    """Copy what SQLite can still read of ``damaged`` into a new ``target``; True if usable (else
    ``target`` is removed)."""
    try:
        src = sqlite3.connect(sqlite_uri(damaged, "ro"), uri=True)
        dst = sqlite3.connect(str(target))
        try:
            for stmt in src.iterdump():
                try:
                    dst.execute(stmt)
                except sqlite3.DatabaseError:
                    continue
            dst.commit()
            ok = catalogue_problem(dst, newest_schema) is None
        finally:
            src.close()
            dst.close()
    except sqlite3.DatabaseError:
        ok = False
    if not ok:
        target.unlink(missing_ok=True)
    return ok
