"""AV1 segments: SVT-AV1 encodes, dav1d decodes (both through PyAV's bundled FFmpeg).

What a first drive and every piece without an older drive of its path and light are stored in:
SVT-AV1 with what makes it strong (its hierarchical random-access structure, look-ahead,
temporal filtering) at a constant rate factor, random access every ``refresh`` frames by closed-GOP
keyframes (``irefresh-type=2``, and the run's first frame forced to a keyframe), so a stretch
decodes from the run holding it as with VP9. SVT-AV1 gives no reconstruction and takes no
external reference picture; the digests are taken from dav1d's decode of the packets, made
beside the encoder as they come, and every later extract decodes with dav1d again: AV1 decoding
is normative, so the pictures are bit-identical (checked against the digests on every extract).

The blob is the segment container of :mod:`egovid.dashcam.codec.segment` under the magic
``EGA1``: one packet (temporal unit) per frame, in display order, every run starting with a
keyframe that carries the sequence header.
"""

from __future__ import annotations

import contextlib
import functools
import os
import time
from collections.abc import Callable, Iterable, Iterator
from fractions import Fraction

import av
import numpy as np

from egovid.core.errors import EgovidError
from egovid.dashcam.codec import segment, vpx
from egovid.dashcam.codec.settings import EncoderSettings

ENCODER, DECODER = "libsvtav1", "libdav1d"


def _encoder(pw: int, ph: int, settings: EncoderSettings) -> av.CodecContext:
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its banner at every start otherwise (errors stay)
    cc = av.CodecContext.create(ENCODER, "w")
    cc.width, cc.height, cc.pix_fmt = pw, ph, "yuv420p"
    cc.time_base = Fraction(1, settings.fps)
    cc.framerate = Fraction(settings.fps)
    cc.gop_size = settings.refresh if settings.refresh else 1 << 20
    params = f"irefresh-type=2:lp={settings.threads}"
    cc.options = {"preset": str(settings.speed), "crf": str(max(settings.q, 1)), "svtav1-params": params}
    with keep_thread_scheduling():
        cc.open()
    return cc


@contextlib.contextmanager
def keep_thread_scheduling() -> Iterator[None]:
    """Give the calling thread back the scheduling policy it had before the block.

    SVT-AV1 (4.1.0 at least) switches the thread that opens an encoder to real-time ``SCHED_FIFO``
    priority 99 when the process runs as root (its banner then warns "Failed to set thread
    priority" for its own threads). Left so, that thread — often a program's main thread — and
    every process it starts afterwards (exiftool, ffmpeg, a test's command) run real-time: a busy
    child then takes every core it can and nothing of normal priority runs until it ends (seen: a
    test's 0.2-s poll blocked for minutes while a child rendered, and a loaded machine's other
    work stalled). Measured by reading the thread's policy back from the kernel before and after."""
    try:
        policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    except (AttributeError, OSError):  # no POSIX scheduling here: nothing to keep
        yield
        return
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            if os.sched_getscheduler(0) != policy or os.sched_getparam(0) != param:
                os.sched_setscheduler(0, policy, param)


def packet(data: bytes) -> av.Packet:
    """A packet whose buffer FFmpeg owns (a copy of ``data``, zero-padded as FFmpeg's decoders
    require). ``av.Packet(bytes)`` would lend FFmpeg the Python object (unpadded), and a dav1d
    worker thread releasing it needs the GIL: when a decoder is dropped mid-stream (a standalone
    encode stopped because the joint one won), its deallocation holds the GIL while it waits for
    those workers, and the ingest hangs (seen: ``avcodec_free_context`` → ``dav1d_flush`` against
    a worker in ``_python_free``)."""
    pkt = av.Packet(len(data))
    pkt.update(data)
    return pkt


class _Dav1d:
    """A dav1d decoder giving padded I420 pictures in order."""

    def __init__(self) -> None:
        self.cc = av.CodecContext.create(DECODER, "r")

    def decode(self, pkt: bytes | None) -> list[np.ndarray]:
        try:
            frames = self.cc.decode(packet(pkt) if pkt is not None else None)
        except av.error.FFmpegError as exc:
            raise EgovidError(f"dav1d could not decode an AV1 segment: {exc}", "the bitstream is damaged") from None
        return [np.ascontiguousarray(f.to_ndarray(format="yuv420p")) for f in frames]


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
    """Encode unpadded I420 frames with SVT-AV1 (standalone: ``baselines`` must give none).

    The same contract as :func:`egovid.dashcam.codec.segment.encode_segment`: the digests, PSNR-Y,
    ``keep_recon`` and ``progress`` are of dav1d's pictures of the packets, in display order;
    ``verify`` and ``verify_runs`` change nothing (the pictures are always the decoder's); ``on_run``
    as there.
    ``clock['encode']`` / ``clock['verify']`` accumulate the encoder's and the decoder's seconds."""
    del verify, verify_runs  # every picture is a decoder's already
    clock = clock if clock is not None else {}
    pw, ph = vpx.padded_size(width, height)
    out = segment.SegmentWriter(
        width, height, settings.refresh, spool=spool, keep_recon=keep_recon, progress=progress, on_run=on_run
    )
    enc, dec = _encoder(pw, ph, settings), _Dav1d()
    sources: dict[int, np.ndarray] = {}
    state = {"coded": 0, "shown": 0}

    def take(packets: Iterable[av.Packet]) -> None:
        for p in packets:
            k = state["coded"]
            if (settings.refresh and k % settings.refresh == 0) or k == 0:
                if not p.is_keyframe:
                    raise segment.EncoderFaultError(
                        f"SVT-AV1 did not start the random-access run at frame {k} with a keyframe",
                        "run the ingest again; if it recurs, pass --codec vp9",
                    )
                out.begin_run(segment.START_KEY)
            data = bytes(p)
            out.emit(data, k)
            state["coded"] += 1
            t0 = time.perf_counter()
            pics = dec.decode(data)
            clock["verify"] = clock.get("verify", 0.0) + time.perf_counter() - t0
            show(pics)

    def show(pics: list[np.ndarray]) -> None:
        for pic in pics:
            k = state["shown"]
            out.picture(k, sources.pop(k), vpx.crop_i420(pic, width, height))
            state["shown"] += 1

    try:
        for k, frame in enumerate(frames):
            if baselines is not None and baselines(k) is not None:
                raise ValueError("the AV1 backend codes no frame against a baseline")
            sources[k] = frame
            vf = av.VideoFrame.from_ndarray(vpx.pad_i420(frame, pw, ph), format="yuv420p")
            vf.pts = k
            if settings.refresh and k % settings.refresh == 0:
                vf.pict_type = av.video.frame.PictureType.I
            t0 = time.perf_counter()
            packets = enc.encode(vf)
            clock["encode"] = clock.get("encode", 0.0) + time.perf_counter() - t0
            take(packets)
        t0 = time.perf_counter()
        packets = enc.encode(None) if sources or state["coded"] else []
        clock["encode"] = clock.get("encode", 0.0) + time.perf_counter() - t0
        take(packets)
        show(dec.decode(None))
    except BaseException:
        out.close()
        # An SVT-AV1 context freed with frames in flight and no end of stream can block for ever
        # in svt_av1_enc_deinit holding the GIL (the exception's traceback keeps it alive until
        # some later collection, in any thread): end its stream here, in this thread, first.
        with contextlib.suppress(Exception):
            if state["coded"] or sources:
                enc.encode(None)
        raise
    if state["shown"] != state["coded"]:
        out.close()
        raise EgovidError(f"dav1d gave {state['shown']} pictures for {state['coded']} AV1 packets")
    return out.result(settings.q, 1, "av1")


def decode_runs(
    lay: segment.SegmentLayout,
    packets: Iterable[bytes],
    first_run: int,
    baselines: Callable[[int], np.ndarray | None] | None = None,
    start: int = 0,
) -> Iterator[np.ndarray]:
    """Frames from ``start`` (display order) of an AV1 segment, given its packets from the first
    packet of run ``first_run`` on (which must hold ``start`` or come before it)."""
    del baselines  # an AV1 segment refers to no other drive
    k = lay.run_packets()[first_run][0]  # one packet per frame
    if k > segment.period_start(lay.refresh, start):
        raise ValueError("decoding must start at or before the run holding the first frame asked for")
    skip = segment.period_start(lay.refresh, start)
    dec = _Dav1d()
    shown = k
    for pkt in packets:
        if k < skip:
            k += 1
            shown += 1
            continue
        k += 1
        for pic in dec.decode(pkt):
            if shown >= start:
                yield vpx.crop_i420(pic, lay.width, lay.height)
            shown += 1
    for pic in dec.decode(None):
        if shown >= start:
            yield vpx.crop_i420(pic, lay.width, lay.height)
        shown += 1


@functools.cache
def self_test() -> str:
    """Encode a small clip, decode it from its second random-access run and from the start: the
    pictures must agree with the digests taken at encoding. Returns a one-line description."""
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (96 * 3 // 2 + 8, 128 + 16), dtype=np.uint8)
    frames = [np.ascontiguousarray(base[k % 3 : k % 3 + 96 * 3 // 2, k : k + 128]) for k in range(8)]
    st = EncoderSettings(q=40, speed=12, codec="av1", refresh=4)
    rec: list[np.ndarray] = []
    try:
        blob = encode_segment(iter(frames), 128, 96, st, keep_recon=rec).blob
        lay, off = segment.parse_header(blob)
        whole = list(decode_runs(lay, segment.iter_packets(blob, off, lay.n_packets), 0))
        later = list(decode_runs(lay, segment.iter_packets(blob, off, lay.n_packets), 0, start=5))
    except EgovidError:
        raise
    except Exception as exc:  # pragma: no cover - a broken FFmpeg build
        raise EgovidError(
            f"SVT-AV1/dav1d (PyAV {av.__version__}) failed the self-test: {exc}", "reinstall PyAV"
        ) from None
    ok = len(whole) == 8 and all(np.array_equal(a, b) for a, b in zip(whole, rec, strict=True))
    ok = ok and all(np.array_equal(a, b) for a, b in zip(later, rec[5:], strict=True)) and len(later) == 3
    if not ok:
        raise EgovidError("SVT-AV1/dav1d failed the round-trip self-test", "reinstall PyAV")
    return f"SVT-AV1 + dav1d (PyAV {av.__version__}, FFmpeg {av.library_versions['libavcodec']})"
