"""What a file is, by its content: the SHA-256 of its bytes and its size.

The archive knows every file it ingested by this digest (:class:`~egovid.dashcam.archive.fleetstore.KnownFile`),
never by its name: the same file copied under another name is the same file, and two different
files named ``FILE0001.MP4`` from two cards are two files. The digest is taken of the bytes as
they are (no decoding): reading them is the whole cost, about what the card or disk delivers
(a 64 GB card at 90 MB/s: 12 minutes, against the hours its first ingest takes; see
``benchmarks/dashcam_reingest.py``). A (path, size, modification time) cache is deliberately not
used, even as a shortcut: a reformatted card writes new files under the old names, often of the
very same size, and the camera's clock is not to be trusted for the time.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

from egovid.core.errors import EgovidError

_BLOCK = 1 << 22  # bytes read at a time


@dataclass(frozen=True)
class FileDigest:
    """A file's content identity: hex SHA-256 of its bytes and their number."""

    sha256: str
    size: int

    @property
    def short(self) -> str:
        return self.sha256[:12]


def file_digest(path: str | os.PathLike) -> FileDigest:
    """The :class:`FileDigest` of the file at ``path`` (read once, front to back)."""
    h = hashlib.sha256()
    size = 0
    try:
        with open(path, "rb", buffering=0) as fh:
            buf = bytearray(_BLOCK)
            view = memoryview(buf)
            while n := fh.readinto(buf):
                h.update(view[:n])
                size += n
    except OSError as exc:
        raise EgovidError(f"cannot read {path}: {exc.strerror or exc}", "check the file and its permissions") from None
    return FileDigest(h.hexdigest(), size)
