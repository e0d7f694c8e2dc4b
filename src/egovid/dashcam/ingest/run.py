"""Running the stages for a drive: take the locks, plan, stream the pictures, commit; and many
drives as one batch on the task engine.

:func:`ingest_drive` is the whole ingest of one drive, in this process; :func:`plan_batch` and
:func:`ingest_many` run many, each as a task (a worker process, a Dask worker). Files become
drives in :func:`egovid.dashcam.ingest.videos.ingest_videos`, the route every caller takes. The
locks (locks.py) are taken before the plan reads the paths and held until the
commit: the archive lock shared, and the areas the drive crosses and every path it may split,
exclusively. So a drive on a road another ingest is adding waits for that commit and then finds
it as its baseline, while drives elsewhere run at the same time.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

from egovid.core.engine import EngineConfig, run_tasks
from egovid.core.errors import EgovidError
from egovid.dashcam.archive.locks import ORIGIN_KEY, AreaSession, cell_keys
from egovid.dashcam.archive.store import Archive, ArchiveSpec
from egovid.dashcam.codec import registry
from egovid.dashcam.codec.segment import EncoderFaultError
from egovid.dashcam.extract import SegmentSnapshot
from egovid.dashcam.ingest.frames import decode_once
from egovid.dashcam.ingest.options import IngestOptions
from egovid.dashcam.ingest.piece import encode_piece
from egovid.dashcam.ingest.records import DriveInput, DriveTrack, IngestReport
from egovid.dashcam.ingest.stages import (
    NEAR,
    commit,
    paths_along,
    probe_stage,
    split_stage,
    track_stage,
    track_xy,
    without_drive,
)
from egovid.dashcam.ingest.watchdog import EncoderWatch

Progress = Callable[[str, int, int], None]


def lock_areas(archive: Archive, session: AreaSession, track: DriveTrack) -> tuple[tuple[float, float], bool]:
    """Hold the areas the drive crosses and those of every known path near it; returns the
    metric plane's origin to plan in and whether this drive sets it (the archive has none yet: then
    the ``origin`` area is held too, so two first drives cannot pick two origins)."""
    while True:
        origin = archive.origin
        new = origin is None
        if new:
            session.acquire({ORIGIN_KEY})
            origin = archive.origin
            new = origin is None
            if new:
                origin = track.first_fix
        xy = track_xy(track, origin)
        keys = cell_keys(xy, pad=NEAR)
        for pid in paths_along(archive.catalogue, xy):
            keys |= cell_keys(archive.catalogue.path(pid).points)
        if keys <= session.keys:
            return origin, new
        session.acquire(keys)


def ingest_drive(
    archive: Archive,
    inp: DriveInput,
    options: IngestOptions | None = None,
    progress: Progress | None = None,
    *,
    watch: EncoderWatch | None = None,
) -> IngestReport:
    """Ingest one drive: probe -> track -> (locks) -> split -> per piece: baseline, align, encode
    -> commit. Raises :class:`EgovidError` without changing the catalogue if anything is wrong; a
    crash leaves at most unreferenced blobs (``egovid dashcam gc``).

    ``watch``: how the encoders are watched (:class:`~egovid.dashcam.ingest.watchdog.EncoderWatch`:
    a piece whose encoder stops responding or breaks its stream is coded again, from a fresh
    decode, ``watch.retries`` times; then the drive is refused with an
    :class:`~egovid.dashcam.codec.segment.EncoderFaultError`; the report lists the retries)."""
    opts = (options or IngestOptions()).check()
    t_start = time.perf_counter()
    vp = probe_stage(inp)
    track = track_stage(inp, vp)
    if inp.append_at is None and archive.catalogue.drive(inp.drive_name) is not None:
        raise EgovidError(
            f"a drive named {inp.drive_name!r} is already in the archive", "pass --name to choose another"
        )
    registry.describe()  # every codec backend round-trips, before anything is written
    size = (vp.info.width, vp.info.height)
    clock: dict[str, float] = {}
    with archive.locks.ingest(on_wait=(lambda _k: progress("wait", 0, 1)) if progress else None) as session:
        t0 = time.perf_counter()
        origin, new_origin = lock_areas(archive, session, track)
        plan = split_stage(archive.catalogue, track, origin, new_origin, size, inp.channel)
        if inp.append_at is not None:  # never coded against the drive it continues
            plan = without_drive(plan, archive.catalogue.drive(inp.drive_name))
        clock["split"] = time.perf_counter() - t0
        refs = SegmentSnapshot(archive.blobs, plan.references)
        watch = watch or EncoderWatch()
        frames = decode_once(inp.files, *size, clock)
        encoded, restarts = [], []
        try:
            for piece in plan.pieces:
                for attempt in range(watch.retries + 1):
                    try:
                        at = piece.frames[0]
                        args = (refs, piece, frames, track, vp.info.fps, size, opts, progress, at, vp.frames, clock)
                        encoded.append(encode_piece(*args, watch))
                        break
                    except EncoderFaultError as exc:
                        if attempt == watch.retries:
                            raise type(exc)(
                                f"{exc.problem} (piece {piece.index}, {attempt + 1} tries); nothing of "
                                f"{inp.drive_name!r} was stored",
                                exc.fix,
                            ) from None
                        restarts.append(f"piece {piece.index}: {exc.problem}")
                        frames.close()  # a fresh decode from the piece's first frame
                        frames = decode_once(inp.files, *size, clock, start=piece.frames[0])
        finally:
            frames.close()
        t0 = time.perf_counter()
        report = commit(archive, inp, vp, track, plan, encoded)
        clock["commit"] = time.perf_counter() - t0
    report.seconds = time.perf_counter() - t_start
    report.stage_seconds = clock
    report.encoder_restarts = restarts
    return report


# -- many drives --------------------------------------------------------------------------------


@dataclass(frozen=True)
class IngestJob:
    """One drive for a task: which archive (its spec: a worker needs no marker), the drive, how."""

    archive: ArchiveSpec
    drive: DriveInput
    options: IngestOptions


@dataclass
class DriveResult:
    """A task's end: the drive's report, or the one-line reason it was refused (a user error: not
    retried)."""

    name: str
    report: IngestReport | None = None
    error: str | None = None


def ingest_task(job: IngestJob) -> DriveResult:
    """The whole ingest of one drive, as a task for a worker process (engine.run_tasks). Safe to run
    again after its worker died: its token makes a repeated commit return the committed drive."""
    archive = Archive.from_spec(job.archive)
    try:
        return DriveResult(job.drive.drive_name, ingest_drive(archive, job.drive, job.options))
    except EgovidError as exc:
        return DriveResult(job.drive.drive_name, error=exc.one_line())
    finally:
        archive.close()


@dataclass
class Batch:
    """Drives checked and ordered for :func:`ingest_many`: ``jobs`` oldest first, and for each
    drive the earlier ones of this batch it crosses paths with (``after``: it starts when they are
    committed, so it can use them as its baseline)."""

    jobs: list[IngestJob]
    after: dict[str, list[str]]


def plan_batch(archive: Archive, drives: list[DriveInput], options: IngestOptions) -> Batch:
    """Check every drive before any work starts (video, GPS, name) and order them: by UTC start,
    each after the earlier drives whose areas (locks.cell_keys) it shares."""
    opts = options.check()
    names = [d.drive_name for d in drives]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise EgovidError(
            f"several videos would be named {', '.join(dup)}", "rename them, or ingest them apart with --name"
        )
    for name in names:
        if archive.catalogue.drive(name) is not None:
            raise EgovidError(f"a drive named {name!r} is already in the archive", "leave that video out, or rename it")
    checked = []
    for d in drives:
        vp = probe_stage(d)
        checked.append((d, track_stage(d, vp)))
    checked.sort(key=lambda dt: float(dt[1].frame_utc[0]))
    origin = archive.origin or checked[0][1].first_fix
    areas = [cell_keys(track_xy(t, origin), pad=NEAR) for _, t in checked]
    after: dict[str, list[str]] = {}
    for i, (d, _) in enumerate(checked):
        after[d.drive_name] = [checked[j][0].drive_name for j in range(i) if areas[i] & areas[j]]
    jobs = [IngestJob(archive.spec, replace(d, token=d.token or uuid.uuid4().hex), opts) for d, _ in checked]
    return Batch(jobs, after)


def ingest_many(archive: Archive, batch: Batch, config: EngineConfig) -> Iterator[DriveResult]:
    """Run a batch on the task engine (this process, a local pool of ``config.workers`` processes,
    or a Dask cluster); yields each drive's result as it ends."""
    keys = [j.drive.drive_name for j in batch.jobs]
    for outcome in run_tasks(ingest_task, batch.jobs, config=config, keys=keys, name="ingest", after=batch.after):
        if outcome.ok:
            yield outcome.value
        else:
            yield DriveResult(outcome.key, error=f"{type(outcome.error).__name__}: {outcome.error}")
