"""``egovid dashcam backup`` / ``restore``: the catalogue as one file, and back into an empty archive.

The backup file is an SQLite database holding the catalogue's tables (drives, paths, segments,
sequences, meta and the fleet tables), whichever backend the archive uses:

* an SQLite catalogue is copied with SQLite's online backup API (``sqlite3.Connection.backup``):
  a consistent picture of the last commit even while an ingest writes (the copy holds a read
  lock; WAL lets the writer go on);
* a PostgreSQL catalogue is exported logically: every table read in one ``REPEATABLE READ READ
  ONLY`` transaction (one snapshot of the server, as ``pg_dump`` takes it; an ingest committing
  meanwhile is either wholly in the file or not at all) and written into the SQLite file.
  ``pg_dump`` itself is not used: its dump is bound to the archive's schema name and to
  PostgreSQL, while a restore goes into a new archive (a schema of its own) of either backend.

:func:`restore_catalogue` loads such a file into an archive whose catalogue is empty (just made by
``egovid dashcam init``, with ``--db`` and ``--blobs`` as wanted), in one transaction: the rows
with their ids, then the spatial indexes rebuilt from them (an R*Tree in SQLite, GiST/PostGIS in
PostgreSQL). A kill leaves the archive empty. The bitstreams are not in the backup: they are
immutable files named by their SHA-256, copied as they are (``rsync``, ``aws s3 sync``) into the
new archive's blob store; ``egovid dashcam check`` then says whether any is missing.
"""

from __future__ import annotations

import os
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

from egovid.core.errors import EgovidError
from egovid.core.files import temp_sibling, track_temp, untrack_temp
from egovid.dashcam.archive import readings
from egovid.dashcam.archive.catalogue import SCHEMA_VERSION, PostgresCatalogue, SqliteCatalogue
from egovid.dashcam.archive.fleetstore import FLEET_SCHEMA, FleetStore
from egovid.dashcam.archive.store import Archive

#: Tables of a catalogue backup, in the order they are restored (rows referred to come first).
DATA_TABLES = (
    "meta",
    "drives",
    "paths",
    "segments",
    "sequences",
    "drive_meta",
    "drive_parts",
    "drive_tracks",
    "file_digests",
    "drive_channels",
    "drive_readings",
)
_OWN_META = ("schema_version", "fleet_schema", "fleet_postgis", readings.META_KEY)  # the target's, never copied
_BATCH = 500  # rows per executemany


@dataclass
class BackupReport:
    """What a backup or restore moved: rows per table, and the file."""

    file: Path
    rows: dict[str, int] = field(default_factory=dict)

    @property
    def drives(self) -> int:
        return self.rows.get("drives", 0)


def backup_catalogue(archive: Archive, file: str | os.PathLike) -> BackupReport:
    """Write a consistent copy of the archive's catalogue to ``file`` (an SQLite database; written
    beside it and renamed into place: an interruption leaves no half-written backup)."""
    target = Path(file)
    if target.exists():
        raise EgovidError(f"{target} exists", "give a new file name (a backup never overwrites a file)")
    if not target.parent.is_dir():
        raise EgovidError(f"folder {target.parent} does not exist", "create it first")
    tmp = track_temp(temp_sibling(target))
    cat = archive.catalogue
    try:
        if isinstance(cat, SqliteCatalogue):
            dst = sqlite3.connect(str(tmp))
            try:
                cat._db.backup(dst)  # SQLite's online backup: one consistent picture
                dst.execute("PRAGMA journal_mode = DELETE")
            finally:
                dst.close()
        elif isinstance(cat, PostgresCatalogue):
            _export_postgres(cat, tmp)
        else:
            raise EgovidError(f"no backup for a catalogue of kind {type(cat).__name__}", "upgrade egovid")
        rows = _count_rows(tmp)
        os.replace(tmp, target)
    except OSError as exc:
        raise EgovidError(f"cannot write {target}: {exc.strerror or exc}", "check the folder and free space") from None
    finally:
        for side in ("", "-wal", "-shm", "-journal"):
            Path(f"{tmp}{side}").unlink(missing_ok=True)
        untrack_temp(tmp)
    return BackupReport(target, rows)


def _export_postgres(cat: PostgresCatalogue, tmp: Path) -> None:
    """Every table of the PostgreSQL catalogue, read in one snapshot, into a new SQLite catalogue."""
    out = SqliteCatalogue(tmp, create=True)
    try:
        FleetStore(out)  # the fleet tables, empty
        db = cat._db
        with db.transaction():
            db.execute("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ READ ONLY")
            present = {
                r[0]
                for r in db.execute(
                    "SELECT table_name FROM information_schema.tables WHERE table_schema = %s", (cat.schema,)
                )
            }
            with out.transaction():
                out._q("DELETE FROM meta")
                if "drive_readings" in present:  # created with an archive's first readings
                    readings.create_table(out)
                for table in (t for t in DATA_TABLES if t in present):
                    cur = db.execute(f'SELECT * FROM "{table}"')
                    cols = [c.name for c in cur.description]
                    sql = f"INSERT INTO {table}({', '.join(cols)}) VALUES({', '.join('?' * len(cols))})"
                    while batch := cur.fetchmany(_BATCH):
                        out._db.executemany(sql, [tuple(_plain(v) for v in row) for row in batch])
    finally:
        out.close()


def _plain(v):
    """A PostgreSQL value as SQLite stores it (bytea comes back as bytes or a memoryview)."""
    return bytes(v) if isinstance(v, memoryview) else v


def _open_backup(file: Path) -> sqlite3.Connection:
    """The backup file opened read-only, checked to be an egovid catalogue this egovid reads."""
    fix = "give the file `egovid dashcam backup` wrote"
    if not file.is_file():
        raise EgovidError(f"backup file {file} {'is a folder' if file.is_dir() else 'does not exist'}", fix)
    src = sqlite3.connect(f"file:{file}?mode=ro", uri=True)
    try:
        tables = {r[0] for r in src.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        version = None
        if "meta" in tables:
            version = src.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
    except sqlite3.DatabaseError as exc:
        src.close()
        raise EgovidError(f"{file} is not a catalogue backup ({exc})", fix) from None
    missing = [t for t in DATA_TABLES[:5] if t not in tables]
    if missing or version is None:
        src.close()
        raise EgovidError(f"{file} is not a catalogue backup (no {', '.join(missing) or 'schema version'})", fix)
    fleet = src.execute("SELECT value FROM meta WHERE key = 'fleet_schema'").fetchone()
    if int(version[0]) > SCHEMA_VERSION or (fleet is not None and int(fleet[0]) > FLEET_SCHEMA):
        src.close()
        raise EgovidError(f"{file} is a backup of a newer egovid's catalogue", "upgrade egovid")
    return src


def check_restore(file: str | os.PathLike, archive: Archive) -> None:
    """Refuse, before anything is written, a restore of ``file`` into ``archive``: the file must be
    a catalogue backup and the archive's catalogue empty (no drive, no path, no origin)."""
    _open_backup(Path(file)).close()
    cat = archive.catalogue
    if cat.drives() or cat.paths() or archive.origin is not None:
        raise EgovidError(
            f"the archive {archive.root} is not empty ({len(cat.drives())} drive(s))",
            "restore into a new archive: `egovid dashcam init NEW` (with --db/--blobs as wanted), then restore into it",
        )


def restore_catalogue(file: str | os.PathLike, archive: Archive) -> BackupReport:
    """Load a catalogue backup into an empty archive (see the module docstring), in one
    transaction; the spatial indexes are rebuilt from the rows."""
    file = Path(file)
    check_restore(file, archive)
    src = _open_backup(file)
    cat = archive.catalogue
    store = FleetStore(cat)  # the target's fleet tables exist before the transaction
    report = BackupReport(file)
    try:
        with archive.locks.maintenance("restore"), cat.transaction():
            check_restore(file, archive)  # nobody ingested meanwhile
            present = {r[0] for r in src.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            if "drive_readings" in present:
                readings.ensure_table(cat)
            for table in (t for t in DATA_TABLES if t in present):
                report.rows[table] = _copy_table(src, cat, table)
            for p in cat.paths():
                cat._index_path(p.id, p.points)
            for (did,) in cat._q("SELECT drive_id FROM drive_tracks").fetchall():
                t, lat, lon = store.track(int(did))
                if len(t):
                    store._index_track(int(did), t, lat, lon)
            if isinstance(cat, PostgresCatalogue):
                _reset_identities(cat)
    finally:
        src.close()
    return report


def _copy_table(src: sqlite3.Connection, cat, table: str) -> int:
    """Rows of one table from the backup into the catalogue (the columns both have); their count."""
    cols_src = [r[1] for r in src.execute(f"PRAGMA table_info({table})")]
    have = set(_columns(cat, table))
    cols = [c for c in cols_src if c in have]
    where = f" WHERE key NOT IN ({', '.join('?' * len(_OWN_META))})" if table == "meta" else ""
    cur = src.execute(f"SELECT {', '.join(cols)} FROM {table}{where}", _OWN_META if where else ())
    sql = f"INSERT INTO {table}({', '.join(cols)}) VALUES({', '.join('?' * len(cols))})"
    n = 0
    while batch := cur.fetchmany(_BATCH):
        for row in batch:
            cat._q(sql, row)
        n += len(batch)
    return n


def _columns(cat, table: str) -> list[str]:
    if isinstance(cat, SqliteCatalogue):
        return [r[1] for r in cat._q(f"PRAGMA table_info({table})")]
    rows = cat._q(
        "SELECT column_name FROM information_schema.columns WHERE table_schema = ? AND table_name = ?",
        (cat.schema, table),
    )
    return [r[0] for r in rows]


def _reset_identities(cat: PostgresCatalogue) -> None:
    """PostgreSQL's identity columns continue after the restored ids."""
    rows = cat._q(
        "SELECT table_name FROM information_schema.columns WHERE table_schema = ? AND column_name = 'id' "
        "AND is_identity = 'YES'",
        (cat.schema,),
    ).fetchall()
    for (table,) in rows:
        cat._q(
            f"SELECT setval(pg_get_serial_sequence('\"{cat.schema}\".\"{table}\"', 'id'), "
            f'COALESCE((SELECT MAX(id) FROM "{table}"), 0) + 1, false)'
        )


def _count_rows(file: Path) -> dict[str, int]:
    db = sqlite3.connect(str(file))
    try:
        present = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        return {t: int(db.execute(f"SELECT count(*) FROM {t}").fetchone()[0]) for t in DATA_TABLES if t in present}
    finally:
        db.close()
