"""Segment bitstreams: the container every codec backend writes (header, random-access run
layout, length-prefixed packets; the magic names the codec: ``EGV9`` VP9, ``EGA1`` AV1
(SVT-AV1), ``EGAM`` AV1 joint (libaom), see :mod:`egovid.dashcam.codec.registry`), the writer
they share (:class:`SegmentWriter`: digests, PSNR, spool), and the VP9 backend: VP9 with the
older drive's aligned frames as a free reference (§14.2). The AV1 backends are
:mod:`egovid.dashcam.codec.av1` and :mod:`egovid.dashcam.codec.aom_segment`.

A *segment* is a run of a drive's frames coded as one VP9 stream: **intra** (a root, a plain VP9
stream) or **joint** (every frame after the keyframe may also predict from the *baseline*: the
older drive's frame aligned to it, injected into GOLDEN on both sides; see
:mod:`egovid.dashcam.codec.vpx`). The baseline is never stored: the decoder rebuilds it from the archive,
so it must be bit-identical on both sides — it is built only from decoded reference frames
(never from the source video) with integer or fixed-point operations and stored parameters.

Optional global alignment of the baseline (measured in ``benchmarks/dashcam_bdrate.py``):
``gain`` (luma ``a·Y + b``, a and b in 1/64 steps) and ``similarity`` (a 4-parameter warp of all
planes, fixed-point). The blob format is ``EGV9`` + header + length-prefixed packets in coding
order (version 1: low delay only; version 2 adds the GOP length in the last header byte; version 3
the random-access layout).

**Coding structure.** With ``gop`` = 1 every frame predicts from the one before (low delay). The
thesis coded HEVC hierarchical B pictures and its per-picture savings (Fig. 16.2) fall from 48 % for
P pictures, 8 frames from their temporal reference, to 6 % for B1 pictures: the older drive helps
most where the temporal reference is far. With ``gop`` = G > 1 (the archive's default, G = 8) the
frames are coded out of order, as :func:`coding_plan` lists: frame 0 is the keyframe, frame 1 a P
frame, then every G-th frame an *anchor* predicted from the anchor before it (LAST) and the
baseline (GOLDEN), and the frames between from the previous frame (LAST), the anchor ahead
(ALTREF) and their baseline (GOLDEN), at quantiser ``q + gop_dq``. Only libvpx's public reference
controls are used, so the decoder repeats the same loads, and the buffers are arranged so that no
load overwrites another slot (libvpx copies into whatever buffer a slot points to, and after the
keyframe every slot points to the same one): GOLDEN is never refreshed, anchors refresh only ALTREF,
the other frames only LAST. The encoder holds G frames (look-ahead), the decoder G + 1.

**Random access.** A segment is coded in independently decodable *runs* of ``refresh`` frames
(:func:`substreams`; 0 = one run). A run of an intra segment starts with a keyframe. A run of a
joint segment starts like the thesis' dependent view at an intra period (its "P" pictures, Fig.
16.2, which save the most): its first frame (``ra``) is predicted from its baseline alone, after a
grey keyframe that is decoded but never shown (VP9 decoders need a keyframe to start; the grey one
costs a few bytes). Decoding can begin at any run, so seeking needs neither this drive's earlier
frames nor the older drive's. Blob format version 3 stores the period and how each run starts.
"""

from __future__ import annotations

import hashlib
import itertools
import struct
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.metrics.psnr import psnr_db
from egovid.dashcam.codec import vpx
from egovid.dashcam.codec.settings import EncoderSettings


class EncoderFaultError(EgovidError):
    """An encoder misbehaved (stopped responding, or broke the stream's structure): not the
    input's fault; coding the piece again in a fresh encoder is expected to work
    (:mod:`egovid.dashcam.ingest.watchdog`)."""


#: Blob magic per codec (the layout after it is the same: header, run layout, packets).
MAGICS = {"vp9": b"EGV9", "av1": b"EGA1", "aom": b"EGAM"}
MAGIC = MAGICS["vp9"]
VERSION = 3
VERSION_HELD = 4  # version 3 with runs that start with START_BASELINE_HELD
_HEADER = struct.Struct("<4sHHHHHIBB")
_LAYOUT = struct.Struct("<HI")  # version 3: random-access period, number of runs; then a start byte per run
START_KEY, START_BASELINE, START_BASELINE_HELD = 0, 1, 2
#: Undisplayed packets before a run's first frame, by how the run starts: a grey keyframe for
#: START_BASELINE; a grey keyframe and a grey frame that refreshes no reference for
#: START_BASELINE_HELD (blob version 4), which the realtime deadline needs: libvpx's realtime mode
#: decision (vp9_pickmode.c) never searches GOLDEN on a frame right after GOLDEN was refreshed
#: (``rc.frames_since_golden == 0``, as after every keyframe), so without it the run's first frame
#: could not use the injected baseline and came out intra-coded.
DUMMIES = {START_KEY: 0, START_BASELINE: 1, START_BASELINE_HELD: 2}
_KEY_OR_BASELINE = (START_KEY, START_BASELINE)
#: The blobs a codec writes, by header version: the run starts each may hold (a version not listed
#: is refused). VP9: every version (1-2 without a run layout, 4 with held baselines); AV1
#: (SVT-AV1): version 3, keyframe runs only; libaom: version 3 with keyframe runs, 4 with joint ones.
RUN_STARTS = {
    "vp9": {1: _KEY_OR_BASELINE, 2: _KEY_OR_BASELINE, 3: _KEY_OR_BASELINE, 4: (*_KEY_OR_BASELINE, START_BASELINE_HELD)},
    "av1": {3: (START_KEY,)},
    "aom": {3: (START_KEY,), 4: (START_KEY, START_BASELINE_HELD)},
}


@dataclass
class EncodedSegment:
    """Packets of a segment plus what the encoder saw. ``blob`` is the whole segment blob, unless
    the packets went to a ``spool`` file as they came (then ``blob`` is empty and :meth:`chunks`
    gives the blob's bytes: the header, then the spool)."""

    blob: bytes
    frames: int
    recon_digest: str
    psnr_y: float
    bytes_per_frame: list[int] = field(default_factory=list)
    # SHA-256 (first RUN_DIGEST_CHARS hex digits) of each random-access run's pictures; none
    # when the segment is one run (recon_digest covers it)
    run_digests: list[str] = field(default_factory=list)
    header: bytes = b""
    nbytes: int = 0  # size of the blob
    run_offsets: list[int] = field(default_factory=list)  # see run_offsets()
    spool: object = None

    def chunks(self, size: int = 1 << 20) -> Iterator[bytes]:
        """The blob's bytes, in pieces of at most ``size``."""
        if self.spool is None:
            yield self.blob
            return
        yield self.header
        self.spool.seek(0)
        while block := self.spool.read(size):
            yield block


@dataclass(frozen=True)
class SegmentLayout:
    """What a segment blob's header says: frame size, quantiser, coding structure, how each
    random-access run starts (see :class:`SegmentBlob`) and the number of packets."""

    width: int
    height: int
    q: int
    gop: int
    refresh: int
    starts: tuple[int, ...]
    n_packets: int
    codec: str = "vp9"

    @property
    def frames(self) -> int:
        return self.n_packets - sum(DUMMIES[s] for s in self.starts)

    def plan(self) -> list[tuple[int, str, int | None]]:
        return coding_plan(self.frames, self.gop, self.refresh, self.starts)

    def run_packets(self) -> list[tuple[int, int]]:
        """(first packet, end packet) of every random-access run, in coding order."""
        plan = self.plan()  # a run starts at its keyframe or at its first undisplayed frame
        firsts = [
            i for i, (_, role, _) in enumerate(plan) if role == "key" or (role == "dummy" and plan[i - 1][1] != "dummy")
        ]
        return list(itertools.pairwise([*firsts, self.n_packets]))


@dataclass(frozen=True)
class SegmentBlob:
    """A parsed segment blob. ``starts``: how each independently decodable run begins
    (:data:`START_KEY`: a keyframe; :data:`START_BASELINE`: an undisplayed grey keyframe, then the
    first frame predicted from its baseline alone). ``packets`` are in coding order."""

    width: int
    height: int
    q: int
    gop: int
    refresh: int
    starts: tuple[int, ...]
    packets: list[bytes]
    codec: str = "vp9"

    @property
    def frames(self) -> int:
        return len(self.packets) - sum(DUMMIES[s] for s in self.starts)

    def plan(self) -> list[tuple[int, str, int | None]]:
        return coding_plan(self.frames, self.gop, self.refresh, self.starts)


def pack(
    width: int,
    height: int,
    q: int,
    packets: list[bytes],
    gop: int = 1,
    refresh: int = 0,
    starts: tuple[int, ...] | list[int] = (START_KEY,),
    codec: str = "vp9",
) -> bytes:
    """A segment blob: header + run layout + length-prefixed packets (in coding order)."""
    head = pack_header(width, height, q, len(packets), gop, refresh, starts, codec)
    return head + b"".join(map(frame_packet, packets))


def pack_header(
    width: int,
    height: int,
    q: int,
    n_packets: int,
    gop: int,
    refresh: int,
    starts: tuple[int, ...] | list[int],
    codec: str = "vp9",
) -> bytes:
    """The header and run layout of a segment blob of ``n_packets`` packets coded with ``codec``."""
    pw, ph = vpx.padded_size(width, height)
    version = VERSION_HELD if START_BASELINE_HELD in starts else VERSION
    head = _HEADER.pack(MAGICS[codec], version, width, height, pw, ph, n_packets, q, gop)
    return head + _LAYOUT.pack(refresh, len(starts)) + bytes(starts)


def frame_packet(packet: bytes) -> bytes:
    """A packet as the blob stores it (length-prefixed)."""
    return struct.pack("<I", len(packet)) + packet


def _damaged(what: str = "is truncated") -> EgovidError:
    return EgovidError(f"segment blob {what}", "the archive is damaged; restore it from a backup")


def parse_header(buf: bytes) -> tuple[SegmentLayout, int]:
    """The layout of a segment blob from its first bytes (the header and run layout, versions 1-3)
    and the byte offset of its first packet; raises :class:`EgovidError` on damage."""
    if len(buf) < _HEADER.size:
        raise _damaged()
    magic, version, w, h, _pw, _ph, n, q, gop = _HEADER.unpack_from(buf, 0)
    codec = next((name for name, m in MAGICS.items() if m == magic), None)
    allowed = RUN_STARTS.get(codec, {}).get(version)
    if allowed is None or (version == 1 and gop != 0) or (version > 1 and gop < 1):
        raise EgovidError("segment blob has an unknown format", "the archive is damaged or from another version")
    gop = max(gop, 1)
    off = _HEADER.size
    refresh, starts = 0, (START_KEY,)
    if version >= 3:
        if off + _LAYOUT.size > len(buf):
            raise _damaged()
        refresh, runs = _LAYOUT.unpack_from(buf, off)
        off += _LAYOUT.size
        if off + runs > len(buf):
            raise _damaged()
        starts = tuple(buf[off : off + runs])
        off += runs
    lay = SegmentLayout(w, h, q, gop, refresh, starts, n, codec)
    if any(s not in allowed for s in starts) or len(starts) != len(substreams(lay.frames, refresh)):
        raise _damaged("has an inconsistent layout")
    return lay, off


def iter_packets(buf: bytes, off: int, count: int) -> Iterator[bytes]:
    """``count`` length-prefixed packets of ``buf`` from byte ``off``."""
    for _ in range(count):
        if off + 4 > len(buf):
            raise _damaged()
        (size,) = struct.unpack_from("<I", buf, off)
        if off + 4 + size > len(buf):
            raise _damaged()
        yield buf[off + 4 : off + 4 + size]
        off += 4 + size


def parse(blob: bytes) -> SegmentBlob:
    """The parsed segment blob (versions 1-3); raises :class:`EgovidError` on damage."""
    lay, off = parse_header(blob)
    packets = list(iter_packets(blob, off, lay.n_packets))
    if off + sum(4 + len(p) for p in packets) != len(blob):
        raise _damaged("has trailing data")
    return SegmentBlob(lay.width, lay.height, lay.q, lay.gop, lay.refresh, lay.starts, packets, lay.codec)


def run_offsets(blob: bytes) -> list[int]:
    """Byte offset of the first packet of every random-access run, then the blob's length: what
    a reader needs to fetch runs ``i`` … ``j − 1`` as one byte range (``[off[i], off[j])``, after the
    header ``[0, off[0])``)."""
    lay, off = parse_header(blob)
    firsts = {p0 for p0, _ in lay.run_packets()}
    out = []
    for i in range(lay.n_packets):
        if i in firsts:
            out.append(off)
        (size,) = struct.unpack_from("<I", blob, off)
        off += 4 + size
    return [*out, off]


def substreams(n: int, refresh: int) -> list[tuple[int, int]]:
    """(first frame, frame count) of the independently decodable runs of an ``n``-frame segment:
    one per ``refresh`` frames (0: a single run). Decoding may start at any run."""
    if n <= 0:
        return []
    r = refresh if refresh > 0 else n
    return [(k0, min(r, n - k0)) for k0 in range(0, n, r)]


def coding_plan(
    n: int, gop: int, refresh: int = 0, starts: tuple[int, ...] | list[int] | None = None
) -> list[tuple[int, str, int | None]]:
    """Coding order of an ``n``-frame segment: (frame, role, frame LAST must hold or None).

    Per run (:func:`substreams`) of m frames from k0: its start — ``key`` k0, or (``starts[i]`` =
    :data:`START_BASELINE`) an undisplayed grey keyframe ``dummy`` k0 and then ``ra`` k0, the frame
    predicted from its baseline alone — then, with ``gop`` = 1, ``p`` frames (low delay); for G > 1
    ``p`` k0 + 1 and per chunk a = k0 + 1, k0 + 1 + G, ...: the anchor b = min(a + G, k0 + m − 1)
    (LAST loaded with frame a), then a + 1 … b − 1 as ``between`` frames (LAST already holds the
    previous frame)."""
    plan: list[tuple[int, str, int | None]] = []
    for i, (k0, m) in enumerate(substreams(n, refresh)):
        if starts is not None and starts[i] != START_KEY:
            plan += [(k0, "dummy", None)] * DUMMIES[starts[i]] + [(k0, "ra", None)]
        else:
            plan.append((k0, "key", None))
        if gop <= 1:
            plan += [(k, "p", None) for k in range(k0 + 1, k0 + m)]
            continue
        if m > 1:
            plan.append((k0 + 1, "p", None))
        a, end = k0 + 1, k0 + m - 1
        while a < end:
            b = min(a + gop, end)
            plan.extend(_chunk_plan(a, b))
            a = b
    return plan


def _chunk_plan(a: int, b: int) -> list[tuple[int, str, int | None]]:
    """One chunk after anchor ``a``: the anchor ``b`` (LAST loaded with frame a), then a+1 … b−1."""
    return [(b, "anchor", a)] + [(j, "between", None) for j in range(a + 1, b)]


def run_start(blob: bytes, k: int) -> int:
    """The first frame of the run holding frame ``k``: where decoding towards ``k`` begins (reads
    only the blob's header)."""
    if len(blob) < _HEADER.size + _LAYOUT.size or _HEADER.unpack_from(blob, 0)[1] < 3:
        return 0
    return period_start(_LAYOUT.unpack_from(blob, _HEADER.size)[0], k)


def period_start(refresh: int, k: int) -> int:
    """The first frame of the random-access run of period ``refresh`` (0: one run) holding frame ``k``."""
    return k - k % refresh if refresh > 0 else 0


# -- baselines ----------------------------------------------------------------------------------


def apply_alignment(frame: np.ndarray, width: int, height: int, kind: str, params: list[int] | None) -> np.ndarray:
    """The baseline built from a decoded reference frame (padded I420), bit-exact on both sides."""
    if kind == "none" or params is None:
        return frame
    pw, ph = frame.shape[1], frame.shape[0] * 2 // 3
    y, u, v = vpx.split_i420(frame, pw, ph)
    if kind == "gain":
        a, b = int(params[0]), int(params[1])
        y2 = np.clip((y.astype(np.int32) * a + b + 32) >> 6, 0, 255).astype(np.uint8)
        return vpx.join_i420(y2, u, v)
    if kind == "similarity":
        m = np.array(params[:6], dtype=np.float64).reshape(2, 3) / 4096.0
        yw = cv2.warpAffine(y, m, (pw, ph), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        mc = m.copy()
        mc[:, 2] = (m[:, 2] + m[:, 0] * 0.5 + m[:, 1] * 0.5 - 0.5) / 2.0  # chroma: half resolution, centred
        uw = cv2.warpAffine(u, mc, (pw // 2, ph // 2), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        vw = cv2.warpAffine(v, mc, (pw // 2, ph // 2), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return vpx.join_i420(yw, uw, vw)
    raise EgovidError(f"unknown baseline alignment {kind!r}")


def estimate_gain(new_y: np.ndarray, ref_y: np.ndarray) -> list[int]:
    """Least-squares luma gain/offset mapping the reference onto the new frame, in 1/64 steps."""
    a = ref_y.astype(np.float64).ravel()[::7]
    b = new_y.astype(np.float64).ravel()[::7]
    va = a.var()
    g = float(np.cov(a, b)[0, 1] / va) if va > 1e-6 else 1.0
    g = float(np.clip(g, 0.5, 2.0))
    off = float(b.mean() - g * a.mean())
    return [round(g * 64), round(off * 64)]


def estimate_similarity(pts_new: np.ndarray, pts_ref: np.ndarray, scale: float) -> list[int] | None:
    """Fixed-point 2x3 similarity (reference → new) from matched points found at ``scale`` of
    full resolution; None when it cannot be estimated."""
    if len(pts_new) < 12:
        return None
    m, inl = cv2.estimateAffinePartial2D(pts_ref, pts_new, method=cv2.RANSAC, ransacReprojThreshold=2.0)
    if m is None or inl is None or inl.sum() < 10:
        return None
    m = m.copy()
    m[:, 2] /= scale
    return [round(v * 4096) for v in m.ravel()]


# -- encode / decode ----------------------------------------------------------------------------


def digest_update(h, frame: np.ndarray) -> None:
    h.update(np.ascontiguousarray(frame))  # the array's own buffer: no copy


class _Digests:
    """The segment digest and the per-run digests of the encoder's pictures, hashed in a thread
    of their own, in order (SHA-256 releases the GIL: the encoder's thread does not wait for it;
    at most a few frames queue)."""

    def __init__(self, refresh: int) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.refresh = refresh
        self.h, self.run_h = hashlib.sha256(), hashlib.sha256()
        self.runs: list[str] = []
        self.n = 0
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="egovid-digest")
        self.queued: list = []

    def _add(self, rec: np.ndarray) -> None:
        digest_update(self.h, rec)
        self.n += 1
        if self.refresh:
            digest_update(self.run_h, rec)
            if self.n % self.refresh == 0:
                self.runs.append(self.run_h.hexdigest()[:RUN_DIGEST_CHARS])
                self.run_h = hashlib.sha256()

    def add(self, rec: np.ndarray) -> None:
        for f in self.queued:
            if f.done():
                f.result()  # a hash that failed fails the segment here, not silently
        self.queued = [f for f in self.queued if not f.done()]
        while len(self.queued) > 4:
            self.queued.pop(0).result()
        self.queued.append(self.pool.submit(self._add, rec))

    def result(self) -> tuple[str, list[str]]:
        """(segment digest, run digests; none for a single run) once every picture is hashed."""
        self.pool.shutdown(wait=True)
        for f in self.queued:
            f.result()
        if self.refresh and self.n % self.refresh:
            self.runs.append(self.run_h.hexdigest()[:RUN_DIGEST_CHARS])
        return self.h.hexdigest(), self.runs

    def close(self) -> None:
        self.pool.shutdown(wait=False, cancel_futures=True)


RUN_DIGEST_CHARS = 16  # 64 bits of SHA-256 per run: ample to catch damage, 16 bytes per 24 frames


class SegmentWriter:
    """What every codec backend does with its packets and pictures, whatever its coding order:
    the blob (packets length-prefixed, to memory or a ``spool`` file as they come), each run's
    first byte, per-frame sizes, and in display order the digests, the PSNR-Y against the source,
    ``keep_recon`` and ``progress``. :meth:`result` packs it as an :class:`EncodedSegment`."""

    def __init__(
        self, width: int, height: int, refresh: int, *, spool=None, keep_recon=None, progress=None, on_run=None
    ) -> None:
        self.width, self.height, self.refresh = width, height, refresh
        self.spool, self.keep_recon, self.progress, self.on_run = spool, keep_recon, progress, on_run
        self.shown_bytes = 0
        self.packets: list[bytes] = []
        self.n_packets = self.n_bytes = 0
        self.run_body: list[int] = []  # offset of each run's first packet after the header
        self.starts: list[int] = []
        self.size_of: dict[int, int] = {}
        self.pending: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.digests = _Digests(refresh)
        self.se, self.pix, self.next = 0.0, 0, 0

    def begin_run(self, start: int) -> None:
        """A random-access run begins here, started as ``start`` (:data:`START_KEY`, ...)."""
        self.run_body.append(self.n_bytes)
        self.starts.append(start)

    def emit(self, pkt: bytes, k: int) -> None:
        """Packet ``pkt`` (coding order), whose bytes count towards frame ``k``."""
        if self.spool is not None:
            self.spool.write(frame_packet(pkt))
        else:
            self.packets.append(pkt)
        self.n_packets += 1
        self.n_bytes += 4 + len(pkt)
        self.size_of[k] = self.size_of.get(k, 0) + len(pkt)

    def picture(self, k: int, source: np.ndarray, rec: np.ndarray) -> None:
        """Frame ``k``'s source and its reconstruction (both unpadded I420), in any order."""
        self.pending[k] = (source, rec)
        while self.next in self.pending:
            src, r = self.pending.pop(self.next)
            self.digests.add(r)
            self.se += float(cv2.norm(r[: self.height], src[: self.height], cv2.NORM_L2SQR))
            self.pix += self.height * self.width
            self.shown_bytes += self.size_of[self.next]
            if self.keep_recon is not None:
                self.keep_recon.append(r)
            self.next += 1
            if self.progress is not None:
                self.progress(self.next)
            if self.on_run is not None and self.refresh and self.next % self.refresh == 0:
                self.on_run(self.next, self.shown_bytes, self.se / self.pix)

    def close(self) -> None:
        self.digests.close()

    def result(self, q: int, gop: int, codec: str) -> EncodedSegment:
        if not self.n_packets or self.pending:
            self.digests.close()
            raise EgovidError("a segment with no frames cannot be encoded")
        recon_digest, run_digests = self.digests.result()
        psnr = psnr_db(self.se / max(self.pix, 1))
        sizes = [self.size_of[k] for k in range(self.next)]
        header = pack_header(self.width, self.height, q, self.n_packets, gop, self.refresh, self.starts, codec)
        blob = b"" if self.spool is not None else header + b"".join(map(frame_packet, self.packets))
        offsets = [len(header) + o for o in self.run_body] + [len(header) + self.n_bytes]
        return EncodedSegment(
            blob, self.next, recon_digest, psnr, sizes, run_digests, header, offsets[-1], offsets, self.spool
        )


class _VP9Coder:
    """libvpx's encoder (and the verifying decoder, when it follows) for one segment."""

    def __init__(self, width, height, settings, out: SegmentWriter, verify, verify_runs, clock) -> None:
        self.w, self.h, self.settings, self.out, self.clock = width, height, settings, out, clock
        self.pw, self.ph = vpx.padded_size(width, height)
        self.enc = vpx.VP9Encoder(self.pw, self.ph, settings)
        self.dec = vpx.VP9Decoder(self.pw, self.ph, threads=settings.threads) if verify else None
        self.verify_runs = verify_runs
        self.follow = False  # the decoder follows the current run
        self.q_between = min(63, settings.q + settings.gop_dq)
        self.grey = np.full((self.ph * 3 // 2, self.pw), 128, np.uint8)

    def code(self, frame, role, golden=None, last=None, q=None) -> tuple[bytes, np.ndarray | None]:
        t0 = time.perf_counter()
        pkt = self.enc.encode_structured(frame, role, golden, last, q)
        rec = self.enc.reconstruction() if role != "hold" else None  # a hold frame's picture is in no slot
        t1 = time.perf_counter()
        self.clock["encode"] = self.clock.get("encode", 0.0) + t1 - t0
        if self.follow:
            out = self.dec.decode(pkt, golden, last)
            if rec is not None and not np.array_equal(out, rec):
                raise EgovidError(
                    "the decoder does not reproduce the encoder's pictures",
                    "report this with the libvpx version (egovid dashcam report shows it); nothing was stored",
                )
            self.clock["verify"] = self.clock.get("verify", 0.0) + time.perf_counter() - t1
        return pkt, rec

    def finish(self, k: int, frame: np.ndarray, role: str, golden=None, last=None, q=None) -> np.ndarray:
        """Code frame ``k`` (unpadded) and hand packet and picture to the writer; returns the padded
        reconstruction (what LAST must hold for a later anchor)."""
        pkt, rec = self.code(vpx.pad_i420(frame, self.pw, self.ph), role, golden, last, q)
        self.out.emit(pkt, k)
        self.out.picture(k, frame, vpx.crop_i420(rec, self.w, self.h))
        return rec

    def start_run(self, k0: int, first: np.ndarray, b0: np.ndarray | None) -> None:
        """The run's first frame: a keyframe, or (with a baseline) predicted from it alone after the
        undisplayed grey frames (:data:`DUMMIES`)."""
        self.follow = self.dec is not None and (self.verify_runs is None or self.verify_runs(len(self.out.starts)))
        if b0 is None:
            self.out.begin_run(START_KEY)
            self.finish(k0, first, "key")
            return
        start = START_BASELINE_HELD if self.settings.realtime else START_BASELINE
        self.out.begin_run(start)
        for role in ("key", "hold")[: DUMMIES[start]]:
            self.out.emit(self.code(self.grey, role)[0], k0)
        self.finish(k0, first, "ra", b0)

    def rest_of_run(self, k0: int, run: Iterator[np.ndarray], base: Callable[[int], np.ndarray | None]) -> int:
        """Code the run's frames after its first (low delay, or anchors and the frames between them
        in :func:`coding_plan`'s order); returns the run's length."""
        gop = self.settings.gop
        if gop <= 1:
            n = 1
            for n, frame in enumerate(run, 2):
                self.finish(k0 + n - 1, frame, "p", base(k0 + n - 1))
            return n
        second = next(run, None)
        if second is None:
            return 1
        a = k0 + 1
        a_rec = self.finish(a, second, "p")
        n = 2
        while chunk := list(itertools.islice(run, gop)):  # frames a+1 … b
            b = a + len(chunk)
            b_rec = self.finish(b, chunk[-1], "anchor", base(b), a_rec)
            for j in range(a + 1, b):
                self.finish(j, chunk[j - a - 1], "between", base(j), q=self.q_between)
            a, a_rec = b, b_rec
            n += len(chunk)
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
) -> EncodedSegment:
    """VP9: encode unpadded I420 frames; ``baselines(k)`` gives frame k's padded baseline (or None).

    Frames are read as a stream (``settings.gop`` of them ahead), in runs of ``settings.refresh``
    frames (:func:`substreams`); a run whose first frame has a baseline starts from it (``ra``)
    instead of a keyframe. The digest, PSNR, per-frame sizes, ``keep_recon`` and ``progress``
    follow display order whatever the coding order. ``verify``: a decoder follows the encoder
    packet by packet with the same reference loads, and every picture it gives must be the
    encoder's reconstruction (else :class:`EgovidError`, before anything is stored);
    ``verify_runs(i)``: whether it follows random-access run i (default: every run; a run begins
    with a keyframe, so the decoder can skip runs). ``clock['encode']`` / ``clock['verify']``
    accumulate seconds. ``spool``: a binary file the packets are written to as they come (memory
    stays flat however long the segment). ``on_run(frames, bytes, mse)``: called whenever the first
    ``frames`` (a whole number of random-access runs) are coded, with their bytes and mean squared
    error (what an early choice between encodes compares)."""
    vpx.self_test()
    out = SegmentWriter(
        width, height, settings.refresh, spool=spool, keep_recon=keep_recon, progress=progress, on_run=on_run
    )
    coder = _VP9Coder(width, height, settings, out, verify, verify_runs, clock if clock is not None else {})

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
    return out.result(settings.q, settings.gop, "vp9")


def decode_segment(
    blob: bytes, baselines: Callable[[int], np.ndarray | None] | None = None, start: int = 0
) -> Iterator[np.ndarray]:
    """VP9: yield the unpadded I420 frames of a segment in display order from frame ``start``. Decoding
    begins at the run holding ``start`` (:func:`run_start`); frames of that run before ``start`` are
    decoded but not yielded."""
    lay, off = parse_header(blob)
    return decode_runs(lay, iter_packets(blob, off, lay.n_packets), 0, baselines, start)


def decode_runs(
    lay: SegmentLayout,
    packets: Iterable[bytes],
    first_run: int,
    baselines: Callable[[int], np.ndarray | None] | None = None,
    start: int = 0,
) -> Iterator[np.ndarray]:
    """Frames from ``start`` (display order), given the packets of the segment from the first
    packet of run ``first_run`` on (which must hold ``start`` or come before it): the part of a
    blob an extract of a stretch reads by byte range. VP9 segments only (any codec:
    :func:`egovid.dashcam.codec.registry.decode_runs`)."""
    if lay.codec != "vp9":
        raise ValueError(f"a {lay.codec} segment is not decoded by libvpx")
    vpx.self_test()
    w, h, gop = lay.width, lay.height, lay.gop
    plan = lay.plan()
    p0 = lay.run_packets()[first_run][0]
    skip = period_start(lay.refresh, start)
    if plan[p0][0] > skip:
        raise ValueError("decoding must start at or before the run holding the first frame asked for")
    pw, ph = vpx.padded_size(w, h)
    dec = vpx.VP9Decoder(pw, ph)
    pending: dict[int, np.ndarray] = {}
    held: dict[int, np.ndarray] = {}
    nxt = skip
    try:
        for (k, role, last_k), pkt in zip(plan[p0:], packets, strict=False):
            if k < skip:
                continue
            if role in ("key", "dummy", "ra"):  # a run start: no frame held before it is referred to again
                held.clear()
            if role == "dummy":
                dec.decode(pkt)
                continue
            injected = baselines is not None and (role in ("ra", "anchor", "between") or (role == "p" and gop <= 1))
            golden = baselines(k) if injected else None
            last = held.pop(last_k) if last_k is not None else None
            out = dec.decode(pkt, golden, last)
            if gop > 1 and role in ("p", "anchor"):
                held[k] = out
            pending[k] = vpx.crop_i420(out, w, h)
            while nxt in pending:
                frame = pending.pop(nxt)
                if nxt >= start:
                    yield frame
                nxt += 1
    finally:
        dec.close()
