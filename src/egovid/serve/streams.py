"""Streams produced on the fly: a drive's frames, decoded from the archive, re-encoded chunk by
chunk (:mod:`egovid.serve.fragments`), kept in a bounded cache and shared by every viewer.

A drive's timeline is cut into chunks of ``chunk_frames`` frames (its random-access period, so a
chunk starts where decoding can start). A request for chunk *k* is answered from the
:class:`ChunkCache`; else it joins the :class:`Producer` of that drive whose next chunk is at most
``reach`` chunks before *k*, or starts a new one at *k*. A producer is a thread that decodes the
drive forward once (the archive's checked decoder: every random-access run is compared with the
encoder's digest) and encodes chunk after chunk while some viewer wants them: it runs at most
``ahead`` chunks past the last one asked of it, then waits, and ends after ``idle_s`` seconds
without demand; a producer whose viewers all went elsewhere (a seek) stops at once, mid-chunk.
Memory is bounded: the cache by bytes, the producers by count (the one asked least
recently is stopped first), each holding a decoder and a few frames. An error in one producer
(a damaged bitstream, a decoder failure) is kept and answered to the requests it serves; the
other streams and the server go on.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass

import numpy as np

from egovid.core.errors import user_error
from egovid.core.video import ColourTags
from egovid.serve.fragments import EncodeSettings, encode_chunk, output_size


class StreamError(Exception):
    """A chunk that cannot be produced (``status``: the HTTP status that says why)."""

    def __init__(self, message: str, status: int = 500) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class StreamSource:
    """What a producer needs of a drive: its size, frame rate and frame count, the chunk length
    (frames), the source's colour tags and ``frames(first)``: the drive's decoded I420 frames from
    frame ``first`` to its end (an iterator that may be closed early)."""

    drive_id: int
    width: int
    height: int
    fps: float
    frames_total: int
    chunk_frames: int
    frames: Callable[[int], Iterator[np.ndarray]]
    colour: ColourTags | None = None

    @property
    def chunks(self) -> int:
        return -(-self.frames_total // self.chunk_frames)


class ChunkCache:
    """Encoded chunks by key, least recently used dropped first once they hold more than
    ``max_bytes``. Thread-safe."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict[Hashable, bytes] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, key: Hashable) -> bytes | None:
        with self._lock:
            data = self._items.get(key)
            if data is not None:
                self._items.move_to_end(key)
            return data

    def put(self, key: Hashable, data: bytes) -> None:
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self._bytes -= len(old)
            self._items[key] = data
            self._bytes += len(data)
            while self._bytes > self.max_bytes and len(self._items) > 1:
                _, gone = self._items.popitem(last=False)
                self._bytes -= len(gone)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0

    @property
    def bytes(self) -> int:
        return self._bytes

    def __len__(self) -> int:
        return len(self._items)


class Producer:
    """One thread decoding a drive forward from chunk ``first`` and encoding chunks into the cache
    while they are wanted (see the module docstring). State is read and changed under the
    service's condition ``cond``."""

    def __init__(self, service: StreamService, source: StreamSource, generation: int, first: int) -> None:
        self.service, self.source, self.generation = service, source, generation
        self.next = first  # the chunk it produces next
        self.wants: dict[str, int] = {}  # viewer -> produce up to this chunk for it
        self.asked = time.monotonic()
        self.error: StreamError | None = None
        self.done = False
        self.stop = False
        self.thread = threading.Thread(target=self._run, name=f"egovid-stream-{source.drive_id}-{first}", daemon=True)

    @property
    def want(self) -> int:
        """The last chunk some viewer still wants of it (−1: none)."""
        return max(self.wants.values(), default=-1)

    def key(self, k: int) -> tuple[int, int, int]:
        return (self.source.drive_id, self.generation, k)

    def _wait_for_demand(self, k: int) -> bool:
        svc = self.service
        with svc.cond:
            while not self.stop and k > self.want:
                if time.monotonic() - self.asked > svc.idle_s:
                    return False
                svc.cond.wait(0.5)
            return not self.stop

    def _run(self) -> None:
        src, svc = self.source, self.service
        frames: Iterator[np.ndarray] | None = None
        try:
            k = self.next
            frames = src.frames(k * src.chunk_frames)
            while k < src.chunks and self._wait_for_demand(k):
                n = min(src.chunk_frames, src.frames_total - k * src.chunk_frames)
                batch = []
                while len(batch) < n:
                    with svc.cond:
                        gone = self.stop or self.want < k
                    if gone:  # withdrawn mid-chunk (a seek): stop now
                        return
                    batch.append(next(frames))
                data = encode_chunk(batch, src.width, src.height, src.fps, svc.settings, src.colour)
                del batch
                svc.cache.put(self.key(k), data)
                k += 1
                with svc.cond:
                    self.next = k
                    svc.cond.notify_all()
        except StopIteration:
            self.error = StreamError(f"drive {src.drive_id} ended before frame {src.frames_total}", 500)
        except Exception as exc:  # kept for the viewers of this stream; the server goes on
            found = user_error(exc)
            text = found.one_line() if found is not None else f"{type(exc).__name__}: {exc}"
            self.error = StreamError(f"drive {src.drive_id} cannot be streamed: {text}", 500)
        finally:
            close = getattr(frames, "close", None)
            if close is not None:
                with contextlib.suppress(Exception):
                    close()
            with svc.cond:
                self.done = True
                svc.cond.notify_all()


class StreamService:
    """Chunks of any drive for any number of viewers (see the module docstring).

    ``open_source(drive_id)``: the drive's :class:`StreamSource` (raises ``KeyError`` for no such
    drive); ``cache_bytes``: cache bound; ``max_producers``: producers alive at once; ``ahead``:
    chunks a producer runs past the last one asked; ``reach``: how far behind a wanted chunk a
    producer may be to serve it rather than a new one; ``idle_s``: a producer without demand for
    this long ends."""

    def __init__(
        self,
        open_source: Callable[[int], StreamSource],
        *,
        settings: EncodeSettings = EncodeSettings(),
        cache_bytes: int = 256 * 2**20,
        max_producers: int = 6,
        ahead: int = 2,
        reach: int = 3,
        idle_s: float = 20.0,
    ) -> None:
        self.open_source = open_source
        self.settings = settings
        self.cache = ChunkCache(cache_bytes)
        self.max_producers, self.ahead, self.reach, self.idle_s = max_producers, ahead, reach, idle_s
        self.cond = threading.Condition()
        self._producers: list[Producer] = []
        self._sources: dict[int, StreamSource] = {}
        self._generation = 0
        self._tickets: dict[str, int] = {}  # viewer -> number of its latest request

    def source(self, drive_id: int) -> StreamSource:
        """The drive's stream source (kept until :meth:`invalidate`)."""
        with self.cond:
            src = self._sources.get(drive_id)
        if src is None:
            src = self.open_source(drive_id)
            with self.cond:
                self._sources.setdefault(drive_id, src)
        return src

    def manifest(self, drive_id: int) -> dict:
        """What a player needs to ask for chunks: frame rate, size, frames, chunk length (frames)
        and count."""

        s = self.source(drive_id)
        w, h = output_size(s.width, s.height, self.settings.max_height)
        return {"drive": drive_id, "fps": s.fps, "width": w, "height": h, "frames": s.frames_total,
                "chunk_frames": s.chunk_frames, "chunks": s.chunks, "duration": s.frames_total / s.fps}  # fmt: skip

    def _producer_for(self, src: StreamSource, k: int) -> Producer:
        """A live producer that will reach chunk ``k`` soon, or a new one starting there (under
        ``cond``)."""
        self._producers = [p for p in self._producers if not p.done]
        for p in self._producers:
            if (
                p.source.drive_id == src.drive_id
                and p.generation == self._generation
                and not p.stop
                and p.error is None
                and p.next <= k <= p.next + self.reach
            ):
                return p
        live = [p for p in self._producers if not p.stop]
        while len(live) >= self.max_producers:
            oldest = min(live, key=lambda p: p.asked)
            oldest.stop = True
            live.remove(oldest)
        p = Producer(self, src, self._generation, k)
        self._producers.append(p)
        p.thread.start()
        return p

    def chunk(self, drive_id: int, k: int, timeout: float = 60.0, viewer: str = "") -> bytes:
        """Chunk ``k`` of a drive (fragmented MP4 bytes), waiting up to ``timeout`` seconds for it
        to be produced. ``viewer``: who asks (a page's random id; "" for anonymous): a viewer's
        request withdraws its demand from every other producer, so a seek stops the production
        for the old position, and ends the wait of the viewer's earlier request (the page asks
        for one chunk at a time: an earlier one still waiting was abandoned). Raises
        :class:`StreamError` (404: no such chunk; 409: superseded; 500: the stream failed; 504:
        not produced in time)."""
        src = self.source(drive_id)
        if not 0 <= k < src.chunks:
            raise StreamError(f"drive {drive_id} has chunks 0-{src.chunks - 1}, not {k}", 404)
        deadline = time.monotonic() + timeout
        starts = 0
        with self.cond:
            ticket = self._tickets[viewer] = self._tickets.get(viewer, 0) + 1
            while True:
                if viewer and self._tickets[viewer] != ticket:  # the page asked for another chunk since
                    raise StreamError(f"chunk {k} of drive {drive_id}: superseded by a newer request", 409)
                key = (drive_id, self._generation, k)
                data = self.cache.get(key)
                if data is not None:
                    return data
                p = self._producer_for(src, k)
                if viewer:
                    for q in self._producers:
                        if q is not p:
                            q.wants.pop(viewer, None)
                p.wants[viewer] = max(p.wants.get(viewer, -1), k + self.ahead)
                p.asked = time.monotonic()
                self.cond.notify_all()
                if p.error is not None:
                    raise p.error
                if p.done or p.stop:
                    starts += 1
                    if starts > 3:
                        raise StreamError(f"chunk {k} of drive {drive_id} was not produced", 500)
                left = deadline - time.monotonic()
                if left <= 0:
                    raise StreamError(f"chunk {k} of drive {drive_id} was not produced in {timeout:.0f} s", 504)
                self.cond.wait(min(left, 1.0))
                data = self.cache.get(key)
                if data is not None:
                    return data
                if p.error is not None:
                    raise p.error

    def invalidate(self) -> None:
        """Forget every cached chunk and stop every producer (the archive changed: a forget)."""
        with self.cond:
            self._generation += 1
            for p in self._producers:
                p.stop = True
            self._sources.clear()
            self.cache.clear()
            self.cond.notify_all()

    def stats(self) -> dict:
        """Producers at work (at most ``max_producers``), producers told to stop that have not
        ended yet (they end at their next frame), chunks and bytes cached."""
        with self.cond:
            working = sum(1 for p in self._producers if not p.done and not p.stop)
            stopping = sum(1 for p in self._producers if not p.done and p.stop)
        return {"producers": working, "stopping": stopping, "chunks_cached": len(self.cache),
                "bytes_cached": self.cache.bytes}  # fmt: skip

    def close(self, timeout: float = 5.0) -> None:
        """Stop every producer and wait for them (up to ``timeout`` seconds in all)."""
        self.invalidate()
        deadline = time.monotonic() + timeout
        for p in list(self._producers):
            p.thread.join(max(0.0, deadline - time.monotonic()))
