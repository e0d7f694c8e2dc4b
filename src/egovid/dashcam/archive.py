"""The route-aware dashcam archive (thesis Part III): ingest, extract, report.

Layout of an archive folder::

    ARCHIVE/egovid-archive.json   marker (format version, origin of the metric plane, catalogue)
    ARCHIVE/catalogue.sqlite      drives, paths, sequences, segments (see catalogue.py); with
                                  ``init --db postgresql://…`` these live in a PostgreSQL schema
    ARCHIVE/blobs/ab/abcdef...    segment bitstreams, named by their SHA-256
    ARCHIVE/.lock                 taken for the whole of an ingest

Ingest of a drive (video + GPS):

1. the GPS fixes inside the video's time span are matched against the known paths; the drive is
   cut into per-path pieces, paths are split where the drive joins or leaves them, and the
   unmatched parts become new paths (paths.py);
2. per piece, the older drives on the same path are ranked by illumination and the best becomes
   the reference; without one the piece is a root (intra-coded);
3. a joint piece is aligned frame by frame to its reference (ORB, or SeqSLAM / GPS only for
   comparison), stopped frames keep the previous reference, and it is encoded with the aligned
   older frames injected as a free reference (codec.py); the bitstream is verified by decoding it
   the way ``extract`` will;
4. everything lands in one catalogue transaction; blobs are written (atomically, content-addressed)
   before the commit, so a crash leaves at most unreferenced blobs, never a damaged archive.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import fcntl
import hashlib
import itertools
import json
import os
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from egovid.dashcam import codec, vpx
from egovid.dashcam.align import OrbScorer, ScaleRefiner, align_orb, small_gray, smooth_monotone
from egovid.dashcam.catalogue import Catalogue, Segment, Sequence, catalogue_settings, open_catalogue
from egovid.dashcam.gps import GpsTrack, project, read_track
from egovid.dashcam.illumination import best_match, frame_features
from egovid.dashcam.paths import (
    SPACING,
    DrivePiece,
    match_path,
    resample,
    smooth_track,
    split_drive,
    split_points,
)
from egovid.dashcam.stops import stopped_frames
from egovid.errors import EgovidError
from egovid.io.files import atomic_write_bytes, atomic_write_text
from egovid.io.video import VideoWriter, iter_frames, probe

MARKER = "egovid-archive.json"
FORMAT_VERSION = 1
ALIGNERS = ("orb", "orb-plain", "seqslam", "gps")
BASELINE_ALIGN = ("none", "gain", "similarity")


@dataclass
class IngestOptions:
    """How a drive is ingested.

    ``q``: VP9 quantiser 0-63 (lower = better quality; frames between anchors use ``q + 12``);
    ``speed``: libvpx cpu-used; ``realtime``: realtime instead of good-quality deadline; ``gop``:
    anchor spacing in frames (8, the default; 1 = low delay, every frame from the one before);
    ``refresh``: random-access period in frames (a drive can be decoded from every ``refresh``-th
    frame on: a keyframe for a root drive, a frame predicted from the older drive alone for a joint
    one; 0 = from the start only);
    ``aligner``: orb (thesis' ORB search, smoothed and refined by vertical image scale; the default) |
    orb-plain (the thesis' search alone) | seqslam | gps;
    ``baseline_align``: none | gain | similarity (global alignment of the baseline);
    ``measure_savings``: also encode each joint piece standalone to report the saving;
    ``verify``: decode each new bitstream as extract will and compare with the encoder.
    """

    q: int = 32
    speed: int = 5
    realtime: bool = False
    gop: int = 8
    refresh: int = 24
    aligner: str = "orb"
    baseline_align: str = "none"
    measure_savings: bool = True
    verify: bool = True
    name: str | None = None
    start_utc: float | None = None
    gps_offset: float = 0.0


@dataclass
class PieceReport:
    frames: tuple[int, int]
    path_id: int
    mode: str
    ref_drive: str | None
    bytes: int
    standalone_bytes: int | None
    psnr_y: float
    stopped_frames: int
    prior_fallbacks: int
    seconds: float

    @property
    def saving(self) -> float | None:
        if not self.standalone_bytes:
            return None
        return 1.0 - self.bytes / self.standalone_bytes


@dataclass
class IngestReport:
    drive_id: int
    name: str
    frames: int
    pieces: list[PieceReport] = field(default_factory=list)
    new_paths: list[int] = field(default_factory=list)
    split_paths: list[int] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def to_dict(self) -> dict:
        d = asdict(self)
        d["fps"] = self.fps
        for p, pr in zip(d["pieces"], self.pieces, strict=True):
            p["saving"] = pr.saving
        return d


def _parse_creation_time(text: str | None) -> float | None:
    if not text:
        return None
    try:
        t = dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.UTC)
    return t.timestamp()


def frame_times(video: str | os.PathLike) -> np.ndarray:
    """Presentation times (seconds from the first frame) of every frame, from the demuxer only."""
    import av

    with av.open(str(video)) as c:
        s = c.streams.video[0]
        pts = [p.pts for p in c.demux(s) if p.pts is not None and p.size]
        tb = float(s.time_base)
    if not pts:
        raise EgovidError(f"video {video} has no frames", "give a dashcam video with frames")
    t = np.sort(np.array(pts, dtype=np.float64)) * tb
    return t - t[0]


class DriveFrames:
    """Decoded frames of an archived drive, by index (forward streaming with a small cache)."""

    def __init__(self, archive: Archive, drive_id: int, cache: int = 48) -> None:
        self.archive = archive
        self.segments = archive.catalogue.segments(drive_id)
        if not self.segments:
            raise EgovidError(f"drive {drive_id} has no frames in the archive", "the archive is damaged")
        self._gen: Iterator[np.ndarray] | None = None
        self._seg: Segment | None = None
        self._pos = -1
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._size = cache

    def _segment_of(self, idx: int) -> Segment:
        for s in self.segments:
            if s.frame_start <= idx < s.frame_end:
                return s
        raise EgovidError(f"frame {idx} is not in the archive", "the archive is damaged")

    def get(self, idx: int) -> np.ndarray:
        idx = int(idx)
        if idx in self._cache:
            self._cache.move_to_end(idx)
            return self._cache[idx]
        seg = self._segment_of(idx)
        if self._seg is None or self._seg.id != seg.id or idx < self._pos:
            self._gen = self.archive.decode(seg, start=idx - seg.frame_start)
            self._seg, self._pos = seg, idx
        frame = None
        while self._pos <= idx:
            frame = next(self._gen)
            self._cache[self._pos] = frame
            if len(self._cache) > self._size:
                self._cache.popitem(last=False)
            self._pos += 1
        return frame


class Archive:
    """An archive folder (see the module docstring)."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        marker = self.root / MARKER
        if not marker.exists():
            raise EgovidError(f"{self.root} is not an egovid archive", "create one with `egovid dashcam init`")
        meta = json.loads(marker.read_text())
        if meta.get("format") != FORMAT_VERSION:
            raise EgovidError(f"archive format {meta.get('format')} is not supported", "upgrade egovid")
        self.meta = meta
        self.catalogue: Catalogue = open_catalogue(self.root, meta.get("catalogue"))
        self.blobs = self.root / "blobs"

    @classmethod
    def create(cls, root: str | os.PathLike, db: str | None = None) -> Archive:
        """Create an empty archive at ``root``. ``db``: None or ``sqlite`` for the embedded SQLite
        catalogue (``root/catalogue.sqlite``), or a ``postgresql://`` URL: the catalogue then lives
        in a new schema of that database and only the bitstreams in ``root``."""
        root = Path(root)
        settings = catalogue_settings(db)
        if (root / MARKER).exists():
            raise EgovidError(f"{root} is already an egovid archive", "use it, or choose another folder")
        if root.exists() and any(root.iterdir()):
            raise EgovidError(f"{root} exists and is not empty", "give a new or empty folder")
        if settings["backend"] != "sqlite":  # connect first: a bad URL leaves no folder behind
            open_catalogue(root, settings, create=True).close()
        root.mkdir(parents=True, exist_ok=True)
        (root / "blobs").mkdir(exist_ok=True)
        if settings["backend"] == "sqlite":
            open_catalogue(root, settings, create=True).close()
        meta = {"format": FORMAT_VERSION, "origin": None, "catalogue": settings}
        atomic_write_text(root / MARKER, json.dumps(meta, indent=1))
        return cls(root)

    # -- storage --------------------------------------------------------------------------------
    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        with open(self.root / ".lock", "a+") as fh:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise EgovidError(f"{self.root} is busy with another ingest", "wait for it to finish") from None
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def put_blob(self, data: bytes) -> str:
        sha = hashlib.sha256(data).hexdigest()
        path = self.blobs / sha[:2] / sha
        if not path.exists():
            path.parent.mkdir(exist_ok=True)
            atomic_write_bytes(path, data)
        return sha

    def get_blob(self, sha: str) -> bytes:
        path = self.blobs / sha[:2] / sha
        if not path.exists():
            raise EgovidError(f"bitstream {sha[:12]} is missing from {self.blobs}", "restore the archive from a backup")
        data = path.read_bytes()
        if hashlib.sha256(data).hexdigest() != sha:
            raise EgovidError(f"bitstream {sha[:12]} is corrupt", "restore the archive from a backup")
        return data

    def collect_garbage(self, *, dry_run: bool = False) -> tuple[list[Path], int]:
        """Delete the files under ``blobs/`` that no segment refers to — bitstreams and temporary
        files left by an ingest that crashed or was killed — and return them with their total size
        in bytes (``dry_run``: only list them). Holds the ingest lock and the catalogue's write lock
        throughout, so an ingest running elsewhere never loses the blobs it has just written."""
        with self.lock(), self.catalogue.transaction():
            used = {g.blob for d in self.catalogue.drives() for g in self.catalogue.segments(d.id)}
            junk = [p for p in sorted(self.blobs.rglob("*")) if p.is_file() and p.name not in used]
            size = sum(p.stat().st_size for p in junk)
            if not dry_run:
                for p in junk:
                    p.unlink()
                for d in self.blobs.iterdir():
                    if d.is_dir() and not any(d.iterdir()):
                        d.rmdir()
        return junk, size

    @property
    def origin(self) -> tuple[float, float] | None:
        o = self.meta.get("origin")
        return (o[0], o[1]) if o else None

    def _set_origin(self, lat: float, lon: float) -> None:
        self.meta["origin"] = [lat, lon]
        atomic_write_text(self.root / MARKER, json.dumps(self.meta, indent=1))

    # -- decoding -------------------------------------------------------------------------------
    def baselines(self, seg: Segment, first: int = 0) -> Callable[[int], np.ndarray] | None:
        """The baseline builder of a joint segment (None for an intra segment), for decoding that
        begins at the segment's frame ``first``."""
        if seg.mode != "joint":
            return None
        return baseline_builder(
            DriveFrames(self, int(seg.ref_drive_id)),
            seg.refmap,
            seg.params["width"],
            seg.params["height"],
            seg.align,
            first,
        )

    def decode(self, seg: Segment, start: int = 0) -> Iterator[np.ndarray]:
        """Unpadded I420 frames of a segment, from its frame ``start``: decoding begins at the
        random-access run holding it, so neither this drive nor its reference is decoded from the
        beginning."""
        blob = self.get_blob(seg.blob)
        return codec.decode_segment(blob, self.baselines(seg, codec.run_start(blob, start)), start)

    def drive_or_fail(self, key: str):
        d = self.catalogue.drive(key)
        if d is None:
            names = ", ".join(x.name for x in self.catalogue.drives()) or "none"
            raise EgovidError(f"no drive {key!r} in {self.root}", f"drives in the archive: {names}")
        return d

    def extract(
        self,
        key: str,
        out: str | os.PathLike,
        progress: Callable[[int, int], None] | None = None,
        frames: tuple[int, int] | None = None,
    ) -> Path:
        """Write a drive back as a lossless video (MKV/FFV1, or MP4 with lossless H.264), checking
        the pictures against the encoder's reconstruction: every whole segment against its digest,
        and a partly written one run by run (each random-access run has its own digest; the runs
        at the ends of the stretch are decoded whole for it).

        ``frames``: (first, end) frame numbers of the drive to write (end exclusive; default all).
        Decoding starts at the random-access run holding ``first``, in this drive and in the
        drives it refers to."""
        d = self.drive_or_fail(key)
        out = Path(out)
        ext = out.suffix.lower()
        if ext not in (".mkv", ".mp4"):
            raise EgovidError(f"cannot write {out.name}", "use an .mkv (FFV1) or .mp4 (lossless H.264) output")
        f0, f1 = frames if frames is not None else (0, d.frames)
        if not 0 <= f0 < f1 <= d.frames:
            raise EgovidError(
                f"frames {f0}-{f1 - 1} are not in drive {d.name} (frames 0-{d.frames - 1})",
                "choose a range inside the drive (see `egovid dashcam show`)",
            )
        codec_name, options = ("ffv1", None) if ext == ".mkv" else ("libx264", {"qp": "0", "preset": "ultrafast"})
        done, total = 0, f1 - f0
        with VideoWriter(
            out, d.width, d.height, d.fps, codec=codec_name, crf=None, preset=None, pix_fmt="yuv420p", options=options
        ) as w:
            for seg in self.catalogue.segments(d.id):
                if seg.frame_end <= f0 or seg.frame_start >= f1:
                    continue
                for frame in self._checked_frames(d.name, seg, max(f0, seg.frame_start), min(f1, seg.frame_end)):
                    w.write_i420(frame, done / d.fps)
                    done += 1
                    if progress:
                        progress(done, total)
        return out

    def _checked_frames(self, drive: str, seg: Segment, f0: int, f1: int) -> Iterator[np.ndarray]:
        """Frames ``f0`` … ``f1 − 1`` (drive numbering) of a segment, checked against the encoder's
        reconstruction: run by run where the segment has per-run digests (the runs at the ends
        of the stretch are decoded whole for it), else by the segment digest when all of it is
        written. A mismatch raises; the video writer then leaves no output behind."""
        n = seg.frame_end - seg.frame_start
        a, b = f0 - seg.frame_start, f1 - seg.frame_start
        refresh = int(seg.params.get("refresh") or 0)
        runs = seg.params.get("run_digests") or []
        damaged = EgovidError(
            f"drive {drive} frames {seg.frame_start}-{seg.frame_end} do not decode to what was encoded",
            "the archive or one of its reference drives is damaged",
        )
        if refresh and len(runs) == -(-n // refresh):
            k = a - a % refresh
            h = hashlib.sha256()
            for frame in self.decode(seg, k):
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
            return
        # No per-run digests (one run, or an archive written before they existed).
        h = hashlib.sha256()
        for frame in itertools.islice(self.decode(seg, a), b - a):
            codec.digest_update(h, frame)
            yield frame
        if (a, b) == (0, n) and h.hexdigest() != seg.params.get("recon_digest"):
            raise damaged

    # -- ingest ---------------------------------------------------------------------------------
    def ingest(
        self,
        video: str | os.PathLike,
        gps: str | os.PathLike,
        options: IngestOptions | None = None,
        progress: Callable[[str, int, int], None] | None = None,
    ) -> IngestReport:
        """Add a drive (see the module docstring); raises :class:`EgovidError` without changing the
        archive if anything is wrong."""
        opts = options or IngestOptions()
        vpx.EncoderSettings(q=opts.q, speed=opts.speed, gop=opts.gop, refresh=opts.refresh)  # checks them
        if opts.aligner not in ALIGNERS:
            raise EgovidError(f"unknown aligner {opts.aligner!r}", f"choose one of {', '.join(ALIGNERS)}")
        if opts.baseline_align not in BASELINE_ALIGN:
            raise EgovidError(
                f"unknown baseline alignment {opts.baseline_align!r}", f"choose one of {', '.join(BASELINE_ALIGN)}"
            )
        t_start = time.perf_counter()
        info = probe(video)
        track = read_track(gps)
        name = opts.name or Path(video).stem
        if self.catalogue.drive(name) is not None:
            raise EgovidError(f"a drive named {name!r} is already in the archive", "pass --name to choose another")
        times = frame_times(video)
        start = opts.start_utc if opts.start_utc is not None else _parse_creation_time(info.creation_time)
        if start is None:
            start = float(track.t[0])
        start += opts.gps_offset
        t_video = start + times
        _check_overlap(track, t_video, Path(video).name, Path(gps).name)
        vpx.self_test()
        if info.width % 2 or info.height % 2:
            raise EgovidError(
                f"{video} is {info.width}x{info.height}; odd sizes are not supported",
                "crop the video to even dimensions",
            )
        with self.lock():
            if self.origin is None:
                self._set_origin(float(track.lat[0]), float(track.lon[0]))
            with self.catalogue.transaction():
                return self._ingest_locked(video, gps, info, track, t_video, name, opts, progress, t_start)

    def _ingest_locked(self, video, gps, info, track, t_video, name, opts, progress, t_start) -> IngestReport:
        cat = self.catalogue
        n = len(t_video)
        origin = self.origin
        inside = (track.t >= t_video[0] - 5) & (track.t <= t_video[-1] + 5)
        fix_t = track.t[inside]
        xy = smooth_track(project(track.lat[inside], track.lon[inside], origin))
        speed, bearing = track.speed[inside], track.bearing[inside]
        drive_id = cat.add_drive(
            name,
            str(Path(video).resolve()),
            str(Path(gps).resolve()),
            float(t_video[0]),
            info.fps,
            info.width,
            info.height,
            n,
        )
        report = IngestReport(drive_id, name, n)
        # 1. Path matching and splitting.
        pad = 60.0
        near = cat.paths_near(xy[:, 0].min() - pad, xy[:, 1].min() - pad, xy[:, 0].max() + pad, xy[:, 1].max() + pad)
        paths = {pid: cat.path(pid).points for pid in near}
        matches = [match_path(pid, pts, xy, bearing, speed) for pid, pts in paths.items()]
        pieces = split_drive(matches, len(fix_t))
        pieces = self._apply_splits(pieces, paths, report)
        per_frame = track.at(t_video, origin)
        stops = stopped_frames(per_frame["speed"], per_frame["bearing"], info.fps)
        # Frame ranges of the pieces (boundaries half-way between fixes).
        bounds = [0]
        for a, b in itertools.pairwise(pieces):
            tb = 0.5 * (fix_t[a.end - 1] + fix_t[b.start])
            bounds.append(int(np.searchsorted(t_video, tb)))
        bounds.append(n)
        reader1 = iter_frames(video, i420=True)
        reader2 = iter_frames(video, i420=True)
        done = 0
        for piece, f0, f1 in zip(pieces, bounds[:-1], bounds[1:], strict=True):
            if f1 <= f0:
                continue
            t_piece = time.perf_counter()
            path_id, positions = self._piece_path(piece, xy, fix_t, t_video[f0:f1], drive_id, report)
            pr = self._encode_piece(
                video,
                info,
                drive_id,
                path_id,
                positions,
                f0,
                f1,
                reader1,
                reader2,
                per_frame,
                stops,
                opts,
                progress,
                done,
                n,
            )
            pr.seconds = time.perf_counter() - t_piece
            report.pieces.append(pr)
            done = f1
        report.seconds = time.perf_counter() - t_start
        return report

    def _apply_splits(self, pieces: list[DrivePiece], paths: dict[int, np.ndarray], report: IngestReport):
        """Split existing paths where the drive joins or leaves them (Table 15.1)."""
        cat = self.catalogue
        for piece in pieces:
            if piece.path_id is None:
                continue
            pts = paths[piece.path_id]
            cuts = split_points(piece.first_point, piece.last_point, len(pts))
            if not cuts:
                continue
            # Pieces: [0, c1], [c1, c2], [c2, end] sharing their boundary points.
            edges = [0, *cuts, len(pts) - 1]
            ids = [piece.path_id]
            for a, b in itertools.pairwise(edges):
                ids.append(cat.add_path(pts[a : b + 1], cat.path(piece.path_id).created_by))
            cat.update_path(piece.path_id, pts[: edges[1] + 1])
            offsets = [e * SPACING for e in edges]
            for seq in cat.sequences(path_id=piece.path_id):
                self._split_sequence(seq, ids, offsets)
            report.split_paths.append(piece.path_id)
            # Re-express this piece on the sub-path holding its start.
            k = int(np.searchsorted(edges, piece.first_point, side="right") - 1)
            k = min(k, len(ids) - 1)
            piece.path_id = ids[k]
            piece.closest = piece.closest - edges[k]
            piece.first_point, piece.last_point = int(piece.closest[0]), int(piece.closest[-1])
            for pid, a, b in zip(ids, edges[:-1], edges[1:], strict=False):
                paths[pid] = pts[a : b + 1]
        return pieces

    def _split_sequence(self, seq: Sequence, ids: list[int], offsets: list[float]) -> None:
        cat = self.catalogue
        part = np.clip(np.searchsorted(offsets[1:-1], seq.positions, side="right"), 0, len(ids) - 1)
        first = True
        k = 0
        while k < len(part):
            j = k
            while j < len(part) and part[j] == part[k]:
                j += 1
            pid = ids[part[k]]
            pos = seq.positions[k:j] - offsets[part[k]]
            if first:
                cat.update_sequence(seq.id, pid, seq.frame_start + k, seq.frame_start + j, pos)
                first = False
            else:
                cat.add_sequence(
                    seq.drive_id, pid, seq.frame_start + k, seq.frame_start + j, pos, seq.illum, seq.segment_id
                )
            k = j

    def _piece_path(self, piece, xy, fix_t, t_frames, drive_id, report) -> tuple[int, np.ndarray]:
        """The piece's path id (creating a new path if needed) and each frame's position on it."""
        cat = self.catalogue
        seg_xy = xy[piece.start : piece.end]
        if piece.path_id is None:
            pts = resample(seg_xy if len(seg_xy) > 1 else np.vstack([seg_xy, seg_xy + 0.1]))
            pid = cat.add_path(pts, drive_id)
            report.new_paths.append(pid)
        else:
            pid = piece.path_id
            pts = cat.path(pid).points
        # Position of each fix along the path, by projection on the polyline.
        s_fix = _project_on_polyline(pts, seg_xy)
        s_fix = np.maximum.accumulate(s_fix)
        tt = fix_t[piece.start : piece.end]
        pos = np.interp(t_frames, tt, s_fix) if len(tt) > 1 else np.full(len(t_frames), s_fix[0])
        return pid, pos.astype(np.float32)

    def _encode_piece(
        self,
        video,
        info,
        drive_id,
        path_id,
        positions,
        f0,
        f1,
        reader1,
        reader2,
        per_frame,
        stops,
        opts: IngestOptions,
        progress,
        done,
        n_total,
    ) -> PieceReport:
        cat = self.catalogue
        w, h = info.width, info.height
        k_total = f1 - f0
        settings = vpx.EncoderSettings(
            q=opts.q,
            speed=opts.speed,
            realtime=opts.realtime,
            fps=round(info.fps) or 30,
            gop=opts.gop,
            refresh=opts.refresh,
        )
        # Pass 1: illumination features and (if a reference may exist) ORB features.
        candidates = [
            s
            for s in cat.sequences(path_id=path_id)
            if s.drive_id != drive_id and _overlap(s.positions, positions) >= 0.5
        ]
        cand_drives = {s.drive_id: cat.drive(s.drive_id) for s in candidates}
        candidates = [
            s for s in candidates if (cand_drives[s.drive_id].width, cand_drives[s.drive_id].height) == (w, h)
        ]
        scorer, refiner = OrbScorer(), ScaleRefiner()
        new_feats, new_desc, new_fine, illum = [], [], [], []
        for _ in range(k_total):
            frame = next(reader1).image
            g = small_gray(frame, w, h)
            illum.append(frame_features(cv2.resize(g, (160, 90), interpolation=cv2.INTER_AREA)))
            if candidates:
                if opts.aligner.startswith("orb"):
                    new_feats.append(scorer.features(g))
                    if opts.aligner == "orb":
                        new_fine.append(refiner.features(g))
                elif opts.aligner == "seqslam":
                    from egovid.dashcam.seqslam import descriptor

                    new_desc.append(descriptor(g))
            if progress:
                progress("analyse", done + len(illum), n_total)
        illum_feat = np.mean(illum, axis=0)
        ref_seq = None
        if candidates:
            best = best_match(illum_feat, {s.id: s.illum for s in candidates})
            ref_seq = next((s for s in candidates if s.id == best), None)
        stopped = stops[f0:f1]
        refmap = np.full(k_total, -1, np.int64)
        fallbacks = 0
        align: dict = {"kind": "none"}
        ref_frames = None
        if ref_seq is not None:
            ref_frames = DriveFrames(self, ref_seq.drive_id)
            m = ref_seq.frame_end - ref_seq.frame_start
            order = np.argsort(ref_seq.positions, kind="stable")
            prior = np.interp(positions, ref_seq.positions[order], order.astype(float))
            ref_drive = cand_drives[ref_seq.drive_id]
            if opts.aligner == "gps":
                local = np.clip(np.round(prior), 0, m - 1).astype(np.int64)
            else:
                ref_gray = [small_gray(ref_frames.get(ref_seq.frame_start + j), w, h) for j in range(m)]
                if opts.aligner.startswith("orb"):
                    ref_feats = [scorer.features(g) for g in ref_gray]
                    ref_speed = np.gradient(ref_seq.positions.astype(float)) * ref_drive.fps
                    res = align_orb(
                        new_feats,
                        ref_feats,
                        prior,
                        per_frame["speed"][f0:f1],
                        np.abs(ref_speed),
                        stopped,
                        info.fps,
                        scorer,
                    )
                    if opts.aligner == "orb":
                        ref_fine = [refiner.features(g) for g in ref_gray]
                        res.refmap = refiner.refine(smooth_monotone(res.refmap), new_fine, ref_fine, stopped)
                else:
                    from egovid.dashcam.seqslam import align_seqslam, descriptor

                    res = align_seqslam(np.stack(new_desc), np.stack([descriptor(g) for g in ref_gray]), prior)
                    for k in range(1, k_total):
                        if stopped[k]:
                            res.refmap[k] = res.refmap[k - 1]
                local = res.refmap
                fallbacks = res.prior_fallbacks
                del ref_gray
            refmap = local + ref_seq.frame_start
            if opts.baseline_align != "none":
                align = self._estimate_alignment(opts.baseline_align, video, f0, f1, refmap, ref_frames, w, h, scorer)
        # Pass 2: encode.
        baselines = baseline_builder(ref_frames, refmap, w, h, align) if ref_seq is not None else None

        def frames() -> Iterator[np.ndarray]:
            for _ in range(k_total):
                yield next(reader2).image

        cb = (lambda k: progress("encode", done + k, n_total)) if progress else None
        enc = codec.encode_segment(frames(), w, h, settings, baselines, cb)
        standalone = None
        if ref_seq is not None and opts.measure_savings:
            standalone = len(codec.encode_segment(_reread(video, f0, f1), w, h, settings).blob)
        sha = self.put_blob(enc.blob)
        params_json = {
            "width": w,
            "height": h,
            "q": opts.q,
            "speed": opts.speed,
            "realtime": opts.realtime,
            "gop": opts.gop,
            "refresh": opts.refresh,
            "recon_digest": enc.recon_digest,
            "run_digests": enc.run_digests,
            "psnr_y": enc.psnr_y,
            "aligner": opts.aligner,
            "standalone_bytes": standalone,
            "path_id": path_id,
        }
        seg_id = cat.add_segment(
            drive_id,
            f0,
            f1,
            "joint" if ref_seq is not None else "intra",
            ref_seq.drive_id if ref_seq is not None else None,
            refmap,
            align,
            sha,
            len(enc.blob),
            params_json,
        )
        cat.add_sequence(drive_id, path_id, f0, f1, positions, illum_feat, seg_id)
        if opts.verify:
            seg = cat.segment(seg_id)
            h_ = hashlib.sha256()
            for frame in self.decode(seg):
                codec.digest_update(h_, frame)
            if h_.hexdigest() != enc.recon_digest:
                raise EgovidError(
                    "the decoder does not reproduce the encoder's pictures (baseline not bit-exact)",
                    "report this with the libvpx version; nothing was added to the archive",
                )
        ref_name = cat.drive(ref_seq.drive_id).name if ref_seq is not None else None
        return PieceReport(
            (f0, f1),
            path_id,
            "joint" if ref_seq is not None else "intra",
            ref_name,
            len(enc.blob),
            standalone,
            enc.psnr_y,
            int(stopped.sum()),
            fallbacks,
            0.0,
        )

    def _estimate_alignment(self, kind, video, f0, f1, refmap, ref_frames, w, h, scorer) -> dict:
        params = []
        scale = small_gray(np.zeros((h * 3 // 2, w), np.uint8), w, h).shape[1] / w
        for k, frame in enumerate(_reread(video, f0, f1)):
            ref = ref_frames.get(int(refmap[k]))
            if kind == "gain":
                params.append(codec.estimate_gain(frame[:h], ref[:h]))
            else:
                a, b = scorer.features(small_gray(frame, w, h)), scorer.features(small_gray(ref, w, h))
                p = None
                if a.desc is not None and b.desc is not None:
                    m = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(a.desc, b.desc)
                    if len(m) >= 12:
                        pa = a.pts[[x.queryIdx for x in m]]
                        pb = b.pts[[x.trainIdx for x in m]]
                        p = codec.estimate_similarity(pa, pb, scale)
                params.append(p or [4096, 0, 0, 0, 4096, 0])
        return {"kind": kind, "params": params}

    # -- reporting ------------------------------------------------------------------------------
    def report(self) -> dict:
        """Bits per path and per drive, joint vs measured standalone sizes."""
        cat = self.catalogue
        drives = {d.id: d for d in cat.drives()}
        per_path: dict[int, dict] = {}
        per_drive = []
        for d in drives.values():
            segs = cat.segments(d.id)
            total = sum(s.bytes for s in segs)
            joint = [s for s in segs if s.mode == "joint" and s.params.get("standalone_bytes")]
            jb = sum(s.bytes for s in joint)
            sb = sum(s.params["standalone_bytes"] for s in joint)
            per_drive.append(
                {
                    "drive": d.name,
                    "frames": d.frames,
                    "bytes": total,
                    "bits_per_frame": 8 * total / max(d.frames, 1),
                    "joint_frames": sum(s.frame_end - s.frame_start for s in segs if s.mode == "joint"),
                    "saving_on_joint_frames": (1 - jb / sb) if sb else None,
                    "references": sorted({drives[s.ref_drive_id].name for s in segs if s.ref_drive_id}),
                }
            )
            seg_by_id = {s.id: s for s in segs}
            for seq in cat.sequences(drive_id=d.id):
                seg = seg_by_id[seq.segment_id]
                share = (seq.frame_end - seq.frame_start) / max(seg.frame_end - seg.frame_start, 1)
                p = per_path.setdefault(
                    seq.path_id,
                    {
                        "path": seq.path_id,
                        "sequences": 0,
                        "frames": 0,
                        "bytes": 0.0,
                        "joint_bytes": 0.0,
                        "standalone_bytes": 0.0,
                    },
                )
                p["sequences"] += 1
                p["frames"] += seq.frame_end - seq.frame_start
                p["bytes"] += seg.bytes * share
                if seg.mode == "joint" and seg.params.get("standalone_bytes"):
                    p["joint_bytes"] += seg.bytes * share
                    p["standalone_bytes"] += seg.params["standalone_bytes"] * share
        paths_out = []
        for pid, p in sorted(per_path.items()):
            rec = cat.path(pid)
            paths_out.append(
                {
                    "path": pid,
                    "length_m": round(rec.length_m, 1),
                    "sequences": p["sequences"],
                    "frames": p["frames"],
                    "bytes": round(p["bytes"]),
                    "bits_per_frame": 8 * p["bytes"] / max(p["frames"], 1),
                    "saving": (1 - p["joint_bytes"] / p["standalone_bytes"]) if p["standalone_bytes"] else None,
                }
            )
        blob_bytes = sum(f.stat().st_size for f in self.blobs.rglob("*") if f.is_file())
        return {
            "archive": str(self.root),
            "drives": per_drive,
            "paths": paths_out,
            "blob_bytes": blob_bytes,
            "codec": vpx.self_test(),
        }


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


def _reread(video, f0: int, f1: int) -> Iterator[np.ndarray]:
    for fr in iter_frames(video, i420=True, max_frames=f1):
        if fr.index >= f0:
            yield fr.image


def _same_size(drive, w: int, h: int) -> bool:
    return (drive.width, drive.height) == (w, h)


def _overlap(a: np.ndarray, b: np.ndarray) -> float:
    """Share of the position range of ``b`` covered by ``a``."""
    if len(a) == 0 or len(b) == 0:
        return 0.0
    lo, hi = max(a.min(), b.min()), min(a.max(), b.max())
    span = max(float(b.max() - b.min()), 1e-6)
    return max(0.0, float(hi - lo)) / span


def _project_on_polyline(pts: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Arclength (metres) of the closest point of a polyline to each of ``xy``."""
    seg = np.diff(pts, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    out = np.empty(len(xy))
    for i, p in enumerate(xy):
        rel = p - pts[:-1]
        t = np.clip(np.einsum("ij,ij->i", rel, seg) / np.maximum(seg_len**2, 1e-12), 0, 1)
        proj = pts[:-1] + seg * t[:, None]
        d = np.hypot(*(proj - p).T)
        k = int(np.argmin(d))
        out[i] = cum[k] + t[k] * seg_len[k]
    return out


def _check_overlap(track: GpsTrack, t_video: np.ndarray, video_name: str, gps_name: str) -> None:
    lo, hi = max(track.t[0], t_video[0]), min(track.t[-1], t_video[-1])
    span = max(t_video[-1] - t_video[0], 1e-6)
    covered = max(0.0, hi - lo) / span
    if covered < 0.8:
        v0 = dt.datetime.fromtimestamp(t_video[0], dt.UTC).isoformat(timespec="seconds")
        g0 = dt.datetime.fromtimestamp(track.t[0], dt.UTC).isoformat(timespec="seconds")
        raise EgovidError(
            f"GPS track {gps_name} (from {g0}) covers {100 * covered:.0f}% of video {video_name} (from {v0})",
            "give the GPS log of this drive, or shift it with --gps-offset SECONDS / --start ISO-TIME",
        )
