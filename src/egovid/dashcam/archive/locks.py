"""Locks that let many ingests share one archive: file locks beside an SQLite catalogue, advisory
locks in a PostgreSQL one (so ingests on several machines see each other).

Two kinds:

* the **archive lock**: every ingest holds it *shared* from its plan to its commit (the blobs it
  writes are not referenced by the catalogue until then); maintenance that deletes blobs (``gc``)
  takes it *exclusive*, and refuses rather than waits when an ingest is running;
* **area locks**, exclusive, one per named area (:func:`cell_keys`: squares of the archive's metric
  plane, plus ``origin`` while an archive has none): an ingest holds the areas its drive crosses
  and those of every path it may split, from before it reads the paths to after its commit. Drives
  of other places ingest at the same time; a drive on the same road waits until the one before it
  is committed, and then finds it as its baseline. Areas are always acquired in sorted order, and
  when a session needs an area below one it holds it releases everything and starts again in
  order, so two sessions never wait for each other in a cycle.

A process that dies (kill -9, a Dask worker lost) loses its locks with it: the kernel closes its
files, the database server its connection.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np

from egovid.core.errors import EgovidError
from egovid.dashcam.archive.postgres import pg_connect

CELL = 250.0  # metres: side of an area-lock square
FILE_LOCKS = 256  # lock files an SQLite archive's areas are hashed onto
ORIGIN_KEY = "_origin"  # sorts before the cells: taken first
_BUSY = "wait for the running ingest to finish (nothing is lost by waiting), then run it again"


def cell_keys(xy: np.ndarray, pad: float = 0.0) -> set[str]:
    """Area keys (``c{ix}_{iy}``) of the squares that the points ``xy`` (N, 2, metres), and the
    segments between consecutive points (sampled every ``CELL / 4`` metres), come within ``pad``
    metres of (in x and in y)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(xy) > 1:
        seg = np.diff(xy, axis=0)
        n = np.maximum(1, np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / (CELL / 4))).astype(int)
        parts = [xy[:-1][i] + seg[i] * (np.arange(n[i])[:, None] / n[i]) for i in range(len(seg))]
        xy = np.vstack([*parts, xy[-1:]])
    lo = np.floor((xy - pad) / CELL).astype(np.int64)
    hi = np.floor((xy + pad) / CELL).astype(np.int64)
    keys: set[str] = set()
    for (i0, j0), (i1, j1) in zip(lo, hi, strict=True):
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                keys.add(f"c{i}_{j}")
    return keys


class AreaSession(ABC):
    """Area locks held by one ingest; grows with :meth:`acquire`, freed by :meth:`release`."""

    def __init__(self, on_wait: Callable[[str], None] | None = None) -> None:
        self.held: list[str] = []  # lock names, in the order taken (sorted)
        self.keys: set[str] = set()  # the area keys they stand for
        self.on_wait = on_wait

    def _name(self, key: str) -> str:
        """The lock that stands for ``key`` (several keys may share one)."""
        return key

    def acquire(self, keys: Iterable[str]) -> None:
        """Hold ``keys`` too (blocking until they are free)."""
        keys = set(keys)
        want = sorted({self._name(k) for k in keys} - set(self.held))
        self.keys |= keys
        if not want:
            return
        if self.held and want[0] < self.held[-1]:  # out of order: start again in order
            everything = sorted(set(self.held) | set(want))
            self.release()
            want = everything
        for key in want:
            if not self._try(key):
                if self.on_wait is not None:
                    self.on_wait(key)
                self._wait(key)
            self.held.append(key)

    def release(self) -> None:
        for key in reversed(self.held):
            self._unlock(key)
        self.held = []

    @abstractmethod
    def _try(self, key: str) -> bool: ...

    @abstractmethod
    def _wait(self, key: str) -> None: ...

    @abstractmethod
    def _unlock(self, key: str) -> None: ...

    def close(self) -> None:
        self.release()
        self.keys = set()


class ArchiveLocks(ABC):
    """The locks of one archive (see the module docstring)."""

    @abstractmethod
    @contextlib.contextmanager
    def ingest(self, on_wait: Callable[[str], None] | None = None) -> Iterator[AreaSession]:
        """Hold the archive lock shared (waiting for maintenance to finish) and yield an empty
        area session, released at the end (``on_wait(key)`` is called before waiting for an area)."""

    @abstractmethod
    @contextlib.contextmanager
    def maintenance(self, what: str) -> Iterator[None]:
        """Hold the archive lock exclusively, or raise :class:`EgovidError` at once when an
        ingest holds it (``what``: the command, for the message)."""


# -- files (SQLite catalogue) ------------------------------------------------------------------


class _FileSession(AreaSession):
    """Area keys hashed onto :data:`FILE_LOCKS` lock files (a bounded number of files, however
    large the fleet's territory; two areas sharing a file only wait for each other)."""

    def __init__(self, folder: Path, on_wait) -> None:
        super().__init__(on_wait)
        self.folder = folder
        self._fh: dict[str, object] = {}

    def _name(self, key: str) -> str:
        return f"{int.from_bytes(hashlib.sha256(key.encode()).digest()[:4], 'big') % FILE_LOCKS:03d}"

    def _open(self, key: str):
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", key):
            raise ValueError(f"bad lock key {key!r}")
        self.folder.mkdir(exist_ok=True)
        fh = open(self.folder / f"{key}.lock", "a+")  # noqa: SIM115 - held until _unlock
        self._fh[key] = fh
        return fh

    def _try(self, key: str) -> bool:
        fh = self._open(key)
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            return False

    def _wait(self, key: str) -> None:
        fcntl.flock(self._fh[key], fcntl.LOCK_EX)

    def _unlock(self, key: str) -> None:
        fh = self._fh.pop(key, None)
        if fh is not None:
            fcntl.flock(fh, fcntl.LOCK_UN)
            fh.close()


class FileLocks(ArchiveLocks):
    """flock(2) locks on files in the archive folder: ``.lock`` (the archive lock) and
    ``.locks/NNN.lock`` (areas, hashed onto 256 files). Each session opens its own files, so
    threads of one process exclude each other as separate processes do."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)

    @contextlib.contextmanager
    def ingest(self, on_wait: Callable[[str], None] | None = None) -> Iterator[AreaSession]:
        with open(self.root / ".lock", "a+") as fh:
            fcntl.flock(fh, fcntl.LOCK_SH)
            session = _FileSession(self.root / ".locks", on_wait)
            try:
                yield session
            finally:
                session.close()
                fcntl.flock(fh, fcntl.LOCK_UN)

    @contextlib.contextmanager
    def maintenance(self, what: str) -> Iterator[None]:
        with open(self.root / ".lock", "a+") as fh:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise EgovidError(f"{self.root} is busy with an ingest; {what} did nothing", _BUSY) from None
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)


# -- PostgreSQL advisory locks -----------------------------------------------------------------


def _pg_key(schema: str, key: str) -> int:
    """A signed 64-bit advisory-lock key for ``key`` in this archive's schema."""
    return int.from_bytes(hashlib.sha256(f"{schema}/{key}".encode()).digest()[:8], "big", signed=True)


class _PgSession(AreaSession):
    def __init__(self, db, schema: str, on_wait) -> None:
        super().__init__(on_wait)
        self.db, self.schema = db, schema

    def _try(self, key: str) -> bool:
        return bool(self.db.execute("SELECT pg_try_advisory_lock(%s)", (_pg_key(self.schema, key),)).fetchone()[0])

    def _wait(self, key: str) -> None:
        self.db.execute("SELECT pg_advisory_lock(%s)", (_pg_key(self.schema, key),))

    def _unlock(self, key: str) -> None:
        self.db.execute("SELECT pg_advisory_unlock(%s)", (_pg_key(self.schema, key),))


class PgLocks(ArchiveLocks):
    """Session-level advisory locks on a connection of their own (one per ingest), keyed by the
    archive's schema, so ingests on different machines sharing the catalogue exclude each other."""

    def __init__(self, url: str, schema: str) -> None:
        self.url, self.schema = url, schema

    @contextlib.contextmanager
    def ingest(self, on_wait: Callable[[str], None] | None = None) -> Iterator[AreaSession]:
        db = pg_connect(self.url)
        try:
            db.execute("SELECT pg_advisory_lock_shared(%s)", (_pg_key(self.schema, ".archive"),))
            session = _PgSession(db, self.schema, on_wait)
            try:
                yield session
            finally:
                session.close()
        finally:
            db.close()  # ends the session: every lock it held goes with it

    @contextlib.contextmanager
    def maintenance(self, what: str) -> Iterator[None]:
        db = pg_connect(self.url)
        try:
            got = db.execute("SELECT pg_try_advisory_lock(%s)", (_pg_key(self.schema, ".archive"),)).fetchone()[0]
            if not got:
                raise EgovidError(
                    f"the archive (schema {self.schema}) is busy with an ingest; {what} did nothing", _BUSY
                )
            yield
        finally:
            db.close()
