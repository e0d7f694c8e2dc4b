"""The stages of an ingest that see pictures, for one piece: choose the baseline, align, encode
(and verify), streamed from the one decode pass with bounded memory.

::

    decode_once ──► [first 24 frames: light] ──► choose_baseline
         │                                            │
         └──► small grey ──► ALIGNERS[name]     ──► match k final ──► baseline k (older drive,
                                                                          decoded forward once)
                                                                              │
    frame k (held until its match is final) ─────────────────────────► VP9 encode (+ lockstep
                                                                          decode: verify) ──► blob

A producer thread decodes, aligns and builds baselines; the encoder runs in the calling thread
(libvpx, OpenCV and FFmpeg release the GIL, so the two use two cores). Memory: the lookahead,
the ~14 frames the alignment holds back, the encoder's GOP and a short queue, whatever the length
of the drive.

The baseline is chosen by the light of the piece's first :data:`LOOKAHEAD` frames (thesis
§15.3.2 averages over the whole sequence; frames are decoded once and not kept, so the choice is
made before the rest arrives). The sequence's stored illumination features are the average over
its frames, as the thesis has them (the first :data:`LOOKAHEAD` and every :data:`LIGHT_EVERY`-th
after them), for later drives to be matched against.
"""

from __future__ import annotations

import contextlib
import queue
import tempfile
import threading
import time
from collections.abc import Callable, Iterator

import cv2
import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.metrics.psnr import psnr_db
from egovid.dashcam.align import ALIGNERS
from egovid.dashcam.align.illumination import frame_features
from egovid.dashcam.align.orb import OrbScorer, small_gray, warm_up, wide_window
from egovid.dashcam.codec import segment as codec
from egovid.dashcam.codec import vpx
from egovid.dashcam.extract import FrameSource
from egovid.dashcam.ingest.frames import InputFrame, RefFrames
from egovid.dashcam.ingest.options import IngestOptions
from egovid.dashcam.ingest.records import DriveTrack, EncodedPiece, PiecePlan
from egovid.dashcam.ingest.stages import choose_baseline
from egovid.dashcam.ingest.watchdog import EncoderStallError, EncoderWatch, Heartbeat

LOOKAHEAD = 24  # frames whose light chooses the baseline (one random-access period)
LIGHT_EVERY = 4  # after the first LOOKAHEAD frames, every 4th frame's light counts
QUEUE = 12  # frames in flight between the producer and the encoder (6 left the encoder waiting twice as long)


def _illumination(gray: np.ndarray) -> np.ndarray:
    return frame_features(cv2.resize(gray, (160, 90), interpolation=cv2.INTER_AREA))


class _Pipe:
    """A bounded queue between threads that carries an exception or the end, and gives up when
    the other side has stopped."""

    _END = object()

    def __init__(self, size: int) -> None:
        self.q: queue.Queue = queue.Queue(size)
        self.stop = threading.Event()
        self.dropped = threading.Event()  # its encoder lost the early choice: items go nowhere
        self.ended = threading.Event()  # the same, but its encoder is told the stream ends (and flushes)

    def put(self, item) -> None:
        if self.dropped.is_set() or self.ended.is_set():
            return
        while not self.stop.is_set():
            try:
                self.q.put(item, timeout=0.1)
                return
            except queue.Full:
                continue
        raise _StoppedError

    def close(self, error: BaseException | None = None) -> None:
        with contextlib.suppress(_StoppedError):
            self.put(error if error is not None else self._END)

    def __iter__(self):
        while True:
            try:
                item = self.q.get(timeout=0.1)
            except queue.Empty:
                if self.dropped.is_set():
                    raise _DroppedError from None
                if self.ended.is_set():
                    return
                continue
            if self.dropped.is_set():
                raise _DroppedError
            if item is self._END or self.ended.is_set():
                return
            if isinstance(item, BaseException):
                raise item
            yield item


class _StoppedError(Exception):
    pass


class _DroppedError(Exception):
    """Raised to an encoder whose encode lost the early choice (:class:`_Referee`)."""


class _Prefetch:
    """The older drive's frames of the alignment's first (wide) search, decoded and their ORB
    features computed in a thread of its own while the piece's first :data:`LOOKAHEAD` frames are
    read to choose the baseline (the encoder has nothing to do then). Started for the candidate
    the first frame's light picks; handed to the alignment if the choice agrees, else dropped."""

    def __init__(self, candidate, refs: RefFrames, frames: range) -> None:
        self.candidate, self.refs = candidate, refs
        self.stop = threading.Event()
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, args=(frames,), name="egovid-prefetch", daemon=True)
        self.thread.start()

    def _run(self, frames: range) -> None:
        try:
            for j in frames:
                if self.stop.is_set():
                    return
                self.refs.feats(j)
        except BaseException as exc:  # raised again where the alignment takes the frames
            self.error = exc

    def take(self) -> RefFrames:
        """The older drive's frames, as far as the thread got (it stops at the frame in hand: the
        alignment computes the rest as it needs them, rather than wait)."""
        self.stop.set()
        self.thread.join()
        if self.error is not None:
            self.refs.close()
            raise self.error
        return self.refs

    def cancel(self) -> None:
        """Stop, and close the older drive."""
        self.stop.set()
        self.thread.join()
        self.refs.close()


class _PieceRun:
    """One piece on its way through the stages (see the module docstring)."""

    def __init__(self, source, piece, frames, track, fps, size, opts, clock) -> None:
        self.source, self.piece, self.frames, self.track = source, piece, frames, track
        self.fps, self.size, self.opts, self.clock = fps, size, opts, clock
        self.n = piece.length
        self.stopped = np.asarray(track.stopped[piece.frames[0] : piece.frames[1]], bool)
        self.illum_sum = np.zeros(8)
        self.illum_n = 0
        self.seen = 0
        self.head: list[InputFrame | None] = []
        self.ref = None
        self.refs: RefFrames | None = None
        self.refmap = np.full(self.n, -1, np.int64)
        self.align: dict = {"kind": "none"}
        self.fallbacks = 0
        self.peak_held = 0
        self.scorer = OrbScorer()
        self.prefetch: _Prefetch | None = None

    def tick(self, stage: str, t0: float) -> None:
        self.clock[stage] = self.clock.get(stage, 0.0) + time.perf_counter() - t0

    def next_frame(self) -> InputFrame:
        fr = next(self.frames, None)
        if fr is None:
            raise EgovidError(
                f"the video ends before frame {self.piece.frames[1]} (its container lists more frames)",
                "the file is truncated or damaged; re-export or repair it",
            )
        return fr

    def analyse(self, fr: InputFrame) -> InputFrame:
        """Add the frame's light to the piece's (every frame of the first :data:`LOOKAHEAD`, which
        choose the baseline, then every :data:`LIGHT_EVERY`-th: the stored average of a sequence
        changes by far less than drives of one place differ, at a quarter of the work)."""
        self.seen += 1
        if self.seen <= LOOKAHEAD or self.seen % LIGHT_EVERY == 0:
            t0 = time.perf_counter()
            self.illum_sum += _illumination(fr.gray)
            self.illum_n += 1
            self.tick("analyse", t0)
        return fr

    def choose(self) -> None:
        """Stage *baseline*: the light of the first frames picks the older drive (if any may serve).

        Meanwhile the older drive the first frame's light points to is opened and the alignment's
        first search prepared (:class:`_Prefetch`), kept if the choice agrees."""
        if not self.piece.candidates:
            return
        head = min(self.n, LOOKAHEAD)
        try:
            for i in range(head):
                self.head.append(self.analyse(self.next_frame()))
                if i == 0 and ALIGNERS[self.opts.aligner].orb_search:
                    self._start_prefetch()
            self.ref = choose_baseline(self.illum_sum / self.illum_n, self.piece.candidates)
        finally:
            if self.prefetch is not None and self.prefetch.candidate is not self.ref:
                self.prefetch.cancel()
                self.prefetch = None
        if self.ref is not None and self.opts.baseline_align != "none":
            self.align = {"kind": self.opts.baseline_align, "params": []}

    def drop_prefetch(self) -> None:
        """Stop the prefetch thread and close the older drive it reads, unless the producer took
        it: an interrupted piece must leave no thread decoding the older drive (the interpreter
        would end it inside OpenCV or FFmpeg at exit, and closing that decoder under it fails)."""
        if self.prefetch is not None:
            self.prefetch.cancel()
            self.prefetch = None

    def _start_prefetch(self) -> None:
        likely = choose_baseline(self.illum_sum / self.illum_n, self.piece.candidates)
        if likely is not None:
            m = self._length(likely)
            p = int(np.clip(round(self._prior(likely)[0]), 0, m - 1))
            self.prefetch = _Prefetch(likely, self._open_refs(likely), wide_window(p, m, self.fps))

    @staticmethod
    def _length(ref) -> int:
        return ref.frame_end - ref.frame_start

    def _prior(self, ref) -> np.ndarray:
        """(n,) the older drive's frame (its sequence's numbering, float) at each frame's GPS position."""
        order = np.argsort(ref.positions, kind="stable")
        return np.interp(self.piece.positions, ref.positions[order], order.astype(float))

    def _open_refs(self, ref) -> RefFrames:
        return RefFrames(
            self.source,
            ref.drive_id,
            ref.frame_start,
            self._length(ref),
            self.size,
            self.clock,
            self.opts.refine_radius,
            self.opts.refine_features,
        )

    def produce(self, pipes: list[_Pipe]) -> None:
        """Decode (the shared pass), analyse, align, build baselines; hand (k, frame, baseline)
        to the encoder(s) in order. Runs in its own thread; errors go down the pipes."""
        try:
            aligner = None
            f0, f1 = self.piece.frames
            if self.ref is not None:
                ref = self.ref
                m = self._length(ref)
                if self.prefetch is not None:
                    self.refs, self.prefetch = self.prefetch.take(), None
                else:
                    self.refs = self._open_refs(ref)
                prior = self._prior(ref)
                speed_ref = np.abs(np.gradient(ref.positions.astype(float)) * ref.fps) if m > 1 else np.zeros(m)
                aligner = ALIGNERS[self.opts.aligner](
                    self.refs,
                    prior,
                    self.track.speed[f0:f1],
                    speed_ref,
                    self.stopped,
                    self.fps,
                    self.opts.align_every,
                )
            held: dict[int, np.ndarray] = {}
            k_out = 0
            for k in range(self.n):
                if k < len(self.head):
                    fr, self.head[k] = self.head[k], None
                else:
                    fr = self.analyse(self.next_frame())
                if aligner is not None and pipes[0].dropped.is_set():  # standalone won: stop aligning
                    self.fallbacks = aligner.fallbacks
                    for j in sorted(held):
                        for p in pipes[1:]:
                            p.put((j, held[j], None))
                    held.clear()
                    aligner = None
                    self.refs.close()
                if aligner is None:
                    for p in pipes:
                        p.put((k, fr.image, None))
                    continue
                held[k] = fr.image
                t0 = time.perf_counter()
                finals = aligner.push(fr.gray)
                self.tick("align", t0)
                for j in finals:
                    item = self.baseline(k_out, j, held.pop(k_out))
                    k_out += 1
                    low = aligner.lowest_needed()
                    self.refs.release_below(low, min(low, j))
                    pipes[0].put(item)
                    for p in pipes[1:]:
                        p.put((item[0], item[1], None))
                self.peak_held = max(self.peak_held, len(held) + self.refs.held)
            if aligner is not None:
                self.fallbacks = aligner.fallbacks
                if k_out != self.n and not pipes[0].dropped.is_set():
                    raise RuntimeError(f"the alignment gave {k_out} of {self.n} matches")
            for p in pipes:
                p.close()
        except _StoppedError:  # an encoder stopped: end the others' streams (they flush and finish)
            for p in pipes:
                p.close()
        except BaseException as exc:  # handed to the encoder's thread
            for p in pipes:
                p.close(exc)
        finally:
            if self.refs is not None:
                self.refs.close()

    def baseline(self, k: int, j: int, image: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
        """Frame k's baseline: the older drive's frame j (its sequence's numbering), padded and,
        with ``--baseline-align``, globally aligned (parameters estimated here, stored)."""
        t0 = time.perf_counter()
        w, h = self.size
        pw, ph = vpx.padded_size(w, h)
        self.refmap[k] = self.ref.frame_start + j
        raw = self.refs.image(j)
        params = None
        if self.align["kind"] == "gain":
            params = codec.estimate_gain(image[:h], raw[:h])
        elif self.align["kind"] == "similarity":
            params = _similarity(self.scorer, image, raw, w, h)
        if params is not None:
            self.align["params"].append(params)
        base = codec.apply_alignment(vpx.pad_i420(raw, pw, ph), pw, ph, self.align["kind"], params)
        self.tick("baseline", t0)
        return k, image, base


def _encode_from(
    pipe: _Pipe, clock: dict, stage: str, watch: EncoderWatch, beat: Heartbeat, *args, **kwargs
) -> codec.EncodedSegment:
    """``watch.encode`` (the registry's encode_segment) of the frames coming down ``pipe``
    (baselines with them); ``beat`` says while the codec has control of a frame or the flush."""
    bases: dict[int, np.ndarray] = {}

    def frames() -> Iterator[np.ndarray]:
        t0 = time.perf_counter()
        for k, image, base in pipe:
            clock["wait:" + stage] = clock.get("wait:" + stage, 0.0) + time.perf_counter() - t0
            if base is not None:
                bases[k] = base
            beat.busy(watch.stall_s)
            yield image
            beat.idle()
            t0 = time.perf_counter()
        beat.busy(watch.stall_s * watch.flush_factor)  # the end of stream: the flush

    def baseline(k: int) -> np.ndarray | None:
        for old in [j for j in bases if j < k - 64]:  # asked for never (a keyframe's, a P frame's)
            del bases[old]
        return bases.pop(k, None)

    local: dict = {}
    try:
        return watch.encode(frames(), *args, baselines=baseline, clock=local, **kwargs)
    finally:
        beat.idle()
        for key, v in local.items():
            # the encoder's seconds go to ``stage``; the verifying decoder's to "verify", or to
            # "verify:standalone" beside a joint encode
            name = stage if key == "encode" else key if stage == "encode" else f"{key}:{stage}"
            clock[name] = clock.get(name, 0.0) + v


#: dB of PSNR-Y per halving of the bytes, near the archive's quantisers (SVT-AV1 and libvpx on the
#: synthetic drives: 1.7-2.4): how a joint and a standalone encode of a piece at slightly different
#: quality are compared at equal quality (:func:`keep_joint`).
DB_PER_HALVING = 2.0


#: Random-access runs after which a piece's joint and standalone encodes are compared and the
#: larger one stopped (the rest of the piece is coded by one encoder; with ``--measure-savings``
#: both run to the end and the whole piece decides).
DECIDE_RUNS = 2


def keep_joint(joint: tuple[int, float], alone: tuple[int, float]) -> tuple[bool, str]:
    """Whether the joint encode of a piece is the one to store, and why, given (bytes, PSNR-Y) of
    each: the smaller at equal PSNR-Y. The joint bytes are moved along the rate curve to the
    standalone's quality, ``jb · 2^((sp − jp) / DB_PER_HALVING)``: a joint encode of higher PSNR-Y
    would need fewer bytes at the standalone's quality, one of lower PSNR-Y more."""
    (jb, jp), (sb, sp) = joint, alone
    equal = jb * 2.0 ** ((sp - jp) / DB_PER_HALVING)
    kept = equal < sb
    return kept, (
        f"joint {jb} B at {jp:.2f} dB (= {equal:.0f} B at {sp:.2f} dB) vs standalone {sb} B at {sp:.2f} dB: "
        f"{'joint' if kept else 'standalone'} is smaller"
    )


class _Referee:
    """The early choice between a piece's joint and standalone encodes: when both have coded the
    first ``at`` frames (:data:`DECIDE_RUNS` runs), :func:`keep_joint` on those frames, and the
    other encoder is stopped (its pipe dropped; the producer stops aligning if it was the joint).

    An SVT-AV1 encoder is never dropped mid-stream: its context freed with frames in flight and no
    end of stream can block for ever in ``svt_av1_enc_deinit`` ("deinit called without sending
    EOS!") while the GIL is held, which froze a whole test run once. A losing SVT-AV1 encode is
    ended instead (its pipe's ``ended``: the frames stop, it sends the end of stream and flushes
    as at the end of a piece) and what it coded is discarded; running it to the end took a core
    from the joint encode for the whole drive."""

    def __init__(self, jobs: dict, at: int) -> None:
        self.jobs, self.at = jobs, at
        self.seen: dict[str, tuple[int, float]] = {}
        self.lock = threading.Lock()
        self.loser: str | None = None
        self.why = ""

    def hook(self, name: str) -> Callable[[int, int, float], None]:
        def on_run(frames: int, nbytes: int, mse: float) -> None:
            if frames != self.at:
                return
            with self.lock:
                self.seen[name] = (nbytes, psnr_db(mse))
                if len(self.seen) == 2 and self.loser is None:
                    kept, why = keep_joint(self.seen["joint"], self.seen["standalone"])
                    self.loser = "standalone" if kept else "joint"
                    self.why = f"first {frames} frames: {why}"
                    pipe = self.jobs[self.loser]["pipe"]
                    (pipe.ended if self.jobs[self.loser]["settings"].codec == "av1" else pipe.dropped).set()

        return on_run


class _Encoders:
    """The piece's encoders, each in its own thread on its own pipe from the producer: the stored
    candidate(s) — the standalone encode (``opts.codec``) and, where the piece has an older drive,
    the joint encode (``opts.joint_codec``) — each spooled to a temporary file."""

    def __init__(
        self, run: _PieceRun, opts: IngestOptions, fps: float, size, clock, progress, watch: EncoderWatch
    ) -> None:
        self.watch = watch
        self.jobs: dict[str, dict] = {}
        self.pipes: list[_Pipe] = []
        w, h = size
        joint = run.ref is not None
        n_runs = len(codec.substreams(run.n, opts.refresh))
        self.followed: list[int] = []
        picks = opts.verified_runs(n_runs, run.piece.frames[0])

        def verified(i: int) -> bool:
            if picks(i):
                self.followed.append(i)
                return True
            return False

        shown = [0]

        def once(k: int) -> None:  # two encoders report the same frames: count each once
            if progress is not None and k > shown[0]:
                shown[0] = k
                progress(k)

        at = DECIDE_RUNS * opts.refresh
        self.referee = _Referee(self.jobs, at) if joint and not opts.measure_savings and 0 < at < run.n else None
        if joint:
            st = opts.joint_settings(fps)
            kw = {"verify": opts.verify, "verify_runs": verified, "progress": once}
            self._add("joint", "encode", st, w, h, kw)
        st = opts.standalone_settings(fps)
        kw = {"progress": once} if joint else {"verify": opts.verify, "verify_runs": verified, "progress": once}
        self._add("standalone", "standalone" if joint else "encode", st, w, h, kw)

    def _add(self, name: str, stage: str, settings, w: int, h: int, kw: dict) -> None:
        if self.referee is not None:
            kw = {**kw, "on_run": self.referee.hook(name)}
        pipe = _Pipe(QUEUE)
        spool = tempfile.TemporaryFile(prefix=f"egovid-{name}-")  # noqa: SIM115 - closed by close()
        job = {"pipe": pipe, "spool": spool, "settings": settings, "beat": Heartbeat()}

        def work() -> None:
            try:
                seg = _encode_from(pipe, self.clock, stage, self.watch, job["beat"], w, h, settings, spool=spool, **kw)
                if pipe.ended.is_set():  # lost the early choice and ended short: nothing to keep
                    job["dropped"] = True
                else:
                    job["seg"] = seg
            except _DroppedError:
                job["dropped"] = True
            except BaseException as exc:
                job["error"] = exc
                pipe.stop.set()

        job["thread"] = threading.Thread(target=work, name=f"egovid-{name}", daemon=True)
        self.jobs[name] = job
        self.pipes.append(pipe)

    def run(self, producer: threading.Thread, clock: dict) -> dict[str, codec.EncodedSegment]:
        """Start the producer and the encoders, wait for all; the segments by name. An encoder that
        keeps control past its watch raises :class:`EncoderStallError` (its thread is abandoned;
        the other encoders' streams are ended and given ``stall_s`` to finish)."""
        self.clock = clock
        producer.start()
        for job in self.jobs.values():
            job["thread"].start()
        stalled = None
        try:
            while stalled is None and any(job["thread"].is_alive() for job in self.jobs.values()):
                for name, job in self.jobs.items():
                    job["thread"].join(0.25)
                    if job["thread"].is_alive() and job["beat"].overdue(time.monotonic()) > 0:
                        stalled = name
                        break
        finally:
            for p in self.pipes:
                p.stop.set()
                p.ended.set()
            producer.join()
        if stalled is not None:
            codec_name = self.jobs[stalled]["settings"].codec
            for name, job in self.jobs.items():
                if name != stalled:
                    job["thread"].join(self.watch.stall_s)
            raise EncoderStallError(
                f"the {stalled} encoder ({codec_name}) kept control of a frame for over "
                f"{self.watch.stall_s:.0f} s and was given up",
                "run the ingest again; if it recurs, pass --codec vp9 or report the encoder's hang",
            )
        for job in self.jobs.values():
            if "error" in job:
                raise job["error"]
        return {name: job["seg"] for name, job in self.jobs.items() if "seg" in job}

    def close(self) -> None:
        for job in self.jobs.values():
            job["spool"].close()


def encode_piece(
    source: FrameSource,
    piece: PiecePlan,
    frames: Iterator[InputFrame],
    track: DriveTrack,
    fps: float,
    size: tuple[int, int],
    opts: IngestOptions,
    progress: Callable[[str, int, int], None] | None = None,
    done: int = 0,
    n_total: int = 0,
    clock: dict | None = None,
    watch: EncoderWatch | None = None,
) -> EncodedPiece:
    """Baseline, align, encode and verify one piece, taking its frames from ``frames`` (the drive's
    one decode pass, positioned at the piece's first frame); the blob goes to ``source.blobs``.

    A piece without an older drive is coded standalone (``opts.codec``); one with an older drive
    is coded both ways at once, joint (``opts.joint_codec`` with the baseline) and standalone, and the smaller at
    equal PSNR-Y is stored (:func:`keep_joint`; the reason is recorded in the segment's
    ``choice``). ``clock`` accumulates busy seconds per stage (decode, analyse, reference, align,
    baseline, encode, verify, standalone) and the encoders' waits."""
    clock = clock if clock is not None else {}
    t_start = time.perf_counter()
    run = _PieceRun(source, piece, frames, track, fps, size, opts, clock)
    if piece.candidates and ALIGNERS[opts.aligner].orb_search:
        warm_up()  # while the first frames are decoded for the choice of the baseline
    try:
        run.choose()
        cb = (lambda k: progress("encode", done + k, n_total)) if progress else None
        encoders = _Encoders(run, opts, fps, size, clock, cb, watch or EncoderWatch())
    except BaseException:  # e.g. SIGTERM while the encoders open: the producer never takes the prefetch
        run.drop_prefetch()
        raise
    producer = threading.Thread(
        target=run.produce, args=(encoders.pipes,), name=f"egovid-piece-{piece.index}", daemon=True
    )
    try:
        segs = encoders.run(producer, clock)
        alone, joint = segs.get("standalone"), segs.get("joint")
        if run.ref is None:
            kept, why = False, "no older drive of this path and light"
        elif encoders.referee is not None and encoders.referee.loser is not None:
            kept, why = encoders.referee.loser == "standalone", encoders.referee.why
        else:
            kept, why = keep_joint((joint.nbytes, joint.psnr_y), (alone.nbytes, alone.psnr_y))
        enc = segs["joint" if kept else "standalone"]
        t0 = time.perf_counter()
        sha = source.blobs.put_chunks(enc.chunks())
        run.tick("store", t0)
    finally:
        run.drop_prefetch()  # not taken: the producer stopped before its first frame (it is joined by now)
        encoders.close()
    return _encoded(run, opts, enc, sha, kept, why, encoders, alone if run.ref is not None else None, joint, t_start)


def _encoded(run, opts, enc, sha, kept, why, encoders, alone, joint, t_start) -> EncodedPiece:
    """The piece's record: the kept encode, its settings and the choice."""
    st = encoders.jobs["joint" if kept else "standalone"]["settings"]
    w, h = run.size
    params = {
        "width": w,
        "height": h,
        "codec": st.codec,
        "q": st.q,
        "speed": st.speed,
        "realtime": st.realtime,
        "threads": st.threads,
        "gop": st.gop,
        "keep_refresh": st.keep_refresh,
        "fixed_costs": st.fixed_costs,
        "refresh": st.refresh,
        "preset": opts.preset,
        "recon_digest": enc.recon_digest,
        "run_digests": enc.run_digests,
        "run_offsets": enc.run_offsets,
        "psnr_y": enc.psnr_y,
        "verified_runs": encoders.followed if opts.verify and kept == (run.ref is not None) else [],
        "aligner": opts.aligner,
        "choice": why,
        "joint_codec": encoders.jobs["joint"]["settings"].codec if "joint" in encoders.jobs else None,
        "joint_bytes": joint.nbytes if joint is not None else None,
        "joint_psnr_y": joint.psnr_y if joint is not None else None,
        "standalone_bytes": alone.nbytes if alone is not None else None,
        "standalone_psnr_y": alone.psnr_y if alone is not None else None,
        "stopped_frames": int(run.stopped.sum()),
        "prior_fallbacks": run.fallbacks,
    }
    # libaom's motion-field projection off and quantisation matrices on: recorded only where set,
    # so the params of segments coded without them read as before
    if not st.ref_mvs:
        params["ref_mvs"] = False
    if st.qm:
        params["qm"] = True
    ref = run.ref if kept else None
    return EncodedPiece(
        run.piece.frames,
        "joint" if ref is not None else "intra",
        ref.drive_id if ref is not None else None,
        ref.drive_name if ref is not None else None,
        run.refmap if ref is not None else np.full(run.n, -1, np.int64),
        run.align if ref is not None else {"kind": "none"},
        sha,
        enc.nbytes,
        params,
        run.illum_sum / max(run.illum_n, 1),
        enc.psnr_y,
        params["standalone_bytes"],
        int(run.stopped.sum()),
        run.fallbacks,
        time.perf_counter() - t_start,
        run.peak_held,
    )


def _similarity(scorer: OrbScorer, image: np.ndarray, ref: np.ndarray, w: int, h: int) -> list[int]:
    """The similarity warp (fixed point) from the reference frame to the new frame, from ORB
    matches on the small grey copies (codec.estimate_similarity); identity when too few match."""
    ga, gb = small_gray(image, w, h), small_gray(ref, w, h)
    a, b = scorer.features(ga), scorer.features(gb)
    p = None
    if a.desc is not None and b.desc is not None:
        m = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(a.desc, b.desc)
        if len(m) >= 12:
            pa, pb = a.pts[[x.queryIdx for x in m]], b.pts[[x.trainIdx for x in m]]
            p = codec.estimate_similarity(pa, pb, ga.shape[1] / w)
    return p or [4096, 0, 0, 0, 4096, 0]
