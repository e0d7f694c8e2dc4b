"""User-facing errors.

Anything the user can fix (a missing file, a video that does not decode, an absurd parameter)
raises :class:`EgovidError`. The CLI prints it as one line, ``error: <problem>; <fix>``, and exits
with status 2; it never shows a traceback for these.

:func:`user_error` also turns the expected failures of the outside world into such an error: an
``OSError`` (read-only folder, disk full, permission denied, a file that vanished) and a database
error (SQLite or PostgreSQL). Everything else is a bug and keeps exit status 1.
"""

from __future__ import annotations

import errno
import re
import sqlite3


class EgovidError(Exception):
    """A problem with the user's input, with the fix to suggest.

    Parameters
    ----------
    problem:
        What is wrong, naming the offending file or value.
    fix:
        What the user should do about it (optional).
    """

    def __init__(self, problem: str, fix: str | None = None) -> None:
        self.problem = problem
        self.fix = fix
        super().__init__(self.one_line())

    def one_line(self) -> str:
        """The message as a single line: ``problem; fix``."""
        text = " ".join(self.problem.split())
        if self.fix:
            text += "; " + " ".join(self.fix.split())
        return text


_FREE_SPACE = "free some space or write to another disk"
_OS_ERRORS: dict[int, tuple[str, str]] = {
    errno.ENOSPC: ("no space left on the device{at}", _FREE_SPACE),
    errno.EDQUOT: ("disk quota exceeded{at}", _FREE_SPACE),
    errno.EROFS: ("{what} is on a read-only file system", "write to a folder on a writable disk"),
    errno.EACCES: ("permission denied{at}", "check the permissions, or choose a folder you can write to"),
    errno.EPERM: ("operation not permitted{at}", "check the permissions, or choose a folder you can write to"),
    errno.ENOENT: ("{what} does not exist", "check the path"),
    errno.EISDIR: ("{what} is a folder", "give a file name"),
    errno.ENOTDIR: ("a part of {what} is not a folder", "check the path"),
    errno.ENAMETOOLONG: ("the file name {what} is too long", "choose a shorter name"),
    errno.EIO: ("input/output error{at}", "check the disk (dmesg) and its free space"),
    errno.EMFILE: ("too many open files", "raise the limit (ulimit -n) and try again"),
    errno.ENFILE: ("too many open files on this system", "close other programs and try again"),
    errno.EFBIG: ("a file grew too large for its file system{at}", "write to another disk"),
    errno.ETXTBSY: ("{what} is busy", "try again when the other program is done with it"),
    errno.EEXIST: ("{what} already exists", "remove it or choose another name"),
    errno.ENOTEMPTY: ("the folder {what} is not empty", "empty it or choose another folder"),
}

_SQLITE_ERRORS: dict[str, tuple[str, str]] = {
    "SQLITE_FULL": ("the catalogue database cannot grow: no space left on the device", _FREE_SPACE),
    "SQLITE_READONLY": (
        "the catalogue database is read-only",
        "make the archive folder writable (or work on a writable copy)",
    ),
    "SQLITE_CORRUPT": ("the catalogue database is damaged", "run `egovid dashcam check ARCHIVE --repair`"),
    "SQLITE_NOTADB": ("the catalogue file is not an SQLite database", "run `egovid dashcam check ARCHIVE --repair`"),
    "SQLITE_BUSY": ("the catalogue database is busy", "wait for the other egovid process to finish"),
    "SQLITE_LOCKED": ("the catalogue database is locked", "wait for the other egovid process to finish"),
    "SQLITE_CANTOPEN": ("the catalogue database cannot be opened", "check the archive folder and its permissions"),
    "SQLITE_IOERR": ("the catalogue database hit a disk error", "check the disk and its free space"),
    "SQLITE_PERM": ("permission denied on the catalogue database", "check the archive folder's permissions"),
}


_TEMP_NAME = re.compile(r"^\.(?P<stem>.*)\.(?:part|keep)-\d+(?P<suffix>\.[^./]*)?$")


def _user_facing_name(name: object) -> str:
    """The file the user asked for, not the hidden temporary egovid was writing it through."""
    text = str(name)
    head, _, base = text.rpartition("/")
    m = _TEMP_NAME.match(base)
    if not m:
        return text
    return (head + "/" if head else "") + m["stem"] + (m["suffix"] or "")


def _os_error(exc: OSError) -> EgovidError | None:
    code = exc.errno
    if code is None and exc.args and isinstance(exc.args[0], int):
        code = exc.args[0]
    if code not in _OS_ERRORS:
        return None
    name = exc.filename or getattr(exc, "filename2", None)
    name = _user_facing_name(name) if name else None
    problem, fix = _OS_ERRORS[code]
    what = str(name) if name else "a file"
    at = f" ({name})" if name else ""
    return EgovidError(problem.format(what=what, at=at), fix)


def _sqlite_error(exc: sqlite3.Error) -> EgovidError:
    code = getattr(exc, "sqlite_errorname", "") or ""
    message = " ".join(str(exc).split())
    for key, (problem, fix) in _SQLITE_ERRORS.items():
        if code == key or code.startswith(key + "_"):
            return EgovidError(f"{problem} ({message})", fix)
    low = message.lower()
    if "disk is full" in low:
        return EgovidError(f"{_SQLITE_ERRORS['SQLITE_FULL'][0]} ({message})", _FREE_SPACE)
    if "readonly" in low or "read-only" in low:
        return EgovidError(f"{_SQLITE_ERRORS['SQLITE_READONLY'][0]} ({message})", _SQLITE_ERRORS["SQLITE_READONLY"][1])
    if "disk i/o" in low:
        return EgovidError(f"{_SQLITE_ERRORS['SQLITE_IOERR'][0]} ({message})", _SQLITE_ERRORS["SQLITE_IOERR"][1])
    if "no such table" in low or "no such column" in low or "malformed" in low or "not a database" in low:
        return EgovidError(f"the catalogue database is damaged ({message})", _SQLITE_ERRORS["SQLITE_CORRUPT"][1])
    if "locked" in low:
        return EgovidError(f"the catalogue database is locked ({message})", _SQLITE_ERRORS["SQLITE_LOCKED"][1])
    return EgovidError(f"the catalogue database failed ({message})", "check the archive with `egovid dashcam check`")


def _postgres_error(exc: Exception) -> EgovidError | None:
    kind = type(exc).__name__
    message = " ".join(str(exc).split())[:200]
    if kind in ("OperationalError", "InterfaceError", "ConnectionTimeout", "ConnectionFailure"):
        return EgovidError(
            f"the PostgreSQL catalogue server failed ({message})",
            "check that the server is running and reachable, then run the command again",
        )
    if kind in ("DiskFull",):
        return EgovidError(f"the PostgreSQL server has no space left ({message})", _FREE_SPACE)
    if kind in ("InsufficientPrivilege",):
        return EgovidError(f"the PostgreSQL user may not do this ({message})", "grant the user the rights it needs")
    if kind in ("UndefinedTable", "InvalidSchemaName", "UndefinedColumn"):
        return EgovidError(
            f"the PostgreSQL catalogue is damaged or missing ({message})",
            "check the archive with `egovid dashcam check`",
        )
    return None


def user_error(exc: BaseException) -> EgovidError | None:
    """The user-facing error for an expected failure, or None for a bug.

    Recognises :class:`EgovidError`, an ``OSError`` the user can act on (no space left, read-only
    file system, permission denied, missing file...), SQLite errors and psycopg (PostgreSQL)
    errors; follows ``raise ... from`` chains to find one.
    """
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, EgovidError):
            return exc
        if isinstance(exc, OSError):
            found = _os_error(exc)
            if found is not None:
                return found
        if isinstance(exc, sqlite3.Error):
            return _sqlite_error(exc)
        if type(exc).__module__.split(".")[0] == "psycopg":
            found = _postgres_error(exc)
            if found is not None:
                return found
        exc = exc.__cause__
        seen += 1
    return None
