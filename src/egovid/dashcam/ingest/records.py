"""What the ingest stages hand each other: small, typed, picklable records (a stage may run in
another process, a Dask worker)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from egovid.core.video import VideoInfo
from egovid.dashcam.route.tracks import GpsTrack


@dataclass(frozen=True)
class DriveInput:
    """One drive to ingest: its video, its GPS track (None: the file beside the video with the same
    name and a .gpx, .nmea or .csv extension), the name it gets in the archive (default: the video's
    file name), its UTC start if the video's metadata lacks it (seconds since the epoch), a shift of
    that start in seconds, and ``token``, the id of this ingest (a commit that finds its token in
    the catalogue already happened: a retried task returns the committed drive).

    Hooks for readers of other GPS sources and for catalogue tables of their own: ``track``, an
    already-read track (embedded GPS; then ``gps_label`` names it in the catalogue instead of a
    file), and ``extra``, a picklable object whose ``commit(catalogue, drive_id)`` the commit calls
    in its transaction right after adding the drive. A drive recorded as several files (a trip of
    loop-recording files, route/trips.py) lists them in ``parts``, in order, with the UTC start of
    each in ``part_starts``: they are decoded back to back as one video. ``probe``: the drive's
    stage *probe* already made (by whoever examined its files: the fleet's
    :func:`~egovid.dashcam.ingest.fleet.drive_input`), so that the files are not demuxed again.
    ``append_at``: the video continues the archived drive ``name``, whose frames so far it
    expects (its frames are appended after them; a commit that finds another count fails).
    ``channel``: the camera the video is (``front``, ``rear``, …): it is coded only against
    older drives of the same camera."""

    video: Path
    gps: Path | None = None
    name: str | None = None
    start_utc: float | None = None
    gps_offset: float = 0.0
    token: str = ""
    track: GpsTrack | None = None
    gps_label: str = ""
    extra: object | None = None
    parts: tuple[Path, ...] = ()
    part_starts: tuple[float, ...] = ()
    probe: VideoProbe | None = None
    append_at: int | None = None
    channel: str = "front"

    @property
    def files(self) -> tuple[Path, ...]:
        """The drive's files in order (``parts``, or just ``video``)."""
        return tuple(self.parts) or (Path(self.video),)

    @property
    def drive_name(self) -> str:
        return self.name or Path(self.video).stem


@dataclass
class VideoProbe:
    """Stage *probe*: the video described (``info``), the presentation time of every frame
    (``times``, (N,) seconds from the first frame, from the demuxer alone) and the UTC start of
    frame 0 (seconds since the epoch; None when neither the metadata nor ``--start`` tells)."""

    video: Path
    info: VideoInfo
    times: np.ndarray
    start_utc: float | None

    @property
    def frames(self) -> int:
        return len(self.times)


@dataclass
class DriveTrack:
    """Stage *track*: the GPS fixes over the video's span (±5 s), the UTC time of every frame, and
    per frame the speed (m/s), bearing (degrees) and whether the car stood still (thesis §15.1)."""

    gps_source: Path
    fixes: GpsTrack
    frame_utc: np.ndarray
    speed: np.ndarray
    bearing: np.ndarray
    stopped: np.ndarray

    @property
    def first_fix(self) -> tuple[float, float]:
        return float(self.fixes.lat[0]), float(self.fixes.lon[0])


@dataclass(frozen=True)
class Candidate:
    """An older drive's sequence on a piece's path, a possible baseline: drive, frames
    [start, end) of that drive, each frame's position along the piece's path (metres), its
    illumination features (illumination.frame_features averaged), and the drive's frame rate."""

    drive_id: int
    drive_name: str
    frame_start: int
    frame_end: int
    positions: np.ndarray
    illum: np.ndarray
    fps: float


@dataclass
class PiecePlan:
    """Stage *split*: frames [f0, f1) of the drive that lie on one path (``path``: the id of an
    existing path, or the key of one this ingest creates), each frame's position along it (metres)
    and the older drives on it that may serve as the baseline (same frame size, covering at least
    half of the piece)."""

    index: int
    frames: tuple[int, int]
    path: int | str
    positions: np.ndarray
    candidates: list[Candidate] = field(default_factory=list)

    @property
    def length(self) -> int:
        return self.frames[1] - self.frames[0]


@dataclass
class SplitPlan:
    """Stage *split*: the drive cut into pieces, one per path, and the catalogue edits that go with
    it (paths split where the drive joins or leaves them, new paths), recorded as operations that
    the commit replays in its transaction; ``references``: the segments needed to decode every
    candidate baseline, by drive (the stages that see pictures read no catalogue). ``origin``: the
    metric plane's origin the plan was made in; ``new_origin``: the archive had none, this drive's
    commit sets it."""

    origin: tuple[float, float]
    new_origin: bool
    ops: list[tuple] = field(default_factory=list)
    pieces: list[PiecePlan] = field(default_factory=list)
    references: dict[int, list] = field(default_factory=dict)  # candidates' segments, chains included
    new_paths: list[str] = field(default_factory=list)
    split_paths: list[int] = field(default_factory=list)


@dataclass
class EncodedPiece:
    """Stages *baseline*, *align* and *encode* for one piece: the segment to record (its blob is
    already in the blob store) and what the report tells about it."""

    frames: tuple[int, int]
    mode: str  # "intra" | "joint"
    ref_drive_id: int | None
    ref_drive_name: str | None
    refmap: np.ndarray
    align: dict
    blob: str
    nbytes: int
    params: dict
    illum: np.ndarray
    psnr_y: float
    standalone_bytes: int | None
    stopped_frames: int
    prior_fallbacks: int
    seconds: float = 0.0
    peak_frames_held: int = 0

    def report(self, path_id: int) -> PieceReport:
        """What the ingest's report says about the piece, now on path ``path_id``."""
        return PieceReport(
            self.frames,
            path_id,
            self.mode,
            self.ref_drive_name,
            self.nbytes,
            self.standalone_bytes,
            self.psnr_y,
            self.stopped_frames,
            self.prior_fallbacks,
            self.seconds,
            self.peak_frames_held,
        )


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
    peak_frames_held: int = 0  # frames of both drives in memory at once, at most

    @property
    def saving(self) -> float | None:
        if not self.standalone_bytes:
            return None
        return 1.0 - self.bytes / self.standalone_bytes


@dataclass
class IngestReport:
    """Stage *commit*: the drive as the archive now holds it, and how long each stage took
    (``stage_seconds``, wall-clock seconds summed over the pieces); ``encoder_restarts``: each
    piece coded again after an encoder fault, and why (:mod:`egovid.dashcam.ingest.watchdog`)."""

    drive_id: int
    name: str
    frames: int
    pieces: list[PieceReport] = field(default_factory=list)
    new_paths: list[int] = field(default_factory=list)
    split_paths: list[int] = field(default_factory=list)
    seconds: float = 0.0
    stage_seconds: dict[str, float] = field(default_factory=dict)
    encoder_restarts: list[str] = field(default_factory=list)

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def to_dict(self) -> dict:
        d = asdict(self)
        d["fps"] = self.fps
        for p, pr in zip(d["pieces"], self.pieces, strict=True):
            p["saving"] = pr.saving
        return d
