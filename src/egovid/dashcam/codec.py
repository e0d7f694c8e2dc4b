"""Segment bitstreams: VP9 with the older drive's aligned frames as a free reference (§14.2).

A *segment* is a run of a drive's frames coded as one VP9 stream: **intra** (a root, a plain VP9
stream) or **joint** (every frame after the keyframe may also predict from the *baseline*: the
older drive's frame aligned to it, injected into GOLDEN on both sides; see
:mod:`egovid.dashcam.vpx`). The baseline is never stored: the decoder rebuilds it from the archive,
so it must be bit-identical on both sides — it is built only from decoded reference frames
(never from the source video) with integer or fixed-point operations and stored parameters.

Optional global alignment of the baseline (measured in ``benchmarks/dashcam_bdrate.py``):
``gain`` (luma ``a·Y + b``, a and b in 1/64 steps) and ``similarity`` (a 4-parameter warp of all
planes, fixed-point). The blob format is ``EGV9`` + header + length-prefixed packets.
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from egovid.dashcam import vpx
from egovid.errors import EgovidError

MAGIC = b"EGV9"
VERSION = 1
_HEADER = struct.Struct("<4sHHHHHIBB")


@dataclass
class EncodedSegment:
    """Packets of a segment plus what the encoder saw."""

    blob: bytes
    frames: int
    recon_digest: str
    psnr_y: float
    bytes_per_frame: list[int] = field(default_factory=list)


def pack(width: int, height: int, q: int, packets: list[bytes]) -> bytes:
    pw, ph = vpx.padded_size(width, height)
    head = _HEADER.pack(MAGIC, VERSION, width, height, pw, ph, len(packets), q, 0)
    return head + b"".join(struct.pack("<I", len(p)) + p for p in packets)


def unpack(blob: bytes) -> tuple[int, int, int, list[bytes]]:
    """(width, height, q, packets) of a segment blob; raises on damage."""
    if len(blob) < _HEADER.size:
        raise EgovidError("segment blob is truncated", "the archive is damaged; restore it from a backup")
    magic, version, w, h, _pw, _ph, n, q, _ = _HEADER.unpack_from(blob, 0)
    if magic != MAGIC or version != VERSION:
        raise EgovidError("segment blob has an unknown format", "the archive is damaged or from another version")
    packets, off = [], _HEADER.size
    for _ in range(n):
        if off + 4 > len(blob):
            raise EgovidError("segment blob is truncated", "the archive is damaged; restore it from a backup")
        (size,) = struct.unpack_from("<I", blob, off)
        if off + 4 + size > len(blob):
            raise EgovidError("segment blob is truncated", "the archive is damaged; restore it from a backup")
        packets.append(blob[off + 4 : off + 4 + size])
        off += 4 + size
    if off != len(blob):
        raise EgovidError("segment blob has trailing data", "the archive is damaged")
    return w, h, q, packets


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
    h.update(np.ascontiguousarray(frame).tobytes())


def encode_segment(
    frames: Iterator[np.ndarray],
    width: int,
    height: int,
    settings: vpx.EncoderSettings,
    baselines: Callable[[int], np.ndarray | None] | None = None,
    progress: Callable[[int], None] | None = None,
    keep_recon: list | None = None,
) -> EncodedSegment:
    """Encode unpadded I420 frames; ``baselines(k)`` gives frame k's padded baseline (or None)."""
    vpx.self_test()
    pw, ph = vpx.padded_size(width, height)
    enc = vpx.VP9Encoder(pw, ph, settings)
    packets, sizes = [], []
    h = hashlib.sha256()
    se, n_pix = 0.0, 0
    try:
        for k, frame in enumerate(frames):
            padded = vpx.pad_i420(frame, pw, ph)
            golden = baselines(k) if (baselines is not None and k > 0) else None
            pkt = enc.encode(padded, golden)
            packets.append(pkt)
            sizes.append(len(pkt))
            rec = vpx.crop_i420(enc.reconstruction(), width, height)
            digest_update(h, rec)
            d = rec[:height].astype(np.int32) - frame[:height].astype(np.int32)
            se += float(np.sum(d * d))
            n_pix += d.size
            if keep_recon is not None:
                keep_recon.append(rec)
            if progress is not None:
                progress(k + 1)
    finally:
        enc.close()
    if not packets:
        raise EgovidError("a segment with no frames cannot be encoded")
    mse = se / max(n_pix, 1)
    psnr = 10 * np.log10(255.0**2 / mse) if mse > 0 else 100.0
    return EncodedSegment(pack(width, height, settings.q, packets), len(packets), h.hexdigest(), float(psnr), sizes)


def decode_segment(
    blob: bytes, baselines: Callable[[int], np.ndarray | None] | None = None, start: int = 0
) -> Iterator[np.ndarray]:
    """Yield the unpadded I420 frames of a segment (from frame ``start``; earlier frames are
    decoded but not yielded, since decoding must begin at the keyframe)."""
    vpx.self_test()
    w, h, _q, packets = unpack(blob)
    pw, ph = vpx.padded_size(w, h)
    dec = vpx.VP9Decoder(pw, ph)
    try:
        for k, pkt in enumerate(packets):
            golden = baselines(k) if (baselines is not None and k > 0) else None
            frame = vpx.crop_i420(dec.decode(pkt, golden), w, h)
            if k >= start:
                yield frame
    finally:
        dec.close()
