"""Atomic file output: write to a temporary sibling, rename into place on success.

* :func:`atomic_path` yields a hidden temporary path next to the target and renames it into place
  when the block succeeds; on any exception (an interruption included) the temporary file goes.
* Every temporary file is also registered (:func:`track_temp`), so that the CLI's signal handler
  can remove what an interrupted process still had open (:func:`remove_temp_files`).
* :func:`output_transaction` makes the outputs of one command all-or-nothing: a file it created
  is removed and a file it replaced is put back if the command fails later on.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from pathlib import Path

from egovid.core.errors import EgovidError

_TEMPS: dict[Path, int] = {}  # temporary path -> pid of the process that made it
_LOCK = threading.Lock()
_ACTIVE: list[_Transaction] = []  # open output transactions, innermost last


def temp_sibling(path: str | os.PathLike, tag: str = "part") -> Path:
    """The hidden temporary name egovid writes ``path`` under: ``.STEM.part-PID.SUFFIX``."""
    p = Path(path)
    return p.with_name(f".{p.stem}.{tag}-{os.getpid()}{p.suffix}")


def track_temp(path: str | os.PathLike) -> Path:
    """Register a temporary file to be removed if the process is interrupted."""
    p = Path(path)
    with _LOCK:
        _TEMPS[p] = os.getpid()
    return p


def untrack_temp(path: str | os.PathLike) -> None:
    """Forget a temporary file (it was renamed into place or deleted)."""
    with _LOCK:
        _TEMPS.pop(Path(path), None)


def remove_temp_files() -> int:
    """Delete the registered temporary files of this process; returns how many were removed.

    Safe to call from a signal handler: it only unlinks files.
    """
    pid = os.getpid()
    removed = 0
    for p, owner in list(_TEMPS.items()):
        if owner != pid:
            continue
        with contextlib.suppress(OSError):
            if p.is_dir() and not p.is_symlink():
                import shutil

                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink()
            removed += 1
        _TEMPS.pop(p, None)
    return removed


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it to ``path`` if the block succeeds.

    On an exception the temporary file is deleted and ``path`` is left untouched.
    """
    target = Path(path)
    if not target.parent.exists():
        raise EgovidError(f"output folder {target.parent} does not exist", "create it first")
    tmp = track_temp(temp_sibling(target))
    try:
        yield tmp
        if not tmp.exists():
            raise EgovidError(f"nothing was written to {target}")
        commit_temp(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        untrack_temp(tmp)


def commit_temp(tmp: str | os.PathLike, target: str | os.PathLike) -> Path:
    """Rename a finished temporary file onto ``target`` (atomic on one file system) and forget it;
    inside an :func:`output_transaction` the replacement is recorded so it can be undone."""
    target = Path(target)
    if _ACTIVE:
        _ACTIVE[-1].record(target)
    os.replace(tmp, target)
    untrack_temp(tmp)
    return target


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically, flushed to disk."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    return Path(path)


# -- all-or-nothing outputs of one command ---------------------------------------------------------
class _Transaction:
    def __init__(self) -> None:
        self.created: list[Path] = []
        self.backups: dict[Path, Path] = {}

    def record(self, target: Path) -> None:
        if target in self.backups or target in self.created:
            return
        if target.exists():
            backup = temp_sibling(target, "keep")
            with contextlib.suppress(OSError):
                os.link(target, backup)  # a hard link: no copy, and the original stays in place
                self.backups[target] = track_temp(backup)
                return
            # no hard links on this file system: the file is replaced without a way back
        else:
            self.created.append(target)

    def rollback(self) -> None:
        for target in self.created:
            with contextlib.suppress(OSError):
                target.unlink()
        for target, backup in self.backups.items():
            with contextlib.suppress(OSError):
                os.replace(backup, target)
            untrack_temp(backup)

    def commit(self) -> None:
        for backup in self.backups.values():
            with contextlib.suppress(OSError):
                backup.unlink()
            untrack_temp(backup)


@contextlib.contextmanager
def output_transaction() -> Iterator[None]:
    """Make the files written through :func:`atomic_path` inside the block all-or-nothing.

    Outputs appear in place as soon as each is written (so they can be read back), but if the
    block fails, every file it created is removed and every file it replaced is put back.
    Not for stores that commit on their own (the dashcam archive's blobs).
    """
    tx = _Transaction()
    _ACTIVE.append(tx)
    try:
        yield
    except BaseException:
        tx.rollback()
        raise
    else:
        tx.commit()
    finally:
        _ACTIVE.remove(tx)
