"""Archive integrity: what opening an archive checks, what ``egovid dashcam check`` verifies and
what ``--repair`` rebuilds.

* The SQLite catalogue is checked whenever it is opened (:func:`catalogue_problem`: SQLite's
  quick check, the tables, the schema version). A missing catalogue is an error, never a fresh
  empty one (the archive may hold bitstreams only the catalogue can make sense of).
* After every committed write the SQLite catalogue is copied (SQLite's online backup) to
  ``catalogue.sqlite.backup`` (:func:`write_backup`): a damaged or deleted catalogue can then be
  restored to its last commit.
* :func:`check_archive` verifies the catalogue, every bitstream (present, its SHA-256 matches its
  name), every drive's segments (they tile its frames) and reference chains (no drive depends on a
  missing drive or, through others, on itself); with ``deep`` it decodes every drive and compares
  the pictures with the encoder's digests. With ``repair`` it restores a damaged or missing
  catalogue from its backup (or salvages what SQLite can still read), rebuilds the spatial index,
  deletes the temporary files of interrupted ingests and writes a fresh backup. Bitstreams are
  never rebuilt or deleted: a missing or corrupt one is reported with the drives it takes down.
"""

from __future__ import annotations

import datetime as dt
import os
import sqlite3
import urllib.parse
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from egovid.core.errors import EgovidError

CATALOGUE_FILE = "catalogue.sqlite"
TABLES = ("meta", "drives", "paths", "segments", "sequences")


def repair_fix(root: str | os.PathLike) -> str:
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
    import threading

    from egovid.core.files import track_temp, untrack_temp

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


# -- reference chains ------------------------------------------------------------------------------
def reference_cycle(refs: dict[int, set[int]], start: int) -> list[int] | None:
    """A cycle reachable from drive ``start`` in the graph ``refs`` (drive -> drives its segments
    are coded against), as the list of drives around it; None when every chain ends at a root."""
    state: dict[int, int] = {}  # 1 = on the current path, 2 = done
    path: list[int] = []
    stack: list[tuple[int, Iterable[int]]] = [(start, iter(sorted(refs.get(start, ()))))]
    state[start] = 1
    path.append(start)
    while stack:
        node, children = stack[-1]
        child = next(children, None)  # type: ignore[call-overload]
        if child is None:
            stack.pop()
            path.pop()
            state[node] = 2
            continue
        if state.get(child) == 1:
            return [*path[path.index(child) :], child]
        if child not in state:
            state[child] = 1
            path.append(child)
            stack.append((child, iter(sorted(refs.get(child, ())))))
    return None


def check_chain(source, drive_id: int, names: Callable[[int], str] | None = None) -> None:
    """Raise :class:`EgovidError` when drive ``drive_id`` cannot be decoded because its reference
    chain (through ``source.segments``) loops back on itself (a self-reference included)."""
    refs: dict[int, set[int]] = {}
    todo = [int(drive_id)]
    while todo:
        d = todo.pop()
        if d in refs:
            continue
        refs[d] = {int(g.ref_drive_id) for g in source.segments(d) if g.ref_drive_id is not None}
        todo += [r for r in refs[d] if r not in refs]
    cycle = reference_cycle(refs, int(drive_id))
    if cycle:
        label = names or str
        raise EgovidError(
            f"drive {label(int(drive_id))} cannot be decoded: its references loop "
            f"({' -> '.join(label(d) for d in cycle)})",
            f"the catalogue is damaged; {repair_fix(getattr(source, 'root', 'ARCHIVE'))} to see what is lost",
        )


# -- the check -------------------------------------------------------------------------------------
@dataclass
class Finding:
    """One thing ``check`` found: ``severity`` is ``error`` (something cannot be read back) or
    ``note`` (harmless: leftovers, space that gc can free); ``repaired`` says --repair fixed it."""

    severity: str
    problem: str
    fix: str = ""
    repaired: bool = False


@dataclass
class CheckReport:
    root: Path
    findings: list[Finding] = field(default_factory=list)
    drives: int = 0
    segments: int = 0
    blobs: int = 0
    blob_bytes: int = 0
    decoded_frames: int = 0

    def add(self, severity: str, problem: str, fix: str = "", repaired: bool = False) -> Finding:
        f = Finding(severity, problem, fix, repaired)
        self.findings.append(f)
        return f

    @property
    def errors(self) -> list[Finding]:
        """Errors still there (not repaired)."""
        return [f for f in self.findings if f.severity == "error" and not f.repaired]


def _aside(path: Path) -> Path:
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    return path.with_name(f"{path.name}.damaged-{stamp}")


def _salvage(damaged: Path, target: Path, newest_schema: int) -> bool:
    """Copy what SQLite can still read of ``damaged`` into a new ``target``; True if usable."""
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


def _repair_sqlite(root: Path, problem: str, report: CheckReport, newest_schema: int) -> bool:
    """Restore a missing or damaged SQLite catalogue: the backup if sound, else what SQLite can
    salvage of the damaged file, else (no bitstreams at all) a fresh empty catalogue. The damaged
    file is kept beside it, never deleted. True when a usable catalogue is in place."""
    from egovid.dashcam.archive.catalogue import SqliteCatalogue

    path = root / CATALOGUE_FILE
    kept = None
    if path.exists():
        kept = _aside(path)
        os.replace(path, kept)
        for extra in ("-wal", "-shm"):
            side = path.with_name(path.name + extra)
            if side.exists():
                os.replace(side, kept.with_name(kept.name + extra))
    where = f" (the damaged file is kept as {kept.name})" if kept else ""
    backup = backup_path(path)
    if backup.exists():
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
        if sound:
            report.add("error", f"catalogue {problem}", f"restored from its last backup{where}", repaired=True)
            return True
    if kept is not None and _salvage(kept, path, newest_schema):
        report.add("error", f"catalogue {problem}", f"rebuilt from what SQLite could still read{where}", repaired=True)
        return True
    if local_blob_count(root) == 0:
        SqliteCatalogue(path, create=True).close()
        report.add(
            "error", f"catalogue {problem}", f"the archive held no bitstreams: a new empty catalogue{where}", True
        )
        return True
    if kept is not None:  # put it back: better a damaged file than none
        os.replace(kept, path)
    report.add(
        "error",
        f"catalogue {problem}, with no usable backup",
        "cannot be rebuilt: restore catalogue.sqlite from a backup of the archive, or re-ingest the drives",
    )
    return False


def check_archive(
    root: str | os.PathLike,
    *,
    repair: bool = False,
    deep: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
) -> CheckReport:
    """Verify the archive at ``root`` (see the module docstring); with ``repair``, rebuild what
    can be rebuilt. Never raises for a damaged archive: everything found is in the report."""
    from egovid.dashcam.archive.catalogue import SCHEMA_VERSION
    from egovid.dashcam.archive.store import open_archive, read_marker

    root = Path(root)
    report = CheckReport(root)
    meta = read_marker(root)  # not an archive, or a broken marker: one clear error
    sqlite = (meta.get("catalogue") or {}).get("backend", "sqlite") == "sqlite"
    if sqlite:
        problem = _file_problem(root / CATALOGUE_FILE, SCHEMA_VERSION)
        if problem is not None:
            if not repair:
                exc = unusable_catalogue(root / CATALOGUE_FILE, problem)
                report.add("error", exc.problem, exc.fix or "")
                return report
            if not _repair_sqlite(root, problem, report, SCHEMA_VERSION):
                return report
    try:
        archive = open_archive(root)
    except EgovidError as exc:
        report.add("error", exc.problem, exc.fix or "")
        return report
    try:
        _check_contents(archive, report, repair=repair, deep=deep, progress=progress)
    finally:
        archive.close()
    return report


def _file_problem(path: Path, newest_schema: int) -> str | None:
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


def _check_contents(archive, report: CheckReport, *, repair: bool, deep: bool, progress) -> None:
    cat = archive.catalogue
    drives = {d.id: d for d in cat.drives()}
    segs = {d: cat.segments(d) for d in drives}
    report.drives = len(drives)
    report.segments = sum(len(s) for s in segs.values())
    name = lambda d: drives[d].name if d in drives else f"#{d}"  # noqa: E731
    unreadable: set[int] = set()

    # segments tile each drive's frames, and refer to drives that exist
    for d, drive in drives.items():
        at = 0
        for g in sorted(segs[d], key=lambda g: g.frame_start):
            if g.frame_start != at:
                report.add("error", f"drive {drive.name}: frames {at}-{g.frame_start - 1} are in no segment")
                unreadable.add(d)
            at = max(at, g.frame_end)
            if g.ref_drive_id is not None and g.ref_drive_id not in drives:
                report.add(
                    "error", f"drive {drive.name}: segment {g.id} refers to drive #{g.ref_drive_id}, not in the archive"
                )
                unreadable.add(d)
        if at != drive.frames:
            report.add("error", f"drive {drive.name}: the catalogue says {drive.frames} frames, its segments hold {at}")
            unreadable.add(d)
    refs = {d: {int(g.ref_drive_id) for g in s if g.ref_drive_id is not None} for d, s in segs.items()}
    looped: set[int] = set()
    for d in drives:
        cycle = reference_cycle(refs, d)
        if cycle and not set(cycle) <= looped:
            looped |= set(cycle)
            report.add("error", f"reference chain loops: {' -> '.join(name(x) for x in cycle)}", "cannot be repaired")
    unreadable |= looped

    # bitstreams: present, intact
    used = {}
    for s in segs.values():
        for g in s:
            used.setdefault(g.blob, []).append(g)
    files = {f.name: f for f in archive.blobs.files()}
    bad_blobs: set[str] = set()
    for k, (sha, users) in enumerate(sorted(used.items())):
        if progress:
            progress("bitstreams", k, len(used))
        owners = ", ".join(sorted({name(g.drive_id) for g in users}))
        if sha not in files:
            report.add("error", f"bitstream {sha[:12]} of drive {owners} is missing", "restore it from a backup")
            bad_blobs.add(sha)
            continue
        try:
            archive.blobs.get(sha)  # reads it and checks its SHA-256
        except EgovidError:
            report.add("error", f"bitstream {sha[:12]} of drive {owners} is corrupt", "restore it from a backup")
            bad_blobs.add(sha)
            continue
        report.blobs += 1
        report.blob_bytes += files[sha].size
    if progress:
        progress("bitstreams", len(used), len(used))
    unreadable |= {g.drive_id for sha in bad_blobs for g in used[sha]}
    # the drives' audio and telemetry (their frames stay readable without them)
    streams = cat.streams_blobs()
    for sha, holders in sorted(streams.items()):
        owners = ", ".join(sorted({name(d) for d in holders}))
        problem = None
        if sha not in files:
            problem = "missing"
        else:
            try:
                archive.blobs.get(sha)
            except EgovidError:
                problem = "corrupt"
        if problem:
            report.add(
                "error",
                f"the audio and telemetry of drive {owners} ({sha[:12]}) are {problem}",
                "restore it from a backup",
            )
            continue
        report.blobs += 1
        report.blob_bytes += files[sha].size

    # drives that depend on an unreadable one cannot be read either
    changed = True
    while changed:
        changed = False
        for d, r in refs.items():
            if d not in unreadable and r & unreadable:
                unreadable.add(d)
                changed = True
                down = ", ".join(name(x) for x in sorted(r & unreadable))
                report.add("error", f"drive {name(d)} is coded against an unreadable drive ({down})")

    # leftovers of interrupted ingests, and space gc can free
    temps = [f for f in files.values() if not f.is_blob]
    orphans = [f for f in files.values() if f.is_blob and f.name not in used and f.name not in streams]
    if temps:
        size = sum(f.size for f in temps)
        if repair:
            with archive.locks.maintenance("check --repair"):
                for f in temps:
                    archive.blobs.delete(f.name)
            report.add("note", f"{len(temps)} temporary file(s) of interrupted ingests ({size} bytes)", "deleted", True)
        else:
            report.add(
                "note",
                f"{len(temps)} temporary file(s) of interrupted ingests ({size} bytes)",
                "--repair or gc deletes them",
            )
    if orphans:
        report.add(
            "note",
            f"{len(orphans)} bitstream(s) no drive uses ({sum(f.size for f in orphans)} bytes)",
            "`egovid dashcam gc` frees them",
        )

    # SQLite only: foreign keys and the spatial index
    db = getattr(cat, "_db", None)
    if isinstance(db, sqlite3.Connection):
        fk = db.execute("PRAGMA foreign_key_check").fetchall()
        if fk:
            report.add("error", f"{len(fk)} catalogue row(s) refer to rows that do not exist (first: table {fk[0][0]})")
        try:
            index_ok = db.execute("SELECT rtreecheck('path_index')").fetchone()[0] == "ok"
            index_ok = index_ok and _index_covers_paths(cat)
        except sqlite3.DatabaseError:
            index_ok = False
        if not index_ok:
            if repair:
                with cat.transaction():
                    cat._q("DELETE FROM path_index")
                    for p in cat.paths():
                        cat._index_path(p.id, p.points)
            report.add(
                "error",
                "the spatial index of the paths is inconsistent",
                "rebuilt from the paths" if repair else "--repair rebuilds it",
                repair,
            )
        if repair and not report.errors:
            write_backup(db, cat.file)
        elif not backup_path(cat.file).exists():
            report.add("note", "the catalogue has no backup yet", "--repair writes one (every ingest does too)")

    # deep: decode everything and compare with the encoder's digests
    if deep:
        from egovid.dashcam.extract import checked_frames

        total = sum(drives[d].frames for d in drives if d not in unreadable)
        done = 0
        for d, drive in drives.items():
            if d in unreadable:
                continue
            try:
                for g in segs[d]:
                    for _ in checked_frames(archive, drive.name, g, g.frame_start, g.frame_end):
                        done += 1
                        if progress and done % 16 == 0:
                            progress("decoding", done, total)
            except EgovidError as exc:
                report.add("error", exc.problem, "restore the drive's bitstreams from a backup, or re-ingest it")
        report.decoded_frames = done
        if progress:
            progress("decoding", done, max(total, done))


def _index_covers_paths(cat) -> bool:
    indexed = {r[0] for r in cat._q("SELECT DISTINCT path_id FROM path_index")}
    return indexed == {p.id for p in cat.paths()}
