"""Where an archive keeps its bitstreams: a content-addressed blob store.

One small interface (:class:`BlobStore`) with two implementations:

* :class:`LocalBlobs` — a folder (``ARCHIVE/blobs/ab/abcdef…``), the default. A blob is written to
  a temporary sibling, flushed to disk and renamed into place, so a crash never leaves a partial
  blob under its final name (only a ``.part-PID`` file, which ``gc`` deletes).
* :class:`FsspecBlobs` — any fsspec URL (``s3://BUCKET/PREFIX``; s3fs reads the standard AWS_*
  variables, ``AWS_ENDPOINT_URL`` for a non-AWS endpoint). An object store writes an object whole
  or not at all, so no temporary names are needed.

Blobs are named by the SHA-256 of their bytes: writing the same bytes twice (a task retried after
its worker died) stores one blob, and :meth:`BlobStore.get` checks the digest of what it read.
:meth:`BlobStore.read_range` reads part of a blob (extract of a stretch reads only the random-access
runs it needs); those bytes are checked by the decoded pictures' digests instead.
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
import uuid
from abc import ABC, abstractmethod
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_bytes

_SHA = re.compile(r"[0-9a-f]{64}")
_RESTORE = "restore the archive from a backup"


@dataclass(frozen=True)
class BlobFile:
    """One file of the store: its ``name`` (a SHA-256, or a temporary name), ``size`` in bytes."""

    name: str
    size: int

    @property
    def is_blob(self) -> bool:
        return bool(_SHA.fullmatch(self.name))


def digest(data: bytes) -> str:
    """The name a blob of these bytes gets (hex SHA-256)."""
    return hashlib.sha256(data).hexdigest()


class BlobStore(ABC):
    """Content-addressed bitstreams. Names are hex SHA-256 digests of the bytes."""

    url: str

    def put(self, data: bytes) -> str:
        """Store ``data`` (idempotent: the same bytes are stored once) and return its name."""
        sha = digest(data)
        if not self.exists(sha):
            self._write(sha, data)
        return sha

    def put_chunks(self, chunks: Iterable[bytes]) -> str:
        """Store a blob given as pieces (streamed: it need not fit in memory); returns its name."""
        h = hashlib.sha256()
        with tempfile.TemporaryFile() as tmp:
            for c in chunks:
                h.update(c)
                tmp.write(c)
            sha = h.hexdigest()
            if not self.exists(sha):
                tmp.seek(0)
                self._write_file(sha, tmp)
        return sha

    def _write_file(self, sha: str, fh) -> None:
        self._write(sha, fh.read())

    def get(self, sha: str) -> bytes:
        """The whole blob, checked against its name."""
        data = self._read(sha)
        if digest(data) != sha:
            raise EgovidError(f"bitstream {sha[:12]} in {self.url} is corrupt", _RESTORE)
        return data

    def read_range(self, sha: str, start: int, end: int) -> bytes:
        """Bytes ``start`` … ``end - 1`` of a blob (not checked: the caller checks what it decodes)."""
        if not 0 <= start <= end:
            raise ValueError(f"bad byte range {start}-{end}")
        data = self._read_range(sha, start, end)
        if len(data) != end - start:
            raise EgovidError(f"bitstream {sha[:12]} in {self.url} is shorter than the catalogue says", _RESTORE)
        return data

    @abstractmethod
    def exists(self, sha: str) -> bool: ...

    @abstractmethod
    def _write(self, sha: str, data: bytes) -> None: ...

    @abstractmethod
    def _read(self, sha: str) -> bytes: ...

    @abstractmethod
    def _read_range(self, sha: str, start: int, end: int) -> bytes: ...

    @abstractmethod
    def files(self) -> Iterator[BlobFile]:
        """Every file in the store: blobs and temporary files a crashed writer left."""

    @abstractmethod
    def delete(self, name: str) -> None:
        """Delete one file (a blob or a temporary file) by name."""

    def total_bytes(self) -> int:
        return sum(f.size for f in self.files())

    def _missing(self, sha: str) -> EgovidError:
        return EgovidError(f"bitstream {sha[:12]} is missing from {self.url}", _RESTORE)


class LocalBlobs(BlobStore):
    """Blobs in a local folder, two-level (``ab/abcdef…``), written atomically and fsync'ed."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.url = str(self.folder)

    def _path(self, sha: str) -> Path:
        if not _SHA.fullmatch(sha):
            raise EgovidError(f"{sha[:20]!r} is not a blob name", "the archive's catalogue is damaged")
        return self.folder / sha[:2] / sha

    def exists(self, sha: str) -> bool:
        return self._path(sha).exists()

    def _write(self, sha: str, data: bytes) -> None:
        path = self._path(sha)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, data)

    def put_chunks(self, chunks: Iterable[bytes]) -> str:
        """Write the pieces to a temporary file in the store (hashing as they come), flush it to
        disk and rename it to its name: memory stays flat, a crash leaves only a ``.part`` file."""
        self.folder.mkdir(parents=True, exist_ok=True)
        tmp = self.folder / f".incoming.part-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        h = hashlib.sha256()
        try:
            with open(tmp, "wb") as fh:
                for c in chunks:
                    h.update(c)
                    fh.write(c)
                fh.flush()
                os.fsync(fh.fileno())
            sha = h.hexdigest()
            path = self._path(sha)
            if path.exists():
                tmp.unlink()
            else:
                path.parent.mkdir(exist_ok=True)
                os.replace(tmp, path)
            return sha
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise

    def _read(self, sha: str) -> bytes:
        try:
            return self._path(sha).read_bytes()
        except FileNotFoundError:
            raise self._missing(sha) from None

    def _read_range(self, sha: str, start: int, end: int) -> bytes:
        try:
            with open(self._path(sha), "rb") as fh:
                fh.seek(start)
                return fh.read(end - start)
        except FileNotFoundError:
            raise self._missing(sha) from None

    def files(self) -> Iterator[BlobFile]:
        if not self.folder.exists():
            return
        for p in sorted(self.folder.rglob("*")):
            if p.is_file():
                yield BlobFile(p.name, p.stat().st_size)

    def delete(self, name: str) -> None:
        (self.folder / name).unlink(missing_ok=True)  # a temporary file at the top
        for p in self.folder.glob(f"*/{name}"):
            p.unlink(missing_ok=True)
            if p.parent != self.folder and not any(p.parent.iterdir()):
                p.parent.rmdir()


class FsspecBlobs(BlobStore):
    """Blobs behind an fsspec URL (``s3://BUCKET/PREFIX``, ``gs://…``, ``memory://…``), one object
    per blob, two-level names as in a folder. Credentials and endpoint come from the environment
    (for S3: AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY, AWS_ENDPOINT_URL, AWS_REGION)."""

    def __init__(self, url: str) -> None:
        import fsspec  # only archives with their bitstreams in an object store need it (and s3fs)

        self.url = url.rstrip("/")
        options = _s3_options() if url.startswith("s3://") else {}
        try:
            self.fs, self.base = fsspec.core.url_to_fs(self.url, **options)
        except (ImportError, ValueError) as exc:
            raise EgovidError(f"blob store {url!r} is not usable ({exc})", "give e.g. s3://BUCKET/PREFIX") from None
        self.base = self.base.rstrip("/")

    def _key(self, name: str) -> str:
        return f"{self.base}/{name[:2]}/{name}"

    def exists(self, sha: str) -> bool:
        return bool(self.fs.exists(self._key(sha)))

    def _write(self, sha: str, data: bytes) -> None:
        self.fs.pipe_file(self._key(sha), data)

    def _write_file(self, sha: str, fh) -> None:
        with self.fs.open(self._key(sha), "wb") as out:
            while block := fh.read(1 << 22):
                out.write(block)

    def _read(self, sha: str) -> bytes:
        try:
            return self.fs.cat_file(self._key(sha))
        except FileNotFoundError:
            raise self._missing(sha) from None

    def _read_range(self, sha: str, start: int, end: int) -> bytes:
        if end == start:
            return b""
        try:
            return self.fs.cat_file(self._key(sha), start=start, end=end)
        except FileNotFoundError:
            raise self._missing(sha) from None

    def files(self) -> Iterator[BlobFile]:
        self.fs.invalidate_cache()
        try:
            found = self.fs.find(self.base, detail=True)
        except FileNotFoundError:
            return
        for key, info in sorted(found.items()):
            if info.get("type", "file") == "file":
                yield BlobFile(key.rsplit("/", 1)[-1], int(info.get("size") or 0))

    def delete(self, name: str) -> None:
        self.fs.rm_file(self._key(name))

    def check(self) -> None:
        """Fail with one clear error unless the store can be listed and written (``init``)."""
        bucket = self.base.split("/", 1)[0]
        try:
            found = self.fs.exists(bucket)
        except Exception:
            found = True  # let the write below say why
        if not found:
            raise EgovidError(
                f"bucket {bucket} does not exist at {self.url}", "create it first (or check AWS_ENDPOINT_URL)"
            )
        try:
            probe = f"{self.base}/.egovid-probe"
            self.fs.pipe_file(probe, b"ok")
            self.fs.rm_file(probe)
        except Exception as exc:  # botocore / aiohttp / OSError: all mean "cannot use it"
            why = " ".join(str(exc).split())[:160] or type(exc).__name__
            raise EgovidError(
                f"cannot write to the blob store {self.url}: {why}",
                "check the bucket exists and AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY / AWS_ENDPOINT_URL",
            ) from None


def _s3_options() -> dict:
    """s3fs options from the standard AWS variables (s3fs reads the keys itself; the endpoint of a
    non-AWS server only through AWS_ENDPOINT_URL, which older botocore versions ignore)."""
    options: dict = {}
    endpoint = os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL")
    if endpoint:
        options["client_kwargs"] = {"endpoint_url": endpoint}
    # Fresh listings: gc and check must see what other machines wrote a moment ago.
    options["skip_instance_cache"] = True
    options["use_listings_cache"] = False
    return options


def open_blobs(setting: str | None, root: str | os.PathLike) -> BlobStore:
    """The blob store of an archive: ``setting`` None (the folder ``root/blobs``) or a URL."""
    if not setting:
        return LocalBlobs(Path(root) / "blobs")
    if "://" not in setting:
        raise EgovidError(f"blob store {setting!r} is not a URL", "give s3://BUCKET/PREFIX, or leave --blobs out")
    if setting.startswith("file://"):
        return LocalBlobs(setting[len("file://") :])
    return FsspecBlobs(setting)
