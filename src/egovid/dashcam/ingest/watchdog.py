"""Encoders that stop responding: noticed, the piece coded again, or one clear error.

SVT-AV1 4.1.0 (the build PyAV's FFmpeg carries) was seen to stop for good on a loaded machine,
about 2 runs in 60 with other CPU-bound work beside them: every SVT-AV1 thread waiting on a
semaphore inside ``avcodec_send_frame`` (GIL released), and once a run of frames that did not
start with the keyframe egovid asked for. No cause on egovid's side was found, and a stuck C call
cannot be interrupted. So the ingest watches its encoders instead of waiting on them for ever:

* each encoder's :class:`Heartbeat` says since when the codec has had control (a frame handed
  over and not yet asked for the next one, or the final flush);
* an encoder that keeps control for :attr:`EncoderWatch.stall_s` seconds (the flush:
  ``flush_factor`` times that) ends its piece with :class:`EncoderStallError`; a codec that breaks
  the stream's structure raises :class:`~egovid.dashcam.codec.segment.EncoderFaultError`;
* the ingest then codes the piece again, in fresh encoders from a fresh decode of the drive, up
  to ``retries`` times (a ``note:`` and the report's ``encoder_restarts``); after that the
  command ends with one ``error:`` line naming the encoder, and nothing of the drive is stored.

The stuck encoder's thread is abandoned (a daemon thread blocked in C, holding no lock of ours).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from egovid.dashcam.codec import registry
from egovid.dashcam.codec.segment import EncoderFaultError


class EncoderStallError(EncoderFaultError):
    """An encoder kept control longer than the watch allows."""


@dataclass(frozen=True)
class EncoderWatch:
    """How the ingest watches its encoders.

    ``stall_s``: seconds an encoder may keep control of one frame before it counts as stuck
    (120 s: a 1080p frame takes well under a second even on a loaded 2-core machine);
    ``flush_factor``: the end-of-stream flush may take this many times ``stall_s`` (it codes the
    look-ahead's frames in one call); ``retries``: how many times a piece is coded again after an
    encoder fault; ``encode``: the function that codes a segment (the codec registry's; tests pass
    one whose codec stalls)."""

    stall_s: float = 120.0
    flush_factor: float = 4.0
    retries: int = 1
    encode: Callable = field(default=registry.encode_segment)

    def __post_init__(self) -> None:
        if not self.stall_s > 0 or not self.flush_factor >= 1 or self.retries < 0:
            raise ValueError(f"bad encoder watch {self}")


class Heartbeat:
    """Since when (``time.monotonic()`` seconds) an encoder has had control, and for how long it
    may keep it; ``None`` while it waits for a frame or has finished."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._since: float | None = None
        self._allowed = 0.0

    def busy(self, allowed_s: float) -> None:
        """The codec takes control now, for at most ``allowed_s`` seconds."""
        with self._lock:
            self._since, self._allowed = time.monotonic(), allowed_s

    def idle(self) -> None:
        """The codec gave control back (asks for the next frame, or has finished)."""
        with self._lock:
            self._since = None

    def overdue(self, now: float) -> float:
        """Seconds the codec has had control beyond what it is allowed (≤ 0: not overdue)."""
        with self._lock:
            return -1.0 if self._since is None else now - self._since - self._allowed
