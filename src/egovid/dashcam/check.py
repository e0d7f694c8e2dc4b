"""``egovid dashcam check``: verify an archive, and with ``--repair`` rebuild what can be rebuilt.

:func:`check_archive` verifies the catalogue (on opening: see
:mod:`egovid.dashcam.archive.catalogue_file`), every bitstream (present, its SHA-256 matches its
name; a blob in an object store is read back whole), the blobs no drive uses (listed by name),
the cameras of multi-camera drives (each a drive row of its own, checked like any drive, tied
to a drive that exists), every drive's segments (they tile its frames) and reference chains (no drive depends on a
missing drive or, through others, on itself); with ``deep`` it decodes every drive and compares
the pictures with the encoder's digests. With ``repair`` it restores a damaged or missing SQLite
catalogue from its backup (or salvages what SQLite can still read), rebuilds the spatial index,
deletes the temporary files of interrupted ingests and writes a fresh backup. Bitstreams are never
rebuilt or deleted: a missing or corrupt one is reported with the drives it takes down.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from egovid.core.errors import EgovidError
from egovid.dashcam.archive import catalogue_file as cfile
from egovid.dashcam.archive.blobs import BlobFile
from egovid.dashcam.archive.catalogue import SCHEMA_VERSION, Drive, Segment, SqliteCatalogue
from egovid.dashcam.archive.fleetstore import channel_of_drives, fleet_version
from egovid.dashcam.archive.references import reference_cycle
from egovid.dashcam.archive.store import Archive, open_archive, read_marker
from egovid.dashcam.extract import checked_frames

Progress = Callable[[str, int, int], None]
ORPHANS_LISTED = 20  # names of unused bitstreams ``check`` prints (the count is always given)


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
    """What ``check`` found in the archive at ``root``, and what it verified: drives, segments,
    intact bitstreams and their bytes, frames decoded and compared (``deep``)."""

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

    def failure(self, repaired: bool) -> EgovidError | None:
        """The error a check ends with (None: the archive is sound): the problem itself when it is
        the only one and ``--repair`` was not tried, else how many (they are listed above it)."""
        if len(self.errors) == 1 and not repaired:
            return EgovidError(self.errors[0].problem, self.errors[0].fix or cfile.repair_fix(self.root))
        if not self.errors:
            return None
        fix = (
            "what --repair could not rebuild must come from a backup of the archive, or its drives re-ingested"
            if repaired
            else cfile.repair_fix(self.root)
        )
        return EgovidError(f"archive {self.root} has {len(self.errors)} problem(s) (listed above)", fix)


def _repair_sqlite(root: Path, problem: str, report: CheckReport) -> bool:
    """Restore a missing or damaged SQLite catalogue: the backup if sound, else what SQLite can
    salvage of the damaged file, else (no bitstreams at all) a fresh empty catalogue. The damaged
    file is kept beside it, never deleted. True when a usable catalogue is in place."""
    path = root / cfile.CATALOGUE_FILE
    kept = cfile.set_aside(path) if path.exists() else None
    where = f" (the damaged file is kept as {kept.name})" if kept else ""
    if cfile.restore_backup(path, SCHEMA_VERSION):
        report.add("error", f"catalogue {problem}", f"restored from its last backup{where}", repaired=True)
        return True
    if kept is not None and cfile.salvage(kept, path, SCHEMA_VERSION):
        report.add("error", f"catalogue {problem}", f"rebuilt from what SQLite could still read{where}", repaired=True)
        return True
    if cfile.local_blob_count(root) == 0:
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
    progress: Progress | None = None,
) -> CheckReport:
    """Verify the archive at ``root`` (see the module docstring); with ``repair``, rebuild what
    can be rebuilt. Never raises for a damaged archive: everything found is in the report.
    ``progress(stage, done, total)``: called as bitstreams are read and frames decoded."""
    root = Path(root)
    report = CheckReport(root)
    meta = read_marker(root)  # not an archive, or a broken marker: one clear error
    sqlite = (meta.get("catalogue") or {}).get("backend", "sqlite") == "sqlite"
    if sqlite:
        problem = cfile.file_problem(root / cfile.CATALOGUE_FILE, SCHEMA_VERSION)
        if problem is not None:
            if not repair:
                exc = cfile.unusable_catalogue(root / cfile.CATALOGUE_FILE, problem)
                report.add("error", exc.problem, exc.fix or "")
                return report
            if not _repair_sqlite(root, problem, report):
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


@dataclass
class _Contents:
    """What the catalogue says the archive holds, read once: drives, their segments, the files of
    the blob store, and the drives found unreadable so far."""

    archive: Archive
    drives: dict[int, Drive]
    segs: dict[int, list[Segment]]
    files: dict[str, BlobFile]
    unreadable: set[int] = field(default_factory=set)

    def name(self, d: int) -> str:
        return self.drives[d].name if d in self.drives else f"#{d}"

    def refs(self) -> dict[int, set[int]]:
        """Drive -> the drives its segments are coded against."""
        return {d: {int(g.ref_drive_id) for g in s if g.ref_drive_id is not None} for d, s in self.segs.items()}

    def blob_users(self) -> dict[str, list[Segment]]:
        """Bitstream -> the segments stored in it."""
        used: dict[str, list[Segment]] = {}
        for s in self.segs.values():
            for g in s:
                used.setdefault(g.blob, []).append(g)
        return used


def _check_contents(archive: Archive, report: CheckReport, *, repair: bool, deep: bool, progress) -> None:
    cat = archive.catalogue
    drives = {d.id: d for d in cat.drives()}
    c = _Contents(archive, drives, {d: cat.segments(d) for d in drives}, {f.name: f for f in archive.blobs.files()})
    report.drives = len(drives)
    report.segments = sum(len(s) for s in c.segs.values())
    _check_tiling(c, report)
    _check_channels(c, report)
    _check_chains(c, report)
    used = c.blob_users()
    _check_bitstreams(c, report, used, progress)
    streams = cat.streams_blobs()
    _check_streams(c, report, streams)
    _spread_unreadable(c, report)
    _check_leftovers(c, report, set(used) | set(streams), repair)
    if isinstance(cat, SqliteCatalogue):
        _check_sqlite(cat, report, repair)
    if deep:
        _decode_all(c, report, progress)


def _check_tiling(c: _Contents, report: CheckReport) -> None:
    """Segments tile each drive's frames, and refer to drives that exist."""
    for d, drive in c.drives.items():
        at = 0
        for g in sorted(c.segs[d], key=lambda g: g.frame_start):
            if g.frame_start != at:
                report.add("error", f"drive {drive.name}: frames {at}-{g.frame_start - 1} are in no segment")
                c.unreadable.add(d)
            at = max(at, g.frame_end)
            if g.ref_drive_id is not None and g.ref_drive_id not in c.drives:
                report.add(
                    "error", f"drive {drive.name}: segment {g.id} refers to drive #{g.ref_drive_id}, not in the archive"
                )
                c.unreadable.add(d)
        if at != drive.frames:
            report.add("error", f"drive {drive.name}: the catalogue says {drive.frames} frames, its segments hold {at}")
            c.unreadable.add(d)


def _check_channels(c: _Contents, report: CheckReport) -> None:
    """The cameras of multi-camera drives (fleet tables version 2): each tied to a drive that
    exists and recorded as the camera it is (their bitstreams are checked with every drive's)."""
    cat = c.archive.catalogue
    if fleet_version(cat) < 2:
        return
    cameras = channel_of_drives(cat)
    rows = cat._q("SELECT drive_id, primary_id, channel FROM drive_channels ORDER BY drive_id").fetchall()
    for i, p, ch in rows:
        i, p = int(i), int(p)
        if i not in c.drives or p not in c.drives:
            report.add("error", f"the {ch} camera #{i} of drive {c.name(p)} refers to a drive not in the archive")
        elif cameras.get(i, ch) != ch:
            report.add("error", f"drive {c.name(i)} is the {ch} camera of {c.name(p)} but records {cameras[i]!r}")


def _check_chains(c: _Contents, report: CheckReport) -> None:
    """Every reference chain ends at a root: each loop is reported once, its drives unreadable."""
    refs = c.refs()
    looped: set[int] = set()
    for d in c.drives:
        cycle = reference_cycle(refs, d)
        if cycle and not set(cycle) <= looped:
            looped |= set(cycle)
            report.add("error", f"reference chain loops: {' -> '.join(c.name(x) for x in cycle)}", "cannot be repaired")
    c.unreadable |= looped


def _blob_problem(c: _Contents, sha: str) -> str | None:
    """``missing`` or ``corrupt`` (read whole, its SHA-256 checked), or None for a sound blob."""
    if sha not in c.files:
        return "missing"
    try:
        c.archive.blobs.get(sha)  # reads it and checks its SHA-256
    except EgovidError:
        return "corrupt"
    return None


def _check_bitstreams(c: _Contents, report: CheckReport, used: dict[str, list[Segment]], progress) -> None:
    """The segments' bitstreams: present and intact; the drives of a bad one are unreadable."""
    for k, (sha, users) in enumerate(sorted(used.items())):
        if progress:
            progress("bitstreams", k, len(used))
        problem = _blob_problem(c, sha)
        if problem:
            owners = ", ".join(sorted({c.name(g.drive_id) for g in users}))
            report.add("error", f"bitstream {sha[:12]} of drive {owners} is {problem}", "restore it from a backup")
            c.unreadable |= {g.drive_id for g in users}
            continue
        report.blobs += 1
        report.blob_bytes += c.files[sha].size
    if progress:
        progress("bitstreams", len(used), len(used))


def _check_streams(c: _Contents, report: CheckReport, streams: dict[str, list[int]]) -> None:
    """The drives' audio and telemetry blobs (their frames stay readable without them)."""
    for sha, holders in sorted(streams.items()):
        problem = _blob_problem(c, sha)
        if problem:
            owners = ", ".join(sorted({c.name(d) for d in holders}))
            report.add(
                "error",
                f"the audio and telemetry of drive {owners} ({sha[:12]}) are {problem}",
                "restore it from a backup",
            )
            continue
        report.blobs += 1
        report.blob_bytes += c.files[sha].size


def _spread_unreadable(c: _Contents, report: CheckReport) -> None:
    """Drives that depend on an unreadable one cannot be read either."""
    refs = c.refs()
    changed = True
    while changed:
        changed = False
        for d, r in refs.items():
            if d not in c.unreadable and r & c.unreadable:
                c.unreadable.add(d)
                changed = True
                down = ", ".join(c.name(x) for x in sorted(r & c.unreadable))
                report.add("error", f"drive {c.name(d)} is coded against an unreadable drive ({down})")


def _check_leftovers(c: _Contents, report: CheckReport, referenced: set[str], repair: bool) -> None:
    """Temporary files of interrupted ingests (deleted with ``repair``), and space gc can free."""
    temps = [f for f in c.files.values() if not f.is_blob]
    orphans = [f for f in c.files.values() if f.is_blob and f.name not in referenced]
    if temps:
        what = f"{len(temps)} temporary file(s) of interrupted ingests ({sum(f.size for f in temps)} bytes)"
        if repair:
            with c.archive.locks.maintenance("check --repair"):
                for f in temps:
                    c.archive.blobs.delete(f.name)
            report.add("note", what, "deleted", True)
        else:
            report.add("note", what, "--repair or gc deletes them")
    if orphans:
        report.add(
            "note",
            f"{len(orphans)} bitstream(s) no drive uses ({sum(f.size for f in orphans)} bytes): "
            + ", ".join(sorted(f.name for f in orphans)[:ORPHANS_LISTED])
            + (" …" if len(orphans) > ORPHANS_LISTED else ""),
            "`egovid dashcam gc` frees them",
        )


def _check_sqlite(cat: SqliteCatalogue, report: CheckReport, repair: bool) -> None:
    """SQLite only: foreign keys, the spatial index (rebuilt with ``repair``) and the backup."""
    dangling = cat.dangling_rows()
    if dangling:
        report.add(
            "error", f"{len(dangling)} catalogue row(s) refer to rows that do not exist (first: table {dangling[0][0]})"
        )
    if not cat.spatial_index_sound():
        if repair:
            cat.rebuild_spatial_index()
        report.add(
            "error",
            "the spatial index of the paths is inconsistent",
            "rebuilt from the paths" if repair else "--repair rebuilds it",
            repair,
        )
    if repair and not report.errors:
        cat.write_backup()
    elif not cat.has_backup():
        report.add("note", "the catalogue has no backup yet", "--repair writes one (every ingest does too)")


def _decode_all(c: _Contents, report: CheckReport, progress) -> None:
    """Decode every readable drive and compare with the encoder's digests."""
    readable = {d: drive for d, drive in c.drives.items() if d not in c.unreadable}
    total = sum(drive.frames for drive in readable.values())
    done = 0
    for d, drive in readable.items():
        try:
            for g in c.segs[d]:
                for _ in checked_frames(c.archive, drive.name, g, g.frame_start, g.frame_end):
                    done += 1
                    if progress and done % 16 == 0:
                        progress("decoding", done, total)
        except EgovidError as exc:
            report.add("error", exc.problem, "restore the drive's bitstreams from a backup, or re-ingest it")
    report.decoded_frames = done
    if progress:
        progress("decoding", done, max(total, done))
