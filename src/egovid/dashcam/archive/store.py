"""The archive as storage: its folder and marker, catalogue, blob store and locks, and ``gc``.

Layout of an archive folder::

    ARCHIVE/egovid-archive.json   marker: format version, catalogue settings, blob store; written
                                  once by ``init`` and never again
    ARCHIVE/catalogue.sqlite      drives, paths, sequences, segments, the metric plane's origin
                                  (see catalogue.py); with ``init --db postgresql://…`` these live
                                  in a PostgreSQL schema instead
    ARCHIVE/catalogue.sqlite.backup  its copy after every commit (see catalogue_file.py)
    ARCHIVE/blobs/ab/abcdef...    segment bitstreams, named by their SHA-256; with
                                  ``init --blobs s3://BUCKET/PREFIX`` they live in an object store
    ARCHIVE/.lock, .locks/        file locks (see locks.py); advisory locks with PostgreSQL

:func:`open_archive` is the one way to open an archive. Nothing here ingests: the catalogue is
written by the ingest's commit (``egovid.dashcam.ingest``), in one transaction with everything the
ingest decided, the origin of the metric plane included.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_text, temp_sibling, track_temp, untrack_temp
from egovid.dashcam.archive.blobs import BlobFile, BlobStore, FsspecBlobs, open_blobs
from egovid.dashcam.archive.catalogue import Catalogue, Drive, Segment, catalogue_settings, open_catalogue
from egovid.dashcam.archive.locks import ArchiveLocks, FileLocks, PgLocks
from egovid.dashcam.archive.postgres import redact_url

MARKER = "egovid-archive.json"
FORMAT_VERSION = 1
ORIGIN_META = "origin"


@dataclass(frozen=True)
class ArchiveSpec:
    """Everything a process needs to open an archive without its folder's marker (a Dask worker
    on another machine): the folder, the marker's contents."""

    root: str
    meta: dict


class Archive:
    """An open archive: :attr:`catalogue`, :attr:`blobs`, :attr:`locks`. Use :func:`open_archive`
    or :meth:`create`."""

    def __init__(self, root: str | os.PathLike, meta: dict | None = None) -> None:
        self.root = Path(root)
        if meta is None:
            meta = read_marker(self.root)
        self.meta = meta
        settings = meta.get("catalogue")
        self.catalogue: Catalogue = open_catalogue(self.root, settings)
        self.blobs: BlobStore = open_blobs(meta.get("blobs"), self.root)
        if (settings or {}).get("backend") == "postgresql":
            self.locks: ArchiveLocks = PgLocks(settings["url"], settings["schema"])
        else:
            self.locks = FileLocks(self.root)

    @classmethod
    def create(
        cls,
        root: str | os.PathLike,
        db: str | None = None,
        blobs: str | None = None,
        setup: Callable[[Catalogue], object] | None = None,
    ) -> Archive:
        """Create an empty archive at ``root``. ``db``: None or ``sqlite`` for the embedded SQLite
        catalogue (``root/catalogue.sqlite``), or a ``postgresql://`` URL: the catalogue then lives
        in a new schema of that database. ``blobs``: None for the folder ``root/blobs``, or an
        fsspec URL (``s3://BUCKET/PREFIX``). ``setup``: called with the new catalogue before the
        archive appears (more tables: a failure there, a full disk say, leaves no archive)."""
        root = Path(root)
        settings = catalogue_settings(db)
        if (root / MARKER).exists():
            raise EgovidError(f"{root} is already an egovid archive", "use it, or choose another folder")
        if root.exists() and any(root.iterdir()):
            raise EgovidError(f"{root} exists and is not empty", "give a new or empty folder")
        store = open_blobs(blobs, root)
        if isinstance(store, FsspecBlobs):  # reachable and writable, before anything is created
            store.check()
            if any(True for _ in store.files()):
                raise EgovidError(f"blob store {store.url} is not empty", "give a new prefix")
        if settings["backend"] != "sqlite":  # connect first: a bad URL leaves no folder behind
            _new_catalogue(root, settings, setup)
        # Built in a hidden sibling folder and renamed into place: a full disk or an interruption
        # leaves nothing behind.
        root.parent.mkdir(parents=True, exist_ok=True)
        tmp = track_temp(temp_sibling(root))
        try:
            tmp.mkdir()
            if blobs is None:
                (tmp / "blobs").mkdir()
            if settings["backend"] == "sqlite":
                _new_catalogue(tmp, settings, setup)
            meta = {"format": FORMAT_VERSION, "catalogue": settings}
            if blobs is not None:
                meta["blobs"] = blobs
            atomic_write_text(tmp / MARKER, json.dumps(meta, indent=1))
            if root.exists():
                root.rmdir()  # empty (checked above)
            os.rename(tmp, root)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        finally:
            untrack_temp(tmp)
        return cls(root, meta)

    @property
    def spec(self) -> ArchiveSpec:
        return ArchiveSpec(str(self.root), dict(self.meta))

    @classmethod
    def from_spec(cls, spec: ArchiveSpec) -> Archive:
        return cls(spec.root, spec.meta)

    # -- reading ------------------------------------------------------------------------------
    @property
    def where(self) -> str:
        """Where the catalogue lives, for people: ``SQLite``, or ``PostgreSQL URL, schema NAME``
        (the URL's password hidden)."""
        cat = self.meta.get("catalogue") or {"backend": "sqlite"}
        if cat.get("backend", "sqlite") == "sqlite":
            return "SQLite"
        return f"PostgreSQL {redact_url(cat['url'])}, schema {cat['schema']}"

    @property
    def origin(self) -> tuple[float, float] | None:
        """(latitude, longitude) degrees of the metric plane's origin; None before the first drive.
        Kept in the catalogue (set by the first ingest's commit); archives of the first format
        version kept it in the marker."""
        text = self.catalogue.get_meta(ORIGIN_META)
        o = json.loads(text) if text else self.meta.get("origin")
        return (float(o[0]), float(o[1])) if o else None

    def segments(self, drive_id: int) -> list[Segment]:
        return self.catalogue.segments(drive_id)

    def drive_or_fail(self, key: str) -> Drive:
        d = self.catalogue.drive(key)
        if d is None:
            names = ", ".join(x.name for x in self.catalogue.drives()) or "none"
            raise EgovidError(f"no drive {key!r} in {self.root}", f"drives in the archive: {names}")
        return d

    # -- maintenance --------------------------------------------------------------------------
    def collect_garbage(self, *, dry_run: bool = False) -> tuple[list[BlobFile], int]:
        """Delete the files of the blob store that no segment refers to — bitstreams and temporary
        files left by an ingest that crashed or was killed — and return them with their total size
        in bytes (``dry_run``: only list them). Holds the archive lock exclusively (refusing while
        an ingest runs: its new blobs are not in the catalogue until it commits)."""
        with self.locks.maintenance("gc"):
            used = self.catalogue.blob_names()
            junk = [f for f in self.blobs.files() if f.name not in used]
            if not dry_run:
                for f in junk:
                    self.blobs.delete(f.name)
        return junk, sum(f.size for f in junk)

    def close(self) -> None:
        self.catalogue.close()

    def __enter__(self) -> Archive:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _new_catalogue(root: Path, settings: dict, setup: Callable[[Catalogue], object] | None) -> None:
    cat = open_catalogue(root, settings, create=True)
    try:
        if setup is not None:
            setup(cat)
    finally:
        cat.close()


def read_marker(root: Path) -> dict:
    """The marker of the archive at ``root`` (checked)."""
    marker = root / MARKER
    if not marker.exists():
        raise EgovidError(f"{root} is not an egovid archive", "create one with `egovid dashcam init`")
    try:
        meta = json.loads(marker.read_text())
    except (ValueError, UnicodeDecodeError):
        raise EgovidError(f"the marker {marker} is not valid JSON", "restore it from a backup") from None
    if not isinstance(meta, dict):
        raise EgovidError(f"the marker {marker} is not an egovid archive marker", "restore it from a backup")
    if meta.get("format") != FORMAT_VERSION:
        raise EgovidError(f"archive format {meta.get('format')} is not supported", "upgrade egovid")
    return meta


def open_archive(root: str | os.PathLike) -> Archive:
    """Open the archive at ``root``: the marker, its catalogue, blob store and locks. Raises
    :class:`EgovidError` when it is not an archive or cannot be opened."""
    return Archive(root)
