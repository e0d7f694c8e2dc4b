"""Camera metadata of a file through ExifTool (pyexiftool), the one wrapper egovid uses.

ExifTool (Debian's ``libimage-exiftool-perl``, installed by ``make``) reads the container and
maker-note tags of phones, action cameras and dashcams, and with ``embedded=True`` (``-ee``) the
timed streams inside them (GoPro GPMF, Novatek, BlackVue, DJI, Insta360 GPS, ...).

Tags come back as one flat ``dict``: keys are ``GROUP:Name`` with ExifTool's family-3 group
(``Main`` for the file itself, ``Doc1``, ``Doc2``... for each embedded document), values numeric
where ExifTool can (``-n``: degrees, metres, seconds, not formatted strings). With
``duplicates=True`` repeated tags are all kept (``-a``) and keys gain the family-4 copy group:
``Doc2:Copy5:GPSLatitude``; inside one document the key without ``CopyN`` is that document's last
sample.

Use :class:`ExifTool` as a context manager to keep one ExifTool process for many files (starting
the Perl process costs about 0.3 s), or :func:`read_tags` for a single file.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from egovid.core.errors import EgovidError

#: ExifTool's arguments for :meth:`ExifTool.records`: every embedded tag (``-ee -a``), in file
#: order (``-args``), each with its document (family 3) and the module that read it (family 0:
#: ``GoPro``, ``QuickTime``, ...; units differ between them: GoPro's GPSSpeed is m/s, the
#: QuickTime streams' km/h). ``QuickTimeUTC``: the container's CreateDate is UTC, as the format
#: says, not the local time of the machine that runs ExifTool; ExifTool dates fixes without a time
#: of their own (CAMM type 5, Garmin, 70mai) as CreateDate + SampleTime, which must not move
#: with the time zone egovid runs in.
RECORD_ARGS = ("-ee", "-a", "-G3:0", "-args", "-api", "QuickTimeUTC=1")

_INSTALL_FIX = "install ExifTool (Debian/Ubuntu: apt-get install libimage-exiftool-perl; `make install` does it)"


def exiftool_path() -> str:
    """Path of the ``exiftool`` executable; :class:`EgovidError` when it is not installed."""
    found = shutil.which("exiftool")
    if found is None:
        raise EgovidError("ExifTool is not installed (no `exiftool` on PATH)", _INSTALL_FIX)
    return found


class ExifTool:
    """One long-lived ExifTool process; call :meth:`tags` for each file.

    >>> with ExifTool() as et:                                  # doctest: +SKIP
    ...     tags = et.tags("GX010001.MP4", embedded=True)
    """

    def __init__(self) -> None:
        self._helper = None

    def __enter__(self) -> ExifTool:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        """Start the ExifTool process (done by ``with`` and on first use)."""
        if self._helper is not None:
            return
        import exiftool

        try:
            self._helper = exiftool.ExifToolHelper(executable=exiftool_path(), common_args=["-n"])
        except (OSError, exiftool.exceptions.ExifToolException) as exc:
            raise EgovidError(f"ExifTool does not start ({exc})", _INSTALL_FIX) from None

    def close(self) -> None:
        """Stop the ExifTool process."""
        if self._helper is not None:
            import contextlib

            with contextlib.suppress(Exception):
                self._helper.terminate()
            self._helper = None

    def tags(self, path: str | os.PathLike, *, embedded: bool = False, duplicates: bool = False) -> dict[str, Any]:
        """All tags of ``path`` as ``{"Group:Name": value}`` (see the module docstring).

        ``embedded`` adds the timed streams (``-ee``); ``duplicates`` keeps repeated tags with
        their copy group (``-a -G3:4``) instead of only the last of each. Raises
        :class:`EgovidError` when the file is missing or ExifTool fails on it.
        """
        import exiftool

        p = Path(path)
        if not p.is_file():
            raise EgovidError(f"file not found: {p}", "check the path")
        self.start()
        params = ["-a", "-G3:4"] if duplicates else ["-G3"]
        if embedded:
            params.append("-ee")
        params += ["-api", "LargeFileSupport=1"]
        try:
            result = self._helper.get_metadata(str(p), params=params)
        except exiftool.exceptions.ExifToolException as exc:
            raise EgovidError(f"ExifTool cannot read {p} ({_reason(exc)})", "check that it is a media file") from None
        except (OSError, ValueError) as exc:  # the process died or printed garbage
            self.close()
            raise EgovidError(f"ExifTool failed on {p} ({exc})", _INSTALL_FIX) from None
        if not result:
            raise EgovidError(f"ExifTool returned nothing for {p}", "check that it is a media file")
        tags = dict(result[0])
        tags.pop("SourceFile", None)
        return tags

    def records(self, path: str | os.PathLike) -> str:
        """The timed streams of ``path`` as ExifTool's ``-args`` text, every tag in file order
        (``-ee -a -G3:0``: ``-Doc2:QuickTime:GPSLatitude=…`` lines), the form that keeps one sample's fields
        together where the copy numbers of :meth:`tags` would give them different numbers, and
        the family-0 group (``-Doc2:QuickTime:GPSSpeed=…``, :data:`RECORD_ARGS`).
        Raises :class:`EgovidError` like :meth:`tags`."""
        import exiftool

        p = Path(path)
        if not p.is_file():
            raise EgovidError(f"file not found: {p}", "check the path")
        self.start()
        try:
            return self._helper.execute(*RECORD_ARGS, "-api", "LargeFileSupport=1", str(p))
        except exiftool.exceptions.ExifToolException as exc:
            raise EgovidError(f"ExifTool cannot read {p} ({_reason(exc)})", "check that it is a media file") from None
        except (OSError, ValueError) as exc:
            self.close()
            raise EgovidError(f"ExifTool failed on {p} ({exc})", _INSTALL_FIX) from None


def _reason(exc: Exception) -> str:
    """ExifTool's own ``Error`` tag when it printed one (``File format error``), else its stderr."""
    import json

    try:
        doc = json.loads(getattr(exc, "stdout", "") or "[]")
        err = next((v for k, v in doc[0].items() if k.endswith("Error")), None) if doc else None
    except (ValueError, TypeError, AttributeError):
        err = None
    text = err or getattr(exc, "stderr", None) or str(exc)
    return " ".join(str(text).split())[:160]


def read_tags(path: str | os.PathLike, *, embedded: bool = False, duplicates: bool = False) -> dict[str, Any]:
    """Tags of one file (starts and stops an ExifTool process; see :meth:`ExifTool.tags`)."""
    with ExifTool() as et:
        return et.tags(path, embedded=embedded, duplicates=duplicates)


def read_records(path: str | os.PathLike) -> str:
    """:meth:`ExifTool.records` of one file (starts and stops an ExifTool process)."""
    with ExifTool() as et:
        return et.records(path)


def tag_name(key: str) -> str:
    """The tag name of a ``Group:Copy:Name`` key (``"Doc1:GPSLatitude"`` → ``"GPSLatitude"``)."""
    return key.rsplit(":", 1)[-1]


def find_tag(tags: dict[str, Any], names: Iterable[str], *, group: str | None = None) -> Any | None:
    """The value of the first of ``names`` present in ``tags`` (any group, or only keys starting
    with ``group``), trying the names in order; ``None`` when none is present."""
    wanted = list(names)
    by_name: dict[str, Any] = {}
    for key, value in tags.items():
        if group is not None and not key.startswith(group + ":"):
            continue
        by_name.setdefault(tag_name(key), value)
    for name in wanted:
        if name in by_name:
            return by_name[name]
    return None
