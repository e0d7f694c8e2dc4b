"""The ingest of video files, as ``egovid dashcam ingest`` runs it: the one route every caller
takes (the CLI, the demo, the benchmarks, the tests)::

    examine (sources.plan_ingest: each file's GPS, clock, kind; trips of loop files)
      -> prepare (fleet.prepare: names checked, audio/telemetry blob, fleet rows, the probe)
      -> one drive in this process (run.ingest_drive)
         or a batch on the task engine (run.plan_batch, run.ingest_many: oldest first)
      -> IngestResult (the drives added, those that failed, the files skipped; the JSON report)

What happens on the way is told through :class:`IngestHooks` (progress bars, the files skipped,
each drive as it ends), so a caller prints while a long batch runs.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from egovid.core.engine import EngineConfig
from egovid.core.errors import EgovidError
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.ingest.attach import Archived
from egovid.dashcam.ingest.fleet import ALREADY_IN, PreparedDrive, drive_input, prepare
from egovid.dashcam.ingest.options import IngestOptions
from egovid.dashcam.ingest.records import IngestReport
from egovid.dashcam.ingest.run import Progress, ingest_drive, ingest_many, plan_batch
from egovid.dashcam.ingest.sources import ClockOptions, plan_ingest
from egovid.dashcam.route.tracks import GpsTrack
from egovid.dashcam.route.trips import MAX_GAP_S


def _quiet(*_args) -> None:
    return None


@dataclass
class IngestHooks:
    """What an ingest tells its caller while it runs (each optional):

    ``progress(stage, done, total)``: the examination of the files (``examine``), a single drive's
    stages, or the drives of a batch (``drives``); ``skipped(path, reason)``: each file left out,
    before any drive is ingested; ``batch(drives, where)``: several drives go to the task engine
    (``where``: "2 local worker(s)", "Dask cluster tcp://…"); ``drive(outcome)``: a drive ended,
    added or failed."""

    progress: Progress = _quiet
    skipped: Callable[[Path, str], None] = _quiet
    batch: Callable[[int, str], None] = _quiet
    drive: Callable[[DriveOutcome], None] = _quiet


@dataclass
class DriveOutcome:
    """One drive of an ingest: the trip it was prepared from, and its report or, for a drive of a
    batch that was not added, the one-line reason."""

    prepared: PreparedDrive
    report: IngestReport | None = None
    error: str | None = None

    @property
    def name(self) -> str:
        return self.prepared.name

    def to_dict(self) -> dict:
        """The drive's JSON report: the ingest's figures and the fleet's side (files, clock, …)."""
        return {**self.report.to_dict(), **self.prepared.summary()} if self.report is not None else {}


@dataclass
class IngestResult:
    """The end of an ingest: every drive tried (in the order they ended), the files skipped with
    the reason, and whether it was a single drive ingested in this process (its report is then
    the whole JSON document, as ``--json`` has always written it); ``known``: how many of the
    files skipped the archive holds already (same content, whatever their name)."""

    drives: list[DriveOutcome] = field(default_factory=list)
    skipped: list[tuple[Path, str]] = field(default_factory=list)
    single: bool = False
    known: int = 0

    @property
    def added(self) -> list[DriveOutcome]:
        return [d for d in self.drives if d.report is not None]

    @property
    def failed(self) -> list[DriveOutcome]:
        return [d for d in self.drives if d.report is None]

    @property
    def reports(self) -> list[IngestReport]:
        """The reports of the drives added."""
        return [d.report for d in self.added]

    @property
    def nothing_new(self) -> bool:
        """No drive was tried: every one is in the archive already (the same card synced again)."""
        return not self.drives

    def to_dict(self) -> dict:
        """The ingest's JSON report (``--json``)."""
        skipped = [{"file": str(f), "reason": why} for f, why in self.skipped]
        if self.single:  # one drive; its other cameras (if any) beside it
            channels = {"channels": [d.to_dict() for d in self.drives[1:]]} if len(self.drives) > 1 else {}
            return {**self.drives[0].to_dict(), **channels, "skipped": skipped}
        failed = [{"drive": d.name, "error": d.error} for d in self.failed]
        return {"drives": [d.to_dict() for d in self.added], "failed": failed, "skipped": skipped}

    def check(self) -> IngestResult:
        """Raise :class:`EgovidError` when a drive of the batch was not added."""
        if self.failed:
            names = ", ".join(d.name for d in self.failed)
            raise EgovidError(
                f"{len(self.failed)} of {len(self.drives)} drives were not added ({names})",
                "see the reasons above; the other drives are in the archive, run the command again for these",
            )
        return self


def ingest_videos(
    archive: Archive,
    videos: Sequence[str | os.PathLike],
    *,
    gps: str | os.PathLike | GpsTrack | None = None,
    clock: ClockOptions | None = None,
    name: str | None = None,
    join: bool = True,
    max_gap: float = MAX_GAP_S,
    lock_events: bool = True,
    options: IngestOptions | None = None,
    engine: EngineConfig | None = None,
    hooks: IngestHooks | None = None,
    verify_known: bool = False,
) -> IngestResult:
    """Ingest dashcam videos (files, or folders searched recursively) into ``archive``.

    ``gps``: one GPS log for all of them (a file or a track already read; default: each file's
    own, see :mod:`~egovid.dashcam.ingest.sources`); ``clock``: the user's help with the camera
    clock; ``name``: the drive's name (one drive only); ``join``/``max_gap``: loop files at most
    ``max_gap`` seconds apart make one trip; ``lock_events``: event files are locked as they come
    in; ``engine``: where a batch runs (default: this process, one drive after another);
    ``verify_known``: a file the archive recognises by its sampled digest is hashed whole to be sure
    (:mod:`egovid.dashcam.archive.identity`).

    One drive on this machine is ingested here and any problem is an error; several drives (or a
    Dask scheduler) run as a batch, oldest first, and a drive that fails is listed in the result
    (:meth:`IngestResult.check` raises then). Raises :class:`EgovidError` before any work for
    unusable options or inputs, and when nothing can be ingested."""
    opts = (options or IngestOptions()).check()
    engine = engine or EngineConfig()
    hooks = hooks or IngestHooks()
    plan = plan_ingest(
        videos,
        gps=gps,
        clock=clock,
        join=join,
        max_gap=max_gap,
        on_file=lambda k, n: hooks.progress("examine", k, n),
        # --name: a drive of that name, even of known files
        archived=Archived(archive, dedup=name is None, verify=verify_known),
    )
    prepared = prepare(archive, plan, name=name, lock_events=lock_events)
    for path, why in plan.skipped:
        if path not in plan.known:  # those are counted (a card synced again: hundreds of them)
            hooks.skipped(path, why)
    if not prepared:
        if any(why.startswith(ALREADY_IN) for _, why in plan.skipped):
            return IngestResult([], plan.skipped, known=len(plan.known))
        raise EgovidError("nothing to ingest: every video was skipped", "see the reasons above")
    appends = [p for p in prepared if p.append is not None]
    new = [p for p in prepared if p.append is None]
    outcomes = [_append(archive, p, opts, hooks) for p in appends]  # in order, one commit each
    mains = [p for p in new if p.channel_of is None]
    head = mains[0] if len(mains) == 1 else new[0] if len(new) == 1 else None
    one = head is not None and all(p is head or p.channel_of == head.name for p in new)
    if one and not appends and engine.scheduler is None:  # one drive (and its other cameras), here
        first = DriveOutcome(head, ingest_drive(archive, drive_input(head), opts, progress=hooks.progress))
        hooks.drive(first)
        rest = [_append(archive, p, opts, hooks) for p in new if p is not head]
        return IngestResult([first, *rest], plan.skipped, single=True, known=len(plan.known))
    if new:
        outcomes += _run_batch(archive, new, opts, engine, hooks)
    return IngestResult(outcomes, plan.skipped, known=len(plan.known))


def _append(archive: Archive, p: PreparedDrive, opts: IngestOptions, hooks: IngestHooks) -> DriveOutcome:
    """One file appended to an archived drive (or another camera of a drive just added), in this
    process (the files of a drive one after another: each expects the frames the one before
    left). A failure is the drive's outcome."""
    try:
        outcome = DriveOutcome(p, ingest_drive(archive, drive_input(p), opts, progress=hooks.progress))
    except EgovidError as exc:
        outcome = DriveOutcome(p, error=exc.one_line())
    hooks.drive(outcome)
    return outcome


def _run_batch(
    archive: Archive, prepared: list[PreparedDrive], opts: IngestOptions, engine: EngineConfig, hooks: IngestHooks
) -> list[DriveOutcome]:
    """The prepared drives as one batch on the task engine; their outcomes as they end."""
    by_name = {p.name: p for p in prepared}
    batch = plan_batch(archive, [drive_input(p) for p in prepared], opts)
    for p in prepared:  # a camera's channel is committed after its drive
        if p.channel_of in by_name and p.channel_of not in batch.after.setdefault(p.name, []):
            batch.after[p.name].append(p.channel_of)
    n = len(batch.jobs)
    hooks.batch(n, f"Dask cluster {engine.scheduler}" if engine.scheduler else f"{engine.workers} local worker(s)")
    hooks.progress("drives", 0, n)
    outcomes: list[DriveOutcome] = []
    for res in ingest_many(archive, batch, engine):
        outcomes.append(DriveOutcome(by_name[res.name], res.report, res.error))
        hooks.drive(outcomes[-1])
        hooks.progress("drives", len(outcomes), n)
    return outcomes
