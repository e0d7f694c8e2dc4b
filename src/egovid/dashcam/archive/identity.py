"""What a file is, by its content, and whether the archive holds it already.

**Identity.** A file is the SHA-256 of its bytes and its size (:class:`FileDigest`). The archive
knows every file it ingested by this digest (:class:`~egovid.dashcam.archive.fleetstore.KnownFile`),
never by its name: the same file copied under another name is the same file, and two different
files named ``FILE0001.MP4`` from two cards are two files. The full digest is taken at the first
ingest (reading the bytes is about the cost of the card's read speed, nothing beside the hours of
coding) and stays the stored identity.

**Recognition.** Taking the full digest again on every re-ingest would read the whole card (a
64 GB card at 90 MB/s: 12 minutes, for nothing). Beside the full digest the archive stores a
*sampled digest* (:func:`sample_digest`): the SHA-256 of the file's size, its first and last
:data:`EDGE` bytes and :data:`SAMPLES` blocks of :data:`BLOCK` bytes evenly spaced between them
(4 MiB of a file at most, whatever its size; a file smaller than that is hashed whole). A file
is recognised when its size and sampled digest equal those of a stored file; a file whose sample
matches nothing is hashed in full, and known when its full digest is stored (a row from before
sampled digests, or the rare file whose sample changed but not its content: impossible).

Why this is safe for dashcam files: the sampled blocks are compressed video (and the container's
header and index, first and last), which is as close to random as bytes get; two *different*
recordings of the same size share a sampled digest only if all their ~4 MiB of sampled bytes are
identical, which different camera exposures, GPS atoms and timestamps (in the header and index)
make practically impossible. The accepted risk is a file *edited in place* outside the sampled
blocks, keeping its size (a tool rewriting a few bytes in the middle of a recording): it is taken
for the archived one and skipped. ``--verify-known`` (``verify=True``) takes the full digest of
every file the sample recognises, and compares it with the stored one: the old cost, no risk.

A (path, size, modification time) cache is deliberately not used, even as a shortcut: a
reformatted card writes new files under the old names, often of the very same size, and the
camera's clock is not to be trusted for the time.

This module imports only the standard library and the catalogue (no decoders, no numeric
libraries beyond the catalogue's): ``egovid dashcam ingest`` uses :func:`all_known` to answer a
card synced again before it loads the ingest pipeline.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

from egovid.core.errors import EgovidError
from egovid.dashcam.archive.fleetstore import FleetStore, KnownFile
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.route.inputs import expand_inputs

_READ = 1 << 22  # bytes read at a time by the full digest
EDGE = 1 << 20  # bytes sampled at each end of a file (container header, index)
BLOCK = 1 << 16  # bytes of each sampled block between the ends
SAMPLES = 32  # sampled blocks between the ends
SAMPLED_BYTES = 2 * EDGE + SAMPLES * BLOCK  # at most this many bytes read per file (4 MiB)
ALREADY_IN = "already in the archive"


@dataclass(frozen=True)
class FileDigest:
    """A file's content identity: hex SHA-256 of its bytes and their number, and its sampled
    digest (:func:`sample_digest`; None where not taken)."""

    sha256: str
    size: int
    sample: str | None = None

    @property
    def short(self) -> str:
        return self.sha256[:12]


def _unreadable(path: str | os.PathLike, exc: OSError) -> EgovidError:
    return EgovidError(f"cannot read {path}: {exc.strerror or exc}", "check the file and its permissions")


def file_digest(path: str | os.PathLike) -> FileDigest:
    """The :class:`FileDigest` of the file at ``path``: its bytes read once, front to back, and
    its sampled digest (at most :data:`SAMPLED_BYTES` more, read again)."""
    h = hashlib.sha256()
    size = 0
    try:
        with open(path, "rb", buffering=0) as fh:
            buf = bytearray(_READ)
            view = memoryview(buf)
            while n := fh.readinto(buf):
                h.update(view[:n])
                size += n
    except OSError as exc:
        raise _unreadable(path, exc) from None
    return FileDigest(h.hexdigest(), size, sample_digest(path)[0])


def sample_offsets(size: int) -> list[tuple[int, int]]:
    """The (offset, length) byte ranges of a file of ``size`` bytes that its sampled digest reads:
    the whole file when it is at most :data:`SAMPLED_BYTES`, else the first and last :data:`EDGE`
    bytes and :data:`SAMPLES` blocks of :data:`BLOCK` bytes evenly spaced between them."""
    if size <= SAMPLED_BYTES:
        return [(0, size)]
    inner = size - 2 * EDGE - BLOCK  # the last possible block start, from the end of the first edge
    middle = [(EDGE + inner * (k + 1) // (SAMPLES + 1), BLOCK) for k in range(SAMPLES)]
    return [(0, EDGE), *middle, (size - EDGE, EDGE)]


def sample_digest(path: str | os.PathLike) -> tuple[str, int]:
    """The file's sampled digest (hex SHA-256 of its size and the ranges of :func:`sample_offsets`)
    and its size in bytes."""
    try:
        with open(path, "rb", buffering=0) as fh:
            size = os.fstat(fh.fileno()).st_size
            h = hashlib.sha256(b"egovid-sample-v1 %d\n" % size)
            for offset, length in sample_offsets(size):
                fh.seek(offset)
                data = fh.read(length)
                while len(data) < length:  # a short read (pipes, network disks): read on
                    more = fh.read(length - len(data))
                    if not more:
                        raise OSError(f"the file shrank while read ({offset + len(data)} of {size} bytes)")
                    data += more
                h.update(data)
    except OSError as exc:
        raise _unreadable(path, exc) from None
    return h.hexdigest(), size


def already_in(known: KnownFile) -> str:
    """Why a file the archive holds is left out (starts with :data:`ALREADY_IN`)."""
    where = f"drive {known.drive_name!r}" if known.drive_name else "a drive forgotten since"
    same = f", as {known.name}" if known.name else ""
    return f"{ALREADY_IN} ({where}{same}; same content)"


def identify(
    store: FleetStore, path: str | os.PathLike, *, verify: bool = False
) -> tuple[KnownFile | None, FileDigest | None]:
    """Whether the archive holds the file at ``path`` (see the module docstring): the first file
    ingested with its content (None: a new file) and, when its full digest was taken, its
    :class:`FileDigest` (always for a new file; None for a file its sample recognised without
    ``verify``)."""
    sample, size = sample_digest(path)
    hits = store.known_by_sample(sample, size)
    if hits and not verify:
        return hits[0], None
    full = file_digest(path)
    found = store.known_files(full.sha256, full.size)
    return (found[0] if found else None), full


def all_known(archive: Archive, videos: list[Path], *, verify: bool = False) -> list[tuple[Path, KnownFile]] | None:
    """The input files (``videos``: files and folders, as ``egovid dashcam ingest`` takes them)
    with what each is in the archive, when the archive holds every one of them already; None as
    soon as one is new (or the inputs are not usable: the ingest itself says why)."""
    try:
        files = expand_inputs(videos)
    except EgovidError:
        return None
    if not files:
        return None
    store = FleetStore(archive.catalogue)
    out: list[tuple[Path, KnownFile]] = []
    for f in files:
        hit, _ = identify(store, f, verify=verify)
        if hit is None:
            return None
        out.append((f, hit))
    return out
