"""The codec backends a segment can be coded with, by name: one interface (encode a segment with
optional baselines, decode runs of it, a self-test), looked up from the settings (encoding) or the
blob's magic (decoding), never by string comparisons spread over the code.

* ``vp9`` (:mod:`egovid.dashcam.codec.segment`, libvpx through ctypes): codes against the older
  drive's aligned frames injected as a reference on both sides (thesis §14.2); every archive
  written before AV1 is VP9.
* ``av1`` (:mod:`egovid.dashcam.codec.av1`, SVT-AV1 + dav1d): standalone only; first drives and
  pieces without an older drive of their path and light.
* ``aom`` (:mod:`egovid.dashcam.codec.aom_segment`, libaom through ctypes): AV1 against the older
  drive's aligned frames injected as a reference on both sides (the VP9 design on AV1).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from egovid.core.errors import EgovidError
from egovid.dashcam.codec import aom, aom_segment, av1, segment, vpx
from egovid.dashcam.codec.settings import EncoderSettings


@dataclass(frozen=True)
class Backend:
    """A codec: ``encode(frames, width, height, settings, baselines, progress, keep_recon, *,
    verify, verify_runs, clock, spool) -> EncodedSegment``; ``decode(layout, packets, first_run,
    baselines, start)`` yields unpadded I420 frames; ``joint``: whether it can code against
    baselines; ``self_test()`` raises when the library does not round-trip and returns a line
    naming it; ``q_offset``: what a joint candidate adds to the archive's ``--q`` (libvpx's 0-63
    scale) to code at about the same PSNR-Y as libvpx at ``--q`` (standalone SVT-AV1's offset is
    :data:`egovid.dashcam.ingest.options.AV1_DQ`)."""

    name: str
    joint: bool
    encode: Callable[..., segment.EncodedSegment]
    decode: Callable[..., Iterator[np.ndarray]]
    self_test: Callable[[], str]
    q_offset: int = 0


BACKENDS: dict[str, Backend] = {
    b.name: b
    for b in (
        Backend("vp9", True, segment.encode_segment, segment.decode_runs, vpx.self_test),
        Backend("av1", False, av1.encode_segment, av1.decode_runs, av1.self_test),
        # libaom's quantiser q gives about the PSNR-Y of SVT-AV1 at CRF q + 2 (640x360 different-day
        # drive, experiments/dashcam_aom_joint.py), SVT-AV1's CRF q + 14 that of libvpx at q
        # (ingest/options.py AV1_DQ): libaom at --q + 12.
        Backend("aom", True, aom_segment.encode_segment, aom_segment.decode_runs, aom.self_test, q_offset=12),
    )
}


def backend(name: str) -> Backend:
    """The backend called ``name``; :class:`EgovidError` for an unknown one (an archive from a
    newer egovid)."""
    if name not in BACKENDS:
        raise EgovidError(f"unknown codec {name!r}", "upgrade egovid (the archive may come from a newer version)")
    return BACKENDS[name]


def encode_segment(frames: Iterator[np.ndarray], width: int, height: int, settings: EncoderSettings, *args, **kw):
    """Encode with the backend ``settings.codec`` names (see :class:`Backend`)."""
    return backend(settings.codec).encode(frames, width, height, settings, *args, **kw)


def decode_runs(
    lay: segment.SegmentLayout,
    packets: Iterable[bytes],
    first_run: int,
    baselines: Callable[[int], np.ndarray | None] | None = None,
    start: int = 0,
) -> Iterator[np.ndarray]:
    """Frames from ``start`` of a segment given its packets from run ``first_run`` on, decoded by
    the backend its header names (:func:`egovid.dashcam.codec.segment.decode_runs` for VP9)."""
    return backend(lay.codec).decode(lay, packets, first_run, baselines, start)


def decode_segment(
    blob: bytes, baselines: Callable[[int], np.ndarray | None] | None = None, start: int = 0
) -> Iterator[np.ndarray]:
    """The unpadded I420 frames of a whole segment blob from frame ``start``, whatever its codec."""
    lay, off = segment.parse_header(blob)
    return decode_runs(lay, segment.iter_packets(blob, off, lay.n_packets), 0, baselines, start)


def joint_codecs() -> tuple[str, ...]:
    """The backends that can code a piece against the older drive (``--joint-codec``)."""
    return tuple(b.name for b in BACKENDS.values() if b.joint)


def describe() -> str:
    """One line per backend that passes its self-test (what ``init`` and ``report`` print)."""
    return "; ".join(b.self_test() for b in BACKENDS.values())
