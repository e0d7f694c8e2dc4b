"""Checks every command runs on its inputs and outputs before any work or any write.

Each raises :class:`EgovidError` (one ``error:`` line, exit status 2) naming the problem and the
fix. Commands call them at the top, in this order: inputs (:func:`input_file`, :func:`input_folder`,
:func:`video_input`, :func:`gps_input`), numbers and choices (:func:`number`, :func:`choice`), then
all outputs together (:func:`outputs`, :func:`output_folder`), so that nothing is written unless
everything can be.

Float options need no finiteness check here: the CLI refuses NaN and infinity for every float
option before a command runs (see :mod:`egovid.cli`).
"""

from __future__ import annotations

import math
import os
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path

from egovid.core.errors import EgovidError

VIDEO_OUT = ".mp4 .mkv .mov .m4v"  # what egovid writes H.264 (or FFV1) into
CSV = ".csv"
TUM = ".tum .txt"
JSON = ".json"
HTML = ".html .htm"
PLOT = ".png .pdf .svg .jpg .jpeg"

MIN_FREE_BYTES = 64 * 1024  # less than this free where an output goes: refuse before the work


def input_file(path: Path | None, what: str = "input") -> Path | None:
    """An input file: exists, is a file (not a folder), readable and not empty. None passes."""
    if path is None:
        return None
    p = Path(path)
    if not p.exists():
        hint = " (it is a broken link)" if p.is_symlink() else ""
        raise EgovidError(f"{what} {p} not found{hint}", "check the path")
    if p.is_dir():
        raise EgovidError(f"{what} {p} is a folder, not a file", "give the file itself")
    try:
        with open(p, "rb") as fh:
            fh.read(1)
    except OSError as exc:
        raise EgovidError(f"{what} {p} cannot be read ({exc.strerror})", "check its permissions") from None
    if p.stat().st_size == 0:
        raise EgovidError(f"{what} {p} is empty (0 bytes)", "give a file with data in it")
    return p


def input_folder(path: Path, what: str = "folder") -> Path:
    """An input folder: exists, is a folder, can be listed."""
    p = Path(path)
    if not p.exists():
        raise EgovidError(f"{what} {p} not found", "check the path")
    if not p.is_dir():
        raise EgovidError(f"{what} {p} is a file, not a folder", "give the folder")
    if not os.access(p, os.R_OK | os.X_OK):
        raise EgovidError(f"{what} {p} cannot be read", "check its permissions")
    return p


def video_input(path: Path, *, allow_truncated: bool = False):
    """A video input: a readable file that FFmpeg decodes and that holds every frame its container
    lists (see :func:`egovid.core.video.probe`). Returns its :class:`~egovid.core.video.VideoInfo`."""
    from egovid.core.video import probe

    input_file(path, "video")
    return probe(path, allow_truncated=allow_truncated)


def gps_input(path: Path):
    """A GPS track: a readable GPX, NMEA or CSV file with at least two finite fixes. Returns the
    :class:`~egovid.dashcam.route.tracks.GpsTrack`."""
    from egovid.dashcam.route.tracks import read_track

    input_file(path, "GPS file")
    return read_track(path)


def number(
    value: float | None,
    name: str,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    hi_open: bool = False,
    unit: str = "",
) -> float | None:
    """A finite number within [lo, hi] (an open end excludes the bound). None passes."""
    if value is None:
        return None
    if not math.isfinite(value):
        raise EgovidError(
            f"{name} {value} is not a finite number", f"give a finite number{f' in {unit}' if unit else ''}"
        )
    unit = f" {unit}" if unit else ""
    below = lo is not None and (value <= lo if lo_open else value < lo)
    above = hi is not None and (value >= hi if hi_open else value > hi)
    if below or above:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        span = f"{left}{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}{right}"
        raise EgovidError(f"{name} {value:g}{unit} is out of range {span}", f"give {name} within {span}{unit}")
    return value


def choice(value: str, name: str, options: Sequence[str]) -> str:
    """One of ``options``."""
    if value not in options:
        raise EgovidError(f"unknown {name} {value!r}", f"choose one of {', '.join(options)}")
    return value


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.resolve() == b.resolve():
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def writable_folder(folder: Path, what: str = "output folder", of: str = "") -> Path:
    """A folder an output can be written into: exists, is a folder, writable, space left.
    ``of`` names what goes there, for the message (e.g. ``"the plot x/p.png"``)."""
    folder = Path(folder)
    what = f"{what} {folder} (for {of})" if of else f"{what} {folder}"
    if not folder.exists():
        raise EgovidError(f"{what} does not exist", "create it first")
    if not folder.is_dir():
        raise EgovidError(f"{what} is not a folder", "check the path")
    try:
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        read_only = False
    if read_only:
        raise EgovidError(f"{what} is on a read-only file system", "write to a folder on a writable disk")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise EgovidError(f"{what} is not writable (permission denied)", "choose a folder you can write to")
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        free = MIN_FREE_BYTES
    if free < MIN_FREE_BYTES:
        raise EgovidError(
            f"no space left on the device holding {what} ({free} bytes free)",
            "free some space or write to another disk",
        )
    return folder


def _check_one(path: Path, exts: str, what: str) -> None:
    if path.is_dir():
        raise EgovidError(f"{what} {path} is a folder", "give a file name")
    allowed = exts.split()
    if allowed and path.suffix.lower() not in allowed:
        have = f"extension {path.suffix!r}" if path.suffix else "no extension"
        raise EgovidError(f"{what} {path} has {have}", f"name it with {' or '.join(allowed)}")
    writable_folder(path.parent, "folder", of=f"{what} {path}")


def outputs(inputs: Iterable[Path | None], *specs: tuple[Path | None, str] | tuple[Path | None, str, str]) -> None:
    """Check all the outputs of one command together, before any work.

    ``specs``: ``(path, extensions[, what])``; ``extensions`` is a space-separated list such as
    ``".csv"`` (empty: any); a None path is skipped. Each output must be a file name (not a
    folder) with a known extension in an existing, writable folder with space left, must not be
    any of ``inputs`` (same path, link or hard link) and must differ from the other outputs.
    """
    ins = [Path(p) for p in inputs if p is not None]
    seen: list[tuple[Path, str]] = []
    for spec in specs:
        path, exts = spec[0], spec[1]
        what = spec[2] if len(spec) > 2 else "output"
        if path is None:
            continue
        path = Path(path)
        for other, other_what in seen:
            if _same_file(path, other):
                raise EgovidError(f"{what} {path} is also given as the {other_what}", "give each output its own name")
        for src in ins:
            if _same_file(path, src):
                raise EgovidError(
                    f"{what} {path} is the input {src}: writing it would overwrite the input",
                    "choose another output name",
                )
        _check_one(path, exts, what)
        seen.append((path, what))


def output_folder(path: Path, *, inputs: Iterable[Path | None] = (), what: str = "output folder") -> Path:
    """A folder a command will create (or reuse) and write into: not a file, not an input, and
    its nearest existing parent writable with space left."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise EgovidError(f"{what} {p} is a file", "give a folder")
    for src in inputs:
        if src is not None and _same_file(p, Path(src)):
            raise EgovidError(f"{what} {p} is an input", "choose another folder")
    existing = p
    while not existing.exists():
        existing = existing.parent
    if existing == p:
        writable_folder(p, what)
    else:
        writable_folder(existing, "folder", of=f"{what} {p}")
    return p
