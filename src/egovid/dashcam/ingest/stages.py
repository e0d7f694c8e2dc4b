"""The stages of an ingest that need no pictures: probe, track, split, choose baseline, commit.

Each is a function of small typed records (records.py) and can run on its own, in a test or in
another process. The stages that see pictures (align, encode) are in piece.py and stream the one
decode pass (frames.py). Only :func:`commit` writes the catalogue, in one transaction with
everything the ingest decided: the metric plane's origin (for the first drive), the drive, the
paths it splits or creates, its segments and sequences.
"""

from __future__ import annotations

import datetime as dt
import functools
import itertools
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.times import creation_time_utc
from egovid.core.video import VideoInfo, frame_times, probe
from egovid.dashcam.align.illumination import best_match
from egovid.dashcam.align.stops import stopped_frames
from egovid.dashcam.archive.catalogue import Catalogue, Drive, Sequence
from egovid.dashcam.archive.fleetstore import drive_camera
from egovid.dashcam.archive.store import ORIGIN_META, Archive
from egovid.dashcam.extract import reference_segments
from egovid.dashcam.ingest.records import (
    Candidate,
    DriveInput,
    DriveTrack,
    EncodedPiece,
    IngestReport,
    PiecePlan,
    PieceReport,
    SplitPlan,
    VideoProbe,
)
from egovid.dashcam.route.clock import MIN_COVER, coverage
from egovid.dashcam.route.paths import match_path, resample, smooth_track, split_drive, split_points, split_positions
from egovid.dashcam.route.plane import project_on_polyline, range_overlap
from egovid.dashcam.route.tracks import GpsTrack, gps_beside, project, read_track

NEAR = 60.0  # metres around the drive searched for known paths
_CHUNK = 16  # fixes per spatial query


# -- probe -------------------------------------------------------------------------------------


def probe_stage(inp: DriveInput) -> VideoProbe:
    """Describe the video: size, frame rate, each frame's time (core.video.frame_times: demuxed,
    not decoded), its UTC start (``start_utc``, else the container's plausible ``creation_time``,
    else unknown). A drive whose files were examined already carries this (``inp.probe``, made by
    :func:`~egovid.dashcam.ingest.fleet.drive_input`): then no file is opened again."""
    if inp.probe is not None:
        return inp.probe
    info = probe(inp.video)
    check_frame_size(inp.video, info)
    start = inp.start_utc if inp.start_utc is not None else creation_time_utc(info.creation_time)
    if inp.parts:  # a trip: the files' frames on one clock, the gaps between the files kept
        starts = inp.part_starts
        times = np.concatenate([frame_times(f) + (s - starts[0]) for f, s in zip(inp.parts, starts, strict=True)])
    else:
        times = frame_times(inp.video)
    return VideoProbe(Path(inp.video), info, times, start)


def check_frame_size(video: str | os.PathLike, info: VideoInfo) -> None:
    """Refuse a video of odd width or height (the codec's 4:2:0 pictures need even sizes)."""
    if info.width % 2 or info.height % 2:
        raise EgovidError(
            f"{Path(video).name} is {info.width}x{info.height}; odd sizes are not supported",
            "crop the video to even dimensions",
        )


# -- track -------------------------------------------------------------------------------------


def track_stage(inp: DriveInput, vp: VideoProbe) -> DriveTrack:
    """Read the GPS track, place the video on its clock, check it covers the video, and derive
    per-frame speed, bearing and stops."""
    if inp.track is not None:
        track, gps = inp.track, Path(inp.gps_label or inp.track.source or "embedded")
    else:
        gps = Path(inp.gps) if inp.gps is not None else gps_beside(Path(inp.video))
        if gps.is_dir():
            raise EgovidError(f"--gps {gps} is a folder", "give the drive's GPS file (GPX, NMEA or CSV)")
        track = read_track(gps)
    start = vp.start_utc if vp.start_utc is not None else float(track.t[0])
    t_video = start + inp.gps_offset + vp.times
    if not np.all(np.isfinite(t_video)):
        raise EgovidError(f"the start time of {vp.video.name} is not a finite time", "check --start and --gps-offset")
    check_coverage(track, t_video, vp.video.name, gps.name)
    fixes = track.between(t_video[0] - 5, t_video[-1] + 5)
    speed, bearing = track.motion_at(t_video)
    stopped = stopped_frames(speed, bearing, vp.info.fps)
    return DriveTrack(gps, fixes, t_video, speed, bearing, stopped)


def check_coverage(track: GpsTrack, t_video: np.ndarray, video_name: str, gps_name: str) -> None:
    """Refuse a track that covers less than :data:`~egovid.dashcam.route.clock.MIN_COVER` (80 %) of
    the video's time span (``t_video``: UTC seconds of every frame)."""
    covered = coverage(track, float(t_video[0]), float(t_video[-1] - t_video[0]))
    if covered < MIN_COVER:
        v0 = dt.datetime.fromtimestamp(t_video[0], dt.UTC).isoformat(timespec="seconds")
        g0 = dt.datetime.fromtimestamp(track.t[0], dt.UTC).isoformat(timespec="seconds")
        raise EgovidError(
            f"GPS track {gps_name} (from {g0}) covers {100 * covered:.0f}% of video {video_name} (from {v0})",
            "give the GPS log of this drive, or shift it with --gps-offset SECONDS / --start ISO-TIME",
        )


def track_xy(track: DriveTrack, origin: tuple[float, float]) -> np.ndarray:
    """The fixes on the archive's metric plane (metres), smoothed (paths.smooth_track)."""
    return smooth_track(project(track.fixes.lat, track.fixes.lon, origin))


def paths_along(cat: Catalogue, xy: np.ndarray, pad: float = NEAR) -> list[int]:
    """Ids of the known paths within about ``pad`` metres of the polyline ``xy`` (queried chunk by
    chunk, so a long drive does not pull in every path of its bounding box)."""
    found: set[int] = set()
    for a in range(0, max(len(xy) - 1, 1), _CHUNK):
        c = xy[a : a + _CHUNK + 1]
        lo, hi = c.min(axis=0) - pad, c.max(axis=0) + pad
        found.update(cat.paths_near(lo[0], lo[1], hi[0], hi[1]))
    return sorted(found)


# -- split -------------------------------------------------------------------------------------


class PathEditor(Protocol):
    """Paths and their sequences, as the split sees and edits them: the catalogue itself (at
    commit) or an in-memory copy (while planning). Path keys are ids or keys of planned paths."""

    def points(self, key) -> np.ndarray: ...

    def created_by(self, key) -> int | None: ...

    def add_path(self, points: np.ndarray, created_by: int | None): ...

    def set_points(self, key, points: np.ndarray) -> None: ...

    def sequences(self, key) -> list: ...

    def move_sequence(self, seq, key, frame_start: int, frame_end: int, positions: np.ndarray) -> None: ...

    def add_sequence(self, like, key, frame_start: int, frame_end: int, positions: np.ndarray) -> None: ...


def split_path(ed: PathEditor, key, edges: list[int]) -> list:
    """Cut the path ``key`` at the point indices ``edges`` (0, cut 1, …, last point): it keeps the
    first part, each further part becomes a new path, and every sequence on it is cut with it
    (Table 15.1). Returns the keys of the parts in order."""
    pts = ed.points(key)
    owner = ed.created_by(key)
    keys = [key] + [ed.add_path(pts[a : b + 1], owner) for a, b in list(itertools.pairwise(edges))[1:]]
    ed.set_points(key, pts[: edges[1] + 1])
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    offsets = [float(cum[e]) for e in edges]
    for seq in list(ed.sequences(key)):
        for i, (part, k0, k1, pos) in enumerate(split_positions(seq.positions, offsets)):
            f0, f1 = seq.frame_start + k0, seq.frame_start + k1
            if i == 0:
                ed.move_sequence(seq, keys[part], f0, f1, pos)
            else:
                ed.add_sequence(seq, keys[part], f0, f1, pos)
    return keys


@dataclass
class _SeqCopy:
    drive_id: int
    frame_start: int
    frame_end: int
    positions: np.ndarray
    illum: np.ndarray


class PlannedPaths:
    """An in-memory copy of the paths near a drive and their sequences; edits are recorded as
    operations for the commit to replay (planned paths get keys ``p1``, ``p2``, …)."""

    def __init__(self, cat: Catalogue, path_ids: list[int]) -> None:
        self._points: dict = {}
        self._owner: dict = {}
        self._seqs: dict = {}
        for pid in path_ids:
            rec = cat.path(pid)
            self._points[pid], self._owner[pid] = rec.points, rec.created_by
            self._seqs[pid] = [
                _SeqCopy(s.drive_id, s.frame_start, s.frame_end, s.positions, s.illum)
                for s in cat.sequences(path_id=pid)
            ]
        self._n = 0

    def points(self, key) -> np.ndarray:
        return self._points[key]

    def created_by(self, key):
        return self._owner[key]

    def add_path(self, points, created_by):
        self._n += 1
        key = f"p{self._n}"
        self._points[key], self._owner[key], self._seqs[key] = np.asarray(points), created_by, []
        return key

    def set_points(self, key, points) -> None:
        self._points[key] = np.asarray(points)

    def sequences(self, key) -> list:
        return self._seqs.get(key, [])

    def move_sequence(self, seq, key, frame_start, frame_end, positions) -> None:
        for lst in self._seqs.values():
            if seq in lst:
                lst.remove(seq)
        self._seqs[key].append(_SeqCopy(seq.drive_id, frame_start, frame_end, positions, seq.illum))

    def add_sequence(self, like, key, frame_start, frame_end, positions) -> None:
        self._seqs[key].append(_SeqCopy(like.drive_id, frame_start, frame_end, positions, like.illum))


class CataloguePaths:
    """The catalogue as a :class:`PathEditor` (inside the commit's transaction). ``keys`` maps the
    keys of planned paths to the ids they got; ``drive_id`` is the drive being committed."""

    def __init__(self, cat: Catalogue, drive_id: int) -> None:
        self.cat, self.drive_id = cat, drive_id
        self.keys: dict = {}

    def id(self, key) -> int:
        return self.keys[key] if isinstance(key, str) else int(key)

    def points(self, key) -> np.ndarray:
        return self.cat.path(self.id(key)).points

    def created_by(self, key):
        return self.cat.path(self.id(key)).created_by

    def add_path(self, points, created_by) -> int:
        return self.cat.add_path(points, created_by)

    def set_points(self, key, points) -> None:
        self.cat.update_path(self.id(key), points)

    def sequences(self, key) -> list[Sequence]:
        return self.cat.sequences(path_id=self.id(key))

    def move_sequence(self, seq, key, frame_start, frame_end, positions) -> None:
        self.cat.update_sequence(seq.id, self.id(key), frame_start, frame_end, positions)

    def add_sequence(self, like, key, frame_start, frame_end, positions) -> None:
        self.cat.add_sequence(
            like.drive_id, self.id(key), frame_start, frame_end, positions, like.illum, like.segment_id
        )


def split_stage(
    cat: Catalogue,
    track: DriveTrack,
    origin: tuple[float, float],
    new_origin: bool,
    size: tuple[int, int],
    channel: str = "front",
) -> SplitPlan:
    """Cut the drive into pieces, one per path (§15.1): match its fixes against the known paths
    near it, split paths where it joins or leaves them (Table 15.1), make new paths of the rest;
    for each piece, each frame's position along its path and the older drives on that path that
    may be its baseline (frame ``size`` (width, height) equal, covering at least half of it, of
    the same camera ``channel``: a rear camera is coded against older rear recordings). Reads
    the catalogue, writes nothing: the edits are recorded in the plan for :func:`commit`."""
    xy = track_xy(track, origin)
    near = paths_along(cat, xy)
    ed = PlannedPaths(cat, near)
    plan = SplitPlan(origin, new_origin)
    matches = [match_path(pid, ed.points(pid), xy, track.fixes.bearing, track.fixes.speed) for pid in near]
    pieces = split_drive(matches, len(track.fixes.t))
    keys = _cut_known_paths(ed, plan, pieces, near)
    bounds = _frame_bounds(pieces, track.fixes.t, track.frame_utc)
    same = functools.cache(lambda drive_id: drive_camera(cat, drive_id) == channel)
    for piece, key, f0, f1 in zip(pieces, keys, bounds[:-1], bounds[1:], strict=True):
        if f1 > f0:
            plan.pieces.append(_piece_plan(cat, ed, plan, track, xy, piece, key, (f0, f1), size, same))
    plan.references = reference_segments(cat, {c.drive_id for p in plan.pieces for c in p.candidates})
    return plan


def without_drive(plan: SplitPlan, drive: Drive | None) -> SplitPlan:
    """The plan with ``drive`` no candidate baseline of any piece (a file appended to a drive is
    never coded against that drive: it would refer to itself)."""
    if drive is None:
        return plan
    for p in plan.pieces:
        p.candidates = [c for c in p.candidates if c.drive_id != drive.id]
    return plan


def _cut_known_paths(ed: PlannedPaths, plan: SplitPlan, pieces: list, near: list[int]) -> list:
    """Split the known paths where the drive's pieces join or leave them (recorded in ``plan``);
    the key of each piece's path (None for a piece on no known path)."""
    # Parts of each known path after the splits so far, (key, first point, points) in the path's
    # original numbering, so that a drive passing one path twice cuts the right part.
    parts: dict[int, list[tuple]] = {pid: [(pid, 0, len(ed.points(pid)))] for pid in near}
    keys: list = []
    for piece in pieces:
        if piece.path_id is None:
            keys.append(None)
            continue
        held = parts[piece.path_id]
        i = max(j for j, p in enumerate(held) if p[1] <= piece.first_point or j == 0)
        key, p0, m = held[i]
        first, last = piece.first_point - p0, min(piece.last_point - p0, m - 1)
        cuts = split_points(first, last, m)
        if cuts:
            edges = [0, *cuts, m - 1]
            sub = split_path(ed, key, edges)
            plan.ops.append(("split", key, edges, sub))
            if isinstance(key, int):
                plan.split_paths.append(key)
            held[i : i + 1] = [(k, p0 + a, b - a + 1) for k, (a, b) in zip(sub, itertools.pairwise(edges), strict=True)]
            key = sub[min(int(np.searchsorted(edges, first, side="right") - 1), len(sub) - 1)]
        keys.append(key)
    return keys


def _frame_bounds(pieces: list, fix_t: np.ndarray, t_video: np.ndarray) -> list[int]:
    """Frame ranges of the pieces, as boundaries 0, …, n (half-way between the fixes either side)."""
    inner = [
        int(np.searchsorted(t_video, 0.5 * (fix_t[a.end - 1] + fix_t[b.start]))) for a, b in itertools.pairwise(pieces)
    ]
    return [0, *inner, len(t_video)]


def _piece_plan(
    cat: Catalogue,
    ed: PlannedPaths,
    plan: SplitPlan,
    track: DriveTrack,
    xy: np.ndarray,
    piece,
    key,
    frames: tuple[int, int],
    size: tuple[int, int],
    same_camera=lambda _drive_id: True,
) -> PiecePlan:
    """One piece: its path (a new one, recorded in ``plan``, where ``key`` is None), each frame's
    position along it (metres) and the older drives on it that may be its baseline (of the same
    size, and of the same camera: ``same_camera(drive_id)``)."""
    f0, f1 = frames
    seg_xy = xy[piece.start : piece.end]
    if key is None:
        key = ed.add_path(resample(seg_xy if len(seg_xy) > 1 else np.vstack([seg_xy, seg_xy + 0.1])), None)
        plan.ops.append(("new", key, ed.points(key)))
        plan.new_paths.append(key)
    # Position of each fix along the path, by projection on the polyline.
    s_fix = np.maximum.accumulate(project_on_polyline(ed.points(key), seg_xy))
    tt = track.fixes.t[piece.start : piece.end]
    t_video = track.frame_utc[f0:f1]
    pos = (np.interp(t_video, tt, s_fix) if len(tt) > 1 else np.full(f1 - f0, s_fix[0])).astype(np.float32)
    cands = []
    for s in ed.sequences(key):
        if range_overlap(s.positions, pos) < 0.5 or not same_camera(s.drive_id):
            continue
        d = cat.drive(s.drive_id)
        if (d.width, d.height) == size:
            cands.append(Candidate(d.id, d.name, s.frame_start, s.frame_end, s.positions, s.illum, d.fps))
    return PiecePlan(len(plan.pieces), frames, key, pos, cands)


# -- choose baseline ---------------------------------------------------------------------------


def choose_baseline(illum: np.ndarray, candidates: list[Candidate]) -> Candidate | None:
    """The candidate whose light is most like the piece's (§15.3.2: per-quadrant ranks summed), or
    None (the piece becomes a root) when there is none or none is close enough."""
    if not candidates:
        return None
    best = best_match(illum, {i: c.illum for i, c in enumerate(candidates)})
    return candidates[best] if best is not None else None


# -- commit ------------------------------------------------------------------------------------


def commit(
    archive: Archive,
    inp: DriveInput,
    vp: VideoProbe,
    track: DriveTrack,
    plan: SplitPlan,
    encoded: list[EncodedPiece],
) -> IngestReport:
    """Record the drive in one catalogue transaction: the origin (first drive), the drive, the
    planned path edits, a segment and a sequence per piece. A commit that finds its ``token`` done
    returns that drive's report (a retried task). Raises :class:`EgovidError` (and changes nothing)
    when the drive's name is taken. A video appended to a drive (``inp.append_at``) adds its
    frames after the drive's: its segments and sequences are shifted by that many frames."""
    cat = archive.catalogue
    with cat.transaction():
        if inp.token and (done := cat.get_meta(f"ingest:{inp.token}")) is not None:
            return committed_report(archive, int(done))
        if inp.append_at is None:
            drive_id, at = _add_drive(archive, inp, vp, track, plan.origin), 0
        else:
            drive_id, at = _extend_drive(archive, inp, vp), inp.append_at
        ed = _replay_paths(cat, plan, drive_id)
        report = IngestReport(drive_id, inp.drive_name, vp.frames)
        report.split_paths = list(plan.split_paths)
        report.new_paths = [ed.keys[k] for k in plan.new_paths]
        for piece, enc in zip(plan.pieces, encoded, strict=True):
            path_id = ed.id(piece.path)
            params = {**enc.params, "path_id": path_id}
            frames = (enc.frames[0] + at, enc.frames[1] + at)
            seg_id = cat.add_segment(
                drive_id, *frames, enc.mode, enc.ref_drive_id, enc.refmap, enc.align, enc.blob, enc.nbytes, params
            )
            cat.add_sequence(drive_id, path_id, *frames, piece.positions, enc.illum, seg_id)
            report.pieces.append(enc.report(path_id))
        if inp.token:
            cat.set_meta(f"ingest:{inp.token}", str(drive_id))
    return report


def _add_drive(archive: Archive, inp: DriveInput, vp: VideoProbe, track: DriveTrack, origin) -> int:
    """The drive's row (and the origin for the first drive, and the rows of ``inp.extra``), inside
    the commit's transaction; its id."""
    cat = archive.catalogue
    if cat.drive(inp.drive_name) is not None:
        raise EgovidError(
            f"a drive named {inp.drive_name!r} is already in the archive", "pass --name to choose another"
        )
    current = archive.origin
    if current is None:
        cat.set_meta(ORIGIN_META, json.dumps(list(origin)))
    elif not np.allclose(current, origin, rtol=0, atol=1e-12):
        raise EgovidError("another ingest set the archive's origin meanwhile", "run the ingest again")
    gps = track.gps_source
    drive_id = cat.add_drive(
        inp.drive_name,
        str(vp.video.resolve()),
        str(gps.resolve()) if gps.exists() else str(gps),
        float(track.frame_utc[0]),
        vp.info.fps,
        vp.info.width,
        vp.info.height,
        vp.frames,
    )
    if inp.extra is not None:
        inp.extra.commit(cat, drive_id)
    return drive_id


def _extend_drive(archive: Archive, inp: DriveInput, vp: VideoProbe) -> int:
    """The drive ``inp`` continues, its frame count raised by the video's (and the rows of
    ``inp.extra``), inside the commit's transaction; its id. Fails, changing nothing, when the
    drive is gone or no longer ends where the ingest planned (another ingest appended meanwhile)."""
    cat = archive.catalogue
    d = cat.drive(inp.drive_name)
    if d is None or d.frames != inp.append_at:
        raise EgovidError(f"drive {inp.drive_name!r} changed while the file was being appended", "run the ingest again")
    if (d.width, d.height) != (vp.info.width, vp.info.height):
        raise EgovidError(f"{vp.video.name} has another frame size than drive {d.name!r}", "ingest it with --no-join")
    cat.set_drive_frames(d.id, d.frames + vp.frames)
    if inp.extra is not None:
        inp.extra.commit(cat, d.id)
    return d.id


def _replay_paths(cat: Catalogue, plan: SplitPlan, drive_id: int) -> CataloguePaths:
    """The plan's path edits on the catalogue (inside the commit's transaction); the editor maps
    the planned paths' keys to the ids they got."""
    ed = CataloguePaths(cat, drive_id)
    for op in plan.ops:
        if op[0] == "split":
            _, key, edges, planned = op
            for k, real in zip(planned, split_path(ed, key, edges), strict=True):
                if isinstance(k, str):
                    ed.keys[k] = real
        else:  # ("new", key, points)
            ed.keys[op[1]] = cat.add_path(op[2], drive_id)
    return ed


def committed_report(archive: Archive, drive_id: int) -> IngestReport:
    """The report of a drive already in the archive, rebuilt from the catalogue."""
    cat = archive.catalogue
    d = cat.drive(drive_id)
    rep = IngestReport(d.id, d.name, d.frames)
    for g in cat.segments(d.id):
        ref = cat.drive(g.ref_drive_id).name if g.ref_drive_id else None
        rep.pieces.append(
            PieceReport(
                (g.frame_start, g.frame_end),
                int(g.params.get("path_id", 0)),
                g.mode,
                ref,
                g.bytes,
                g.params.get("standalone_bytes"),
                float(g.params.get("psnr_y", float("nan"))),
                int(g.params.get("stopped_frames", 0)),
                int(g.params.get("prior_fallbacks", 0)),
                0.0,
            )
        )
    return rep
