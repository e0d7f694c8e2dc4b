"""Getting drives back out of an archive: decoding segments (a whole drive or a stretch), the
baselines a joint segment is decoded against, digests, and writing a lossless video
(``egovid dashcam extract``: :func:`plan_extract`, then :func:`extract_drive`).

Everything here reads through a :class:`FrameSource` — the archive itself, or the snapshot of the
reference drives an ingest task carries to another process — so the encoder's baselines and every
later decoder's are built by the same code from the same decoded pictures (bit-exactness depends
on it). A stretch is read by byte ranges when the catalogue knows where the segment's random-access
runs begin (``run_offsets``): from an object store only the runs it needs travel.
"""

from __future__ import annotations

import hashlib
import itertools
import os
import re
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.video import ColourTags, VideoWriter
from egovid.core.video.read import read_ahead
from egovid.dashcam.archive.blobs import BlobStore
from egovid.dashcam.archive.catalogue import Drive, Segment
from egovid.dashcam.archive.fleetstore import FleetStore, drive_channels, live_drive
from egovid.dashcam.archive.references import check_chain
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.codec import registry, vpx
from egovid.dashcam.codec import segment as codec
from egovid.dashcam.codec.streams import StreamCopier

DAMAGED = "the archive or one of its reference drives is damaged"


class FrameSource(Protocol):
    """What decoding needs: the segments of a drive and the blob store holding them."""

    blobs: BlobStore

    def segments(self, drive_id: int) -> list[Segment]: ...


class SegmentSnapshot:
    """A :class:`FrameSource` that carries the segments it needs: those of some drives and of every
    drive they were coded against (:func:`reference_segments`), with the blob store. What an ingest
    hands to another thread or process (a Dask worker), which never opens the catalogue."""

    def __init__(self, blobs: BlobStore, by_drive: dict[int, list[Segment]]) -> None:
        self.blobs, self.by_drive = blobs, by_drive

    def segments(self, drive_id: int) -> list[Segment]:
        return self.by_drive.get(drive_id, [])


def reference_segments(catalogue, drive_ids) -> dict[int, list[Segment]]:
    """The segments of ``drive_ids`` and of every drive they refer to, directly or through others
    (a chain through the archive ending at root segments)."""
    out: dict[int, list[Segment]] = {}
    todo = list(drive_ids)
    while todo:
        d = int(todo.pop())
        if d in out:
            continue
        out[d] = catalogue.segments(d)
        todo += [g.ref_drive_id for g in out[d] if g.ref_drive_id is not None and g.ref_drive_id not in out]
    return out


def segment_frames(source: FrameSource, seg: Segment, start: int = 0, stop: int | None = None) -> Iterator[np.ndarray]:
    """Unpadded I420 frames ``start`` … ``stop − 1`` of a segment (segment numbering; default to
    its end). Decoding begins at the random-access run holding ``start``, in this drive and in the
    drives it refers to; with ``run_offsets`` in the catalogue only the runs needed are read."""
    n = seg.frame_end - seg.frame_start
    stop = n if stop is None else min(stop, n)
    offsets = seg.params.get("run_offsets")
    refresh = int(seg.params.get("refresh") or 0)
    if offsets and refresh:
        head = source.blobs.read_range(seg.blob, 0, offsets[0])
        lay, _ = codec.parse_header(head)
        r0 = start // refresh
        r1 = min(len(offsets) - 1, -(-stop // refresh))
        packets = _ranged_packets(source.blobs, seg.blob, lay, offsets, r0, r1)
        frames = registry.decode_runs(lay, packets, r0, baselines(source, seg, r0 * refresh), start)
    else:
        blob = source.blobs.get(seg.blob)
        frames = registry.decode_segment(blob, baselines(source, seg, codec.run_start(blob, start)), start)
    return itertools.islice(frames, stop - start)


def _ranged_packets(
    blobs: BlobStore, sha: str, lay: codec.SegmentLayout, offsets: list[int], r0: int, r1: int, chunk: int = 8
) -> Iterator[bytes]:
    """The packets of runs ``r0`` … ``r1 − 1``, fetched ``chunk`` runs per byte-range read."""
    runs = lay.run_packets()
    for a in range(r0, r1, chunk):
        b = min(r1, a + chunk)
        body = blobs.read_range(sha, offsets[a], offsets[b])
        yield from codec.iter_packets(body, 0, runs[b - 1][1] - runs[a][0])


class DriveFrames:
    """Decoded frames of an archived drive, by index (forward streaming with a small cache;
    ``ahead`` > 0: decoded that many frames ahead in a background thread, :func:`read_ahead`)."""

    def __init__(self, source: FrameSource, drive_id: int, cache: int = 48, ahead: int = 0) -> None:
        self.source = source
        self.ahead = ahead
        self.segments = source.segments(drive_id)
        if not self.segments:
            raise EgovidError(f"drive {drive_id} has no frames in the archive", DAMAGED)
        self._gen: Iterator[np.ndarray] | None = None
        self._seg: Segment | None = None
        self._pos = -1
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._size = cache

    def _segment_of(self, idx: int) -> Segment:
        for s in self.segments:
            if s.frame_start <= idx < s.frame_end:
                return s
        raise EgovidError(f"frame {idx} is not in the archive", DAMAGED)

    def get(self, idx: int, passed: dict[int, np.ndarray] | None = None) -> np.ndarray:
        """Frame ``idx`` (decoding forward to it; from its random-access run when it lies behind);
        ``passed`` (if given) receives the frames decoded on the way, by index."""
        idx = int(idx)
        if idx in self._cache:
            self._cache.move_to_end(idx)
            return self._cache[idx]
        seg = self._segment_of(idx)
        if self._seg is None or self._seg.id != seg.id or idx < self._pos:
            self.close()
            self._gen = segment_frames(self.source, seg, idx - seg.frame_start)
            if self.ahead:
                self._gen = read_ahead(self._gen, self.ahead)
            self._seg, self._pos = seg, idx
        frame = None
        while self._pos <= idx:
            frame = next(self._gen)
            if passed is not None and self._pos < idx:
                passed[self._pos] = frame
            self._cache[self._pos] = frame
            if len(self._cache) > self._size:
                self._cache.popitem(last=False)
            self._pos += 1
        return frame

    def close(self) -> None:
        """Stop decoding (and the read-ahead thread, if any)."""
        if self._gen is not None and hasattr(self._gen, "close"):
            self._gen.close()
        self._gen = None


def baselines(source: FrameSource, seg: Segment, first: int = 0) -> Callable[[int], np.ndarray] | None:
    """The baseline builder of a joint segment (None for an intra segment), for decoding that
    begins at the segment's frame ``first``."""
    if seg.mode != "joint":
        return None
    if seg.ref_drive_id == seg.drive_id:
        raise EgovidError(f"segment {seg.id} refers to its own drive", DAMAGED)
    return baseline_builder(
        DriveFrames(source, int(seg.ref_drive_id)),
        seg.refmap,
        seg.params["width"],
        seg.params["height"],
        seg.align,
        first,
    )


def baseline_builder(
    ref_frames: DriveFrames, refmap: np.ndarray, width: int, height: int, align: dict, first: int = 0
) -> Callable[[int], np.ndarray]:
    """Frame k's baseline: the decoded reference frame ``refmap[k]``, padded, globally aligned by
    the stored parameters. The same function serves the encoder and every later decoder (``first``:
    the first frame that will be asked for, where decoding begins)."""
    pw, ph = vpx.padded_size(width, height)
    kind, params = align.get("kind", "none"), align.get("params")
    ahead: dict[int, np.ndarray] = {}
    state = {"hi": first - 1}

    def build(k: int) -> np.ndarray:
        # Coding order visits an anchor before the frames behind it. Fetch every reference frame up
        # to the anchor's in display order and keep them (at most one GOP), so that the older drive
        # is decoded forward once even where its frame numbers jump (it stood still, we did not).
        if k > state["hi"]:
            for j in range(state["hi"] + 1, k + 1):
                ahead[j] = ref_frames.get(int(refmap[j]))
            state["hi"] = k
        raw = ahead.pop(k) if k in ahead else ref_frames.get(int(refmap[k]))
        for j in [j for j in ahead if j < k - 64]:  # never asked for (the first frames)
            del ahead[j]
        frame = vpx.pad_i420(raw, pw, ph)
        return codec.apply_alignment(frame, pw, ph, kind, params[k] if params else None)

    return build


def checked_frames(source: FrameSource, drive: str, seg: Segment, f0: int, f1: int) -> Iterator[np.ndarray]:
    """Frames ``f0`` … ``f1 − 1`` (drive numbering) of a segment, checked against the encoder's
    reconstruction: run by run where the segment has per-run digests (the runs at the ends
    of the stretch are decoded whole for it), else by the segment digest when all of it is
    written. A mismatch raises; a video writer then leaves no output behind."""
    n = seg.frame_end - seg.frame_start
    a, b = f0 - seg.frame_start, f1 - seg.frame_start
    refresh = int(seg.params.get("refresh") or 0)
    runs = seg.params.get("run_digests") or []
    damaged = EgovidError(
        f"drive {drive} frames {seg.frame_start}-{seg.frame_end} do not decode to what was encoded", DAMAGED
    )
    if refresh and len(runs) == -(-n // refresh):
        k = a - a % refresh
        end = min(n, -(-b // refresh) * refresh)
        h = hashlib.sha256()
        for frame in segment_frames(source, seg, k, end):
            codec.digest_update(h, frame)
            if a <= k < b:
                yield frame
            k += 1
            if k % refresh == 0 or k == n:
                if h.hexdigest()[: codec.RUN_DIGEST_CHARS] != runs[(k - 1) // refresh]:
                    raise damaged
                if k >= b:
                    return
                h = hashlib.sha256()
        raise damaged  # the bitstream ended early
    # No per-run digests (one run, or an archive written before they existed).
    h = hashlib.sha256()
    got = 0
    for frame in segment_frames(source, seg, a, b):
        codec.digest_update(h, frame)
        got += 1
        yield frame
    if got != b - a or ((a, b) == (0, n) and h.hexdigest() != seg.params.get("recon_digest")):
        raise damaged


def segment_digest(source: FrameSource, seg: Segment) -> str:
    """SHA-256 of all decoded pictures of a segment (compare with ``params['recon_digest']``)."""
    h = hashlib.sha256()
    for frame in segment_frames(source, seg):
        codec.digest_update(h, frame)
    return h.hexdigest()


def drive_frames(source: FrameSource, drive: Drive, f0: int, f1: int) -> Iterator[np.ndarray]:
    """Frames ``f0`` … ``f1 − 1`` of a drive, segment by segment, checked (:func:`checked_frames`)."""
    for seg in source.segments(drive.id):
        if seg.frame_end <= f0 or seg.frame_start >= f1:
            continue
        yield from checked_frames(source, drive.name, seg, max(f0, seg.frame_start), min(f1, seg.frame_end))


def extract_video(
    source: FrameSource,
    drive: Drive,
    out: str | os.PathLike,
    progress: Callable[[int, int], None] | None = None,
    frames: tuple[int, int] | None = None,
    *,
    colour=None,
    streams: bytes | None = None,
    crf: int | None = None,
    audio_codec: str | None = None,
) -> Path:
    """Write a drive back as a lossless video (MKV/FFV1, or MP4 with lossless H.264), checked
    against the encoder's reconstruction (:func:`checked_frames`).

    ``frames``: (first, end) frame numbers of the drive to write (end exclusive; default all).
    Decoding starts at the random-access run holding ``first``, in this drive and in the
    drives it refers to. ``colour``: the source's colour tags (:class:`~egovid.core.video.ColourTags`)
    to tag the output with; ``streams``: the drive's archived audio and telemetry
    (:mod:`egovid.dashcam.codec.streams`), copied for the same stretch (``audio_codec``: re-encode
    the audio, e.g. ``aac``); ``crf``: an MP4 for sharing (H.264 at this quality) instead of a
    lossless one. ``progress(done, total)``: frames written."""
    out = Path(out)
    ext = out.suffix.lower()
    if ext not in (".mkv", ".mp4"):
        raise EgovidError(f"cannot write {out.name}", "use an .mkv (FFV1) or .mp4 (lossless H.264) output")
    f0, f1 = frames if frames is not None else (0, drive.frames)
    if not 0 <= f0 < f1 <= drive.frames:
        raise EgovidError(
            f"frames {f0}-{f1 - 1} are not in drive {drive.name} (frames 0-{drive.frames - 1})",
            "choose a range inside the drive (see `egovid dashcam show`)",
        )
    check_chain(source, drive.id)
    codec_name, options = ("ffv1", None) if ext == ".mkv" else ("libx264", {"qp": "0", "preset": "ultrafast"})
    if crf is not None and ext == ".mp4":
        options = {"crf": str(crf), "preset": "veryfast"}
    done, total = 0, f1 - f0
    with VideoWriter(
        out,
        drive.width,
        drive.height,
        drive.fps,
        codec=codec_name,
        crf=None,
        preset=None,
        pix_fmt="yuv420p",
        options=options,
        colour=colour,
    ) as w:
        copier = (
            StreamCopier(streams, w.container, f0 / drive.fps, f1 / drive.fps, audio_codec=audio_codec)
            if streams
            else None
        )
        for frame in drive_frames(source, drive, f0, f1):
            w.write_i420(frame, done / drive.fps)
            done += 1
            if progress:
                progress(done, total)
        if copier is not None:
            copier.write()
            copier.close()
    return out


def archived_extras(archive: Archive, drive: Drive) -> dict:
    """What the fleet tables add to a drive's frames: the source's colour tags and the archived
    audio and telemetry (keyword arguments ``colour`` and ``streams`` of :func:`extract_video`;
    empty for an archive without fleet tables, which are not created here)."""
    cat = archive.catalogue
    if cat.get_meta("fleet_schema") is None:
        return {}
    m = FleetStore(cat).meta(drive.id)
    return {
        "colour": ColourTags(**m.colour) if m.colour else None,
        "streams": archive.blobs.get(m.streams_blob) if m.streams_blob else None,
    }


@dataclass(frozen=True)
class ExtractJob:
    """What ``extract`` writes: a live drive and its frames [frame_start, frame_end)."""

    drive: Drive
    frame_start: int
    frame_end: int


def plan_extract(archive: Archive, key: str, start: float | None = None, duration: float | None = None) -> ExtractJob:
    """The live drive ``key`` (name or id) and its frames from ``start`` seconds into it (default 0)
    for ``duration`` seconds (default to the end; at least one frame), checked before any work:
    :class:`EgovidError` for an unknown drive or a start past its end."""
    drive = live_drive(archive.catalogue, key, archive.root)
    f0 = round((start or 0.0) * drive.fps)
    f1 = drive.frames if duration is None else min(drive.frames, f0 + max(1, round(duration * drive.fps)))
    if f0 >= drive.frames:
        raise EgovidError(
            f"--start {start} s is past the end of drive {drive.name} ({drive.frames / drive.fps:.1f} s)",
            "choose an earlier start",
        )
    return ExtractJob(drive, f0, f1)


def extract_drive(
    archive: Archive, job: ExtractJob, out: str | os.PathLike, progress: Callable[[int, int], None] | None = None
) -> Path:
    """``egovid dashcam extract``: write the frames of ``job`` (:func:`plan_extract`) as a video with
    the drive's colour tags, audio and telemetry (:func:`archived_extras`), checked against the
    encoder's reconstruction (:func:`extract_video`). ``progress(done, total)``: frames written."""
    frames = (job.frame_start, job.frame_end)
    return extract_video(archive, job.drive, out, progress, frames, **archived_extras(archive, job.drive))


# -- the cameras of a multi-camera drive --------------------------------------------------------

ALL_CHANNELS = "all"  # ``--channel all``: every camera of the drive, in sync


@dataclass(frozen=True)
class ChannelJob:
    """One camera of a drive to write: its channel name, the drive row holding its frames, its
    frames [frame_start, frame_end) and the UTC time of the first (seconds; NaN where the archive
    has no frame times: a drive ingested before the fleet tables)."""

    channel: str
    drive: Drive
    frame_start: int
    frame_end: int
    start_utc: float


def channel_name(text: str | None) -> str | None:
    """``--channel`` checked and in lower case (None stays None: the main camera);
    :class:`EgovidError` for text that cannot name a camera."""
    if text is None:
        return None
    name = text.strip().lower()
    if not re.fullmatch(r"[a-z0-9_]{1,40}", name):
        raise EgovidError(f"--channel {text!r} is not a camera name",
                          f"give front, rear, interior, left_repeater … or {ALL_CHANNELS}")  # fmt: skip
    return name


def _nearest(times: np.ndarray, t: float) -> int:
    """Index of the element of the sorted ``times`` closest to ``t``."""
    i = int(np.searchsorted(times, t))
    if i >= len(times):
        return len(times) - 1
    return i - 1 if i > 0 and t - times[i - 1] <= times[i] - t else i


def channel_jobs(archive: Archive, drive: Drive, f0: int, f1: int, channel: str | None = None) -> list[ChannelJob]:
    """The cameras of live drive ``drive`` to write for its frames [f0, f1) (main channel
    numbering): ``channel`` one of its channels (default: the main one) or :data:`ALL_CHANNELS`.
    Another camera's frames are those recorded over the same time, by frame times (UTC, the
    nearest frame at each end: at most half a frame apart); with ``all``, every camera is cut to
    the time all of them recorded, so the outputs start and end together. :class:`EgovidError`
    for a channel the drive does not have (naming those it has) or one that recorded nothing then."""
    cat = archive.catalogue
    chans = drive_channels(cat, drive.id)
    main = next(iter(chans))
    want = main if channel is None else channel
    if want != ALL_CHANNELS and want not in chans:
        raise EgovidError(f"drive {drive.name} has no channel {want!r}",
                          f"its channels: {', '.join(chans)} (or {ALL_CHANNELS}: every one in sync)")  # fmt: skip
    names = list(chans) if want == ALL_CHANNELS else [want]
    fleet = FleetStore(cat) if cat.get_meta("fleet_schema") is not None else None
    futc = fleet.frame_utc(drive.id, drive.fps) if fleet is not None else np.zeros(0)
    if names == [main]:  # the drive itself: its frames as asked (frame times only said, where known)
        return [ChannelJob(main, drive, f0, f1, float(futc[f0]) if len(futc) > f0 else float("nan"))]
    if fleet is None or len(futc) < f1:
        raise EgovidError(f"drive {drive.name} has no frame times to put its cameras in step", DAMAGED)
    t0, t1 = float(futc[f0]), float(futc[f1 - 1])
    spans: dict[str, tuple[Drive, np.ndarray]] = {}
    for ch in names:
        d = drive if chans[ch] == drive.id else cat.drive(chans[ch])
        times = futc if d.id == drive.id else fleet.frame_utc(d.id, d.fps)
        half = 0.5 / d.fps
        if not len(times) or times[-1] < t0 - half or times[0] > t1 + half:
            if want != ALL_CHANNELS:
                raise EgovidError(f"the {ch} camera of drive {drive.name} recorded nothing in that stretch",
                                  "choose another stretch, or --channel all for the cameras that did")  # fmt: skip
            continue
        spans[ch] = (d, times)
    if want == ALL_CHANNELS and len(spans) > 1:  # the time every camera recorded
        t0 = max([t0, *(float(x[0]) for _, x in spans.values())])
        t1 = min([t1, *(float(x[-1]) for _, x in spans.values())])
        if t1 < t0:
            raise EgovidError(f"the cameras of drive {drive.name} recorded no common time in that stretch",
                              "extract them one by one with --channel NAME")  # fmt: skip
    out = []
    for ch, (d, times) in spans.items():
        a, b = _nearest(times, t0), _nearest(times, t1) + 1
        out.append(ChannelJob(ch, d, a, max(b, a + 1), float(times[a])))
    return out


def channel_output(out: str | os.PathLike, channel: str, every: bool) -> Path:
    """Where a camera is written: ``out`` itself, or with ``--channel all`` ``OUT-CHANNEL.EXT``
    beside it (``every``)."""
    out = Path(out)
    return out.with_name(f"{out.stem}-{channel}{out.suffix}") if every else out
