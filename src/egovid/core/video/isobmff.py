"""ISO-BMFF (MP4/MOV) boxes and sample tables, read without decoding: the one box walker and the
one sample-table reader of egovid (the synthetic file writers of :mod:`egovid.synth.mp4box` walk
boxes with it too).

A box is a 32-bit big-endian size (header included), a four-character type and a payload; size 1
means a 64-bit size follows the type, size 0 "to the end of the enclosing box". A track
(``moov/trak``) says what it holds in ``mdia/hdlr`` (handler type: ``vide``, ``soun``, ``meta``,
``camm``, ...) and ``minf/stbl/stsd`` (sample entry: ``avc1``, ``camm``, ``gpmd``, ...); its
samples are located by the sample table: sizes (``stsz``), chunk offsets (``stco``/``co64``),
samples per chunk (``stsc``), decode-time deltas (``stts``) and composition offsets (``ctts``),
in the media's own time scale (``mdhd``). An edit list (``edts/elst``, in the movie's time scale,
``mvhd``) places the media on the movie's timeline, which is what players and FFmpeg present.
"""

from __future__ import annotations

import mmap
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Box types an ISO-BMFF file starts with (QuickTime files may start with ``wide``, ``mdat``, ...).
_FIRST_BOXES = {"ftyp", "moov", "mdat", "free", "skip", "wide", "pnot", "uuid", "styp"}


def box_header(data, pos: int, end: int) -> tuple[str, int, int] | None:
    """The box at ``pos`` of ``data`` (bytes or mmap) that ends by ``end``: ``(type, header
    length, size)`` in bytes (64-bit sizes read; size 0 runs to ``end``); None where no whole
    header fits or the size is impossible (a damaged or cut tail)."""
    if pos + 8 > end:
        return None
    size, kind = struct.unpack_from(">I4s", data, pos)
    head = 8
    if size == 1:
        if pos + 16 > end:
            return None
        size, head = struct.unpack_from(">Q", data, pos + 8)[0], 16
    elif size == 0:
        size = end - pos
    if size < head:
        return None
    return kind.decode("latin-1"), head, size


def iter_boxes(data, start: int = 0, end: int | None = None) -> Iterator[tuple[str, int, int, int]]:
    """The boxes of ``data[start:end]`` in order as ``(type, offset, payload offset, size)``
    (absolute byte offsets); a box whose size runs past ``end`` is given up to ``end``, and the
    walk stops at a header that cannot be read."""
    end = len(data) if end is None else end
    pos = start
    while True:
        h = box_header(data, pos, end)
        if h is None:
            return
        kind, head, size = h
        yield kind, pos, pos + head, min(size, end - pos)
        pos += size


def _child(data, start: int, end: int, kind: str) -> tuple[int, int] | None:
    """``(payload offset, end)`` of the first ``kind`` box in ``data[start:end]``."""
    for k, o, p, s in iter_boxes(data, start, end):
        if k == kind:
            return p, o + s
    return None


def _path(data, start: int, end: int, *kinds: str) -> tuple[int, int] | None:
    span: tuple[int, int] | None = (start, end)
    for k in kinds:
        span = _child(data, span[0], span[1], k)
        if span is None:
            return None
    return span


@dataclass(frozen=True)
class Track:
    """One track of a file and where its samples are.

    ``handler`` the ``hdlr`` type (``"vide"``, ``"meta"``, ``"camm"``, ...); ``sample_entry`` the
    first ``stsd`` entry's type (``"avc1"``, ``"camm"``, ...); ``timescale`` ticks per second of
    the media; ``offsets``/``sizes`` (N,) int64 byte offset and size of every sample, in decode
    order; ``dts`` (N,) int64 decode times and ``durations`` (N,) int64, in ticks; ``cts`` (N,) int64
    composition offsets in ticks (zeros without ``ctts``); ``edits`` ``(movie start s, media
    start ticks or -1 for an empty edit, movie duration s)`` per edit-list entry (empty: none)."""

    track_id: int
    handler: str
    sample_entry: str
    timescale: int
    offsets: np.ndarray
    sizes: np.ndarray
    dts: np.ndarray
    durations: np.ndarray
    cts: np.ndarray
    edits: tuple[tuple[float, int, float], ...] = ()

    def __len__(self) -> int:
        return len(self.offsets)

    def presentation_times(self) -> tuple[np.ndarray, np.ndarray]:
        """``(times s, kept)``: each sample's presentation time on the movie's timeline
        (composition time through the edit list) and whether an edit shows it at all ((N,) bool;
        without an edit list every sample is kept, at its composition time)."""
        media = (self.dts + self.cts).astype(float)
        if not self.edits:
            return media / self.timescale, np.ones(len(media), bool)
        t = np.full(len(media), np.nan)
        for start, m0, dur in self.edits:
            if m0 < 0:
                continue
            rel = (media - m0) / self.timescale
            inside = (rel >= 0) & ((rel < dur) | (dur <= 0)) & np.isnan(t)
            t[inside] = start + rel[inside]
        kept = ~np.isnan(t)
        return np.where(kept, t, media / self.timescale), kept

    def first_presentation_s(self) -> float:
        """The movie time (s) at which the track's first shown sample is presented (0 for an
        empty track): what FFmpeg calls the stream's start time."""
        if not len(self):
            return 0.0
        t, kept = self.presentation_times()
        return float(t[kept].min()) if kept.any() else 0.0


def _full(data, span: tuple[int, int]) -> tuple[int, int]:
    """``(version, payload offset after version/flags)`` of a full box."""
    return data[span[0]], span[0] + 4


def _table(data, span: tuple[int, int] | None, fmt: str) -> np.ndarray:
    """Entries of a counted table box (version/flags, uint32 count, then rows of ``fmt``), as an
    (n, fields) int64 array; rows past the box's end are dropped."""
    if span is None:
        return np.zeros((0, len(fmt)), np.int64)
    _, p = _full(data, span)
    if p + 4 > span[1]:
        return np.zeros((0, len(fmt)), np.int64)
    (n,) = struct.unpack_from(">I", data, p)
    width = struct.calcsize(">" + fmt)
    n = min(n, (span[1] - p - 4) // width)
    dtype = np.dtype([(f"f{i}", ">" + c.replace("I", "u4").replace("i", "i4").replace("Q", "u8").replace("q", "i8"))
                      for i, c in enumerate(fmt)])  # fmt: skip
    rows = np.frombuffer(data, dtype, count=n, offset=p + 4)
    return np.column_stack([rows[f].astype(np.int64) for f in dtype.names]) if n else np.zeros((0, len(fmt)), np.int64)


def _track(data, start: int, end: int, movie_scale: int) -> Track | None:
    tkhd = _child(data, start, end, "tkhd")
    track_id = 0
    if tkhd is not None:
        v, p = _full(data, tkhd)
        track_id = struct.unpack_from(">I", data, p + (16 if v == 1 else 8))[0]
    mdia = _child(data, start, end, "mdia")
    if mdia is None:
        return None
    hdlr = _child(data, *mdia, "hdlr")
    handler = bytes(data[hdlr[0] + 8 : hdlr[0] + 12]).decode("latin-1") if hdlr else ""
    mdhd = _child(data, *mdia, "mdhd")
    if mdhd is None:
        return None
    v, p = _full(data, mdhd)
    timescale = struct.unpack_from(">I", data, p + (16 if v == 1 else 8))[0]
    stbl = _path(data, *mdia, "minf", "stbl")
    if stbl is None or timescale <= 0:
        return None
    entry = ""
    stsd = _child(data, *stbl, "stsd")
    if stsd is not None:
        first = next(iter_boxes(data, stsd[0] + 8, stsd[1]), None)
        entry = first[0] if first else ""
    # Sizes.
    stsz = _child(data, *stbl, "stsz")
    if stsz is None:
        return None
    _, p = _full(data, stsz)
    fixed, count = struct.unpack_from(">II", data, p)
    if fixed:
        sizes = np.full(count, fixed, np.int64)
    else:
        count = min(count, (stsz[1] - p - 8) // 4)
        sizes = np.frombuffer(data, ">u4", count=count, offset=p + 8).astype(np.int64)
    # Chunks and their samples.
    co = _child(data, *stbl, "stco")
    chunk_off = _table(data, co, "I")[:, 0] if co else _table(data, _child(data, *stbl, "co64"), "Q")[:, 0]
    stsc = _table(data, _child(data, *stbl, "stsc"), "III")
    per_chunk = np.zeros(len(chunk_off), np.int64)
    for k, (first_chunk, n, _) in enumerate(stsc):
        last = stsc[k + 1, 0] - 1 if k + 1 < len(stsc) else len(chunk_off)
        per_chunk[max(first_chunk - 1, 0) : max(last, 0)] = n
    chunk_of = np.repeat(np.arange(len(chunk_off)), per_chunk)[: len(sizes)]
    n = len(chunk_of)
    sizes = sizes[:n]
    first_in_chunk = np.concatenate([[0], np.cumsum(per_chunk)])[chunk_of]
    within = np.cumsum(sizes) - sizes  # bytes before each sample, over the whole track
    offsets = chunk_off[chunk_of] + within - within[first_in_chunk] if n else np.zeros(0, np.int64)
    # Times.
    stts = _table(data, _child(data, *stbl, "stts"), "II")
    durations = np.repeat(stts[:, 1], stts[:, 0])[:n] if len(stts) else np.zeros(0, np.int64)
    durations = np.concatenate([durations, np.zeros(n - len(durations), np.int64)])
    dts = np.cumsum(durations) - durations
    ctts_span = _child(data, *stbl, "ctts")
    cts = np.zeros(n, np.int64)
    if ctts_span is not None:
        signed = data[ctts_span[0]] == 1
        c = _table(data, ctts_span, "Ii" if signed else "II")
        rep = np.repeat(c[:, 1], c[:, 0])[:n]
        cts[: len(rep)] = rep
    edits = _edits(data, start, end, movie_scale, timescale)
    return Track(track_id, handler, entry, timescale, offsets, sizes, dts, durations, cts, edits)


def _edits(data, start: int, end: int, movie_scale: int, timescale: int) -> tuple[tuple[float, int, float], ...]:
    elst = _path(data, start, end, "edts", "elst")
    if elst is None or movie_scale <= 0:
        return ()
    v = data[elst[0]]
    rows = _table(data, elst, "Qqi" if v == 1 else "Iii")
    out, t = [], 0.0
    for seg_dur, media_time, _rate in rows:
        dur = float(seg_dur) / movie_scale
        out.append((t, int(media_time), dur))
        t += dur
    return tuple(out)


def read_tracks(path: str | os.PathLike) -> tuple[list[Track], mmap.mmap | None]:
    """The tracks of an MP4/MOV file and the file mapped in memory (to read samples from with
    :func:`sample_bytes`; close it when done); ``([], None)`` for a file without a readable
    ``moov`` (not ISO-BMFF, empty, cut before its index)."""
    try:
        with open(Path(path), "rb") as fh:
            if os.fstat(fh.fileno()).st_size < 16:
                return [], None
            data = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)  # stays mapped after the close
    except OSError:
        return [], None
    try:
        first = box_header(data, 0, len(data))
        if first is None or first[0] not in _FIRST_BOXES:  # not ISO-BMFF (MKV, AVI, ...): not walked
            data.close()
            return [], None
        moov = _child(data, 0, len(data), "moov")
        if moov is None:
            data.close()
            return [], None
        mvhd = _child(data, *moov, "mvhd")
        movie_scale = 0
        if mvhd is not None:
            v, q = _full(data, mvhd)
            movie_scale = struct.unpack_from(">I", data, q + (16 if v == 1 else 8))[0]
        tracks = []
        for k, o, pl, s in iter_boxes(data, *moov):
            if k == "trak":
                t = _track(data, pl, o + s, movie_scale)
                if t is not None:
                    tracks.append(t)
    except (struct.error, ValueError, IndexError):
        data.close()
        return [], None
    return tracks, data


def sample_bytes(data, track: Track, index: int) -> bytes:
    """The bytes of sample ``index`` of ``track`` (fewer where the file ends inside it)."""
    o, s = int(track.offsets[index]), int(track.sizes[index])
    return bytes(data[o : o + s])
