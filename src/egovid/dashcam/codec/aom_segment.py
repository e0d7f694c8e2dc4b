"""AV1 joint segments: libaom with the older drive's aligned frames as a free reference (§14.2),
the AV1 counterpart of the VP9 backend of :mod:`egovid.dashcam.codec.segment`.

The blob is the segment container of :mod:`egovid.dashcam.codec.segment` under the magic
``EGAM``: one packet (temporal unit) per frame in display order, low delay (frames are coded in
display order; :func:`egovid.dashcam.codec.aom.run_structure` gives each frame's references).
Runs of ``refresh`` frames decode on their own. A run whose first frame has a baseline
(:data:`~egovid.dashcam.codec.segment.START_BASELINE_HELD`) begins with two undisplayed grey
frames (a keyframe, then a frame refreshing one slot) and its first frame predicted from the
baseline alone; every later frame of it predicts from earlier frames of the run (flat: its three
previous frames; in temporal layers, :class:`~egovid.dashcam.codec.aom.RunRefs`: the nearest frames
of the layers below, upper layers at a coarser quantiser) and, where it has one, its baseline,
which both sides copy into :data:`~egovid.dashcam.codec.aom.BASELINE_SLOT` before the frame
(``AV1_SET_REFERENCE``). A run without a baseline for its first frame
(:data:`~egovid.dashcam.codec.segment.START_KEY`) is plain libaom AV1: nothing is injected in it.
The bitstream is AV1, but only a decoder that repeats the injections (libaom's, through
:mod:`egovid.dashcam.codec.aom`) reproduces the pictures; the digests are taken from the
encoder's own pictures and a decoder following the encoder checks them (``verify``).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from egovid.core.errors import EgovidError
from egovid.dashcam.codec import aom, segment, vpx
from egovid.dashcam.codec.settings import EncoderSettings

CODEC = "aom"


def aom_settings(settings: EncoderSettings) -> aom.AomSettings:
    """libaom's settings from the archive's (:class:`~egovid.dashcam.codec.settings.EncoderSettings`)."""
    return aom.AomSettings(
        q=settings.q,
        speed=settings.speed,
        realtime=settings.realtime,
        threads=settings.threads,
        row_mt=settings.row_mt,
        tile_columns=settings.tile_columns,
        fps=settings.fps,
        fixed_costs=settings.fixed_costs,
        ref_mvs=settings.ref_mvs,
        qm=settings.qm,
    )


class _AomCoder:
    """libaom's encoder (and the verifying decoder, when it follows) for one segment."""

    def __init__(self, width, height, settings, out: segment.SegmentWriter, verify, verify_runs, clock) -> None:
        self.w, self.h, self.out, self.clock = width, height, out, clock
        self.pw, self.ph = vpx.padded_size(width, height)
        self.enc = aom.AV1Encoder(self.pw, self.ph, aom_settings(settings))
        self.dec = aom.AV1Decoder(self.pw, self.ph, threads=settings.threads) if verify else None
        self.verify_runs = verify_runs
        self.follow = False
        self.grey = np.full((self.ph * 3 // 2, self.pw), 128, np.uint8)
        self.q, self.top_dq, self.period = settings.q, settings.gop_dq, settings.gop
        self.keep_refresh = settings.keep_refresh
        self.run = aom.RunRefs(False, self.period, settings.keep_refresh)

    def code(self, frame, refs, refresh=(), baseline=None, layer=0) -> tuple[bytes, np.ndarray]:
        t0 = time.perf_counter()
        q = min(63, self.q + self.run.q_offset(layer, self.top_dq))
        spare = self.run.spare(refresh) if refs is not None else 0
        pkt = self.enc.encode(frame, refs, refresh, baseline, q, spare)
        rec = self.enc.reconstruction()
        t1 = time.perf_counter()
        self.clock["encode"] = self.clock.get("encode", 0.0) + t1 - t0
        if self.follow:
            if not np.array_equal(self.dec.decode(pkt, baseline), rec):
                raise EgovidError(
                    "the decoder does not reproduce the encoder's pictures",
                    "report this with the libaom version (egovid dashcam report shows it); nothing was stored",
                )
            self.clock["verify"] = self.clock.get("verify", 0.0) + time.perf_counter() - t1
        return pkt, rec

    def finish(self, k: int, frame: np.ndarray, refs, refresh=(), layer=0, baseline=None) -> None:
        pkt, rec = self.code(vpx.pad_i420(frame, self.pw, self.ph), refs, refresh, baseline, layer)
        self.out.emit(pkt, k)
        self.out.picture(k, frame, vpx.crop_i420(rec, self.w, self.h))

    def start_run(self, k0: int, first: np.ndarray, b0: np.ndarray | None) -> None:
        """The run's first frame: a keyframe, or (with a baseline) from it alone after the two
        undisplayed grey frames."""
        self.follow = self.dec is not None and (self.verify_runs is None or self.verify_runs(len(self.out.starts)))
        self.run = aom.RunRefs(b0 is not None, self.period, self.keep_refresh)
        if b0 is None:
            self.out.begin_run(segment.START_KEY)
            self.finish(k0, first, None)
            return
        self.out.begin_run(segment.START_BASELINE_HELD)
        self.out.emit(self.code(self.grey, None)[0], k0)
        self.out.emit(self.code(self.grey, {aom.LAST: 0}, (0,))[0], k0)
        self.finish(k0, first, *self.run.next(True), b0)

    def rest_of_run(self, k0: int, run: Iterator[np.ndarray], base: Callable[[int], np.ndarray | None]) -> int:
        n = 1
        for n, frame in enumerate(run, 2):
            k = k0 + n - 1
            b = base(k) if self.run.joint else None
            self.finish(k, frame, *self.run.next(b is not None), b)
        return n

    def close(self) -> None:
        self.enc.close()
        if self.dec is not None:
            self.dec.close()


def encode_segment(
    frames: Iterator[np.ndarray],
    width: int,
    height: int,
    settings: EncoderSettings,
    baselines: Callable[[int], np.ndarray | None] | None = None,
    progress: Callable[[int], None] | None = None,
    keep_recon: list | None = None,
    *,
    verify: bool = False,
    verify_runs: Callable[[int], bool] | None = None,
    clock: dict | None = None,
    spool=None,
    on_run: Callable[[int, int, float], None] | None = None,
) -> segment.EncodedSegment:
    """libaom AV1: encode unpadded I420 frames; ``baselines(k)`` gives frame k's padded baseline
    (or None). The same contract as :func:`egovid.dashcam.codec.segment.encode_segment`;
    ``settings.gop`` is the temporal-layer period (:class:`~egovid.dashcam.codec.aom.RunRefs`: 1
    flat, 2 or 4 layers, the top layer at ``q + gop_dq``). Low delay either way: the header
    records GOP 1 (one packet per frame in display order), whatever the layers, so the decoder
    and the container are those of a flat segment."""
    aom.self_test()
    out = segment.SegmentWriter(
        width, height, settings.refresh, spool=spool, keep_recon=keep_recon, progress=progress, on_run=on_run
    )
    coder = _AomCoder(width, height, settings, out, verify, verify_runs, clock if clock is not None else {})

    def base(k: int) -> np.ndarray | None:
        return baselines(k) if baselines is not None else None

    try:
        it = iter(frames)
        k0 = 0
        while True:
            run = itertools.islice(it, settings.refresh) if settings.refresh else it
            first = next(run, None)
            if first is None:
                break
            coder.start_run(k0, first, base(k0))
            k0 += coder.rest_of_run(k0, run, base)
    except BaseException:
        out.close()
        raise
    finally:
        coder.close()
    return out.result(settings.q, 1, CODEC)


def decode_runs(
    lay: segment.SegmentLayout,
    packets: Iterable[bytes],
    first_run: int,
    baselines: Callable[[int], np.ndarray | None] | None = None,
    start: int = 0,
) -> Iterator[np.ndarray]:
    """Frames from ``start`` (display order) of a libaom segment, given its packets from the first
    packet of run ``first_run`` on (which must hold ``start`` or come before it); ``baselines``
    as the encoder had them (a joint run cannot be decoded without)."""
    aom.self_test()
    plan = lay.plan()
    p0 = lay.run_packets()[first_run][0]
    skip = segment.period_start(lay.refresh, start)
    if plan[p0][0] > skip:
        raise ValueError("decoding must start at or before the run holding the first frame asked for")
    pw, ph = vpx.padded_size(lay.width, lay.height)
    dec = aom.AV1Decoder(pw, ph)
    joint = False
    try:
        for (k, role, _), pkt in zip(plan[p0:], packets, strict=False):
            if k < skip:
                continue
            if role == "dummy":
                joint = True
                dec.decode(pkt)
                continue
            if role == "key":
                joint, golden = False, None
            elif joint and baselines is None:
                raise ValueError("a joint libaom segment needs its baselines")
            else:
                golden = baselines(k) if joint else None
            out = dec.decode(pkt, golden)
            if k >= start:
                yield vpx.crop_i420(out, lay.width, lay.height)
    finally:
        dec.close()
