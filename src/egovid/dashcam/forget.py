"""``dashcam forget`` / ``lock`` / ``unlock``: retention applied to an archive.

:func:`forget_drives` runs under the archive's maintenance lock (no ingest or gc at the same time)
and changes the catalogue in one transaction, like an ingest:

1. plan (:func:`egovid.dashcam.retention.plan_forget`): which segments go, which stay as hidden
   references because live drives are coded against them;
2. verify (on by default): every live drive that depends on a forgotten one is decoded the way
   ``extract`` will decode it afterwards — without the segments about to go — and each segment's
   pictures are compared with the encoder's reconstruction digest; a mismatch aborts with the
   archive unchanged;
3. commit: delete the segments and sequences, purge drives nothing needs, hide the others
   (renamed ``NAME~forgotten-ID`` so the name is free again), all in one transaction;
4. only then delete the bitstreams no segment uses any more (and the forgotten drives' audio and
   telemetry). A kill before the commit leaves the archive as it was; a kill after it leaves at most
   unreferenced blobs, which ``egovid dashcam gc`` deletes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from egovid.dashcam.catalogue import Drive, Segment
from egovid.dashcam.extract import segment_digest
from egovid.dashcam.fleetstore import FleetStore
from egovid.dashcam.retention import DriveAge, ForgetPlan, SegmentRef, older_than, over_budget, plan_forget
from egovid.dashcam.store import Archive
from egovid.errors import EgovidError

Say = Callable[[str], None]


@dataclass
class ForgetReport:
    """What a forget did: the drives forgotten (purged, or kept as hidden references with the live
    drives that need them), the locked drives a policy passed over, the bytes freed, the live drives
    verified and how long it took."""

    forgotten: list[str] = field(default_factory=list)
    purged: list[str] = field(default_factory=list)
    kept_as_reference: dict[str, list[str]] = field(default_factory=dict)
    skipped_locked: list[str] = field(default_factory=list)
    verified: list[str] = field(default_factory=list)
    bytes_freed: int = 0
    blobs_deleted: int = 0
    dry_run: bool = False
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def segment_refs(archive: Archive) -> list[SegmentRef]:
    """Every segment of the archive as retention sees it."""
    out = []
    for d in archive.catalogue.drives():
        for s in archive.catalogue.segments(d.id):
            frames = s.refmap[s.refmap >= 0] if s.mode == "joint" else None
            out.append(
                SegmentRef(s.id, s.drive_id, s.frame_start, s.frame_end, s.blob, s.bytes, s.ref_drive_id, frames)
            )
    return out


class _Without:
    """The archive as a frame source without some segments (how extract will see it after)."""

    def __init__(self, archive: Archive, gone: set[int]) -> None:
        self.blobs = archive.blobs
        self._archive, self._gone = archive, gone

    def segments(self, drive_id: int) -> list[Segment]:
        return [s for s in self._archive.segments(drive_id) if s.id not in self._gone]


def _ages(archive: Archive, fleet: FleetStore) -> list[DriveAge]:
    metas = fleet.metas()
    return [
        DriveAge(d.id, d.start_utc, metas[d.id].locked if d.id in metas else False)
        for d in archive.catalogue.drives()
        if d.id not in metas or metas[d.id].state == "live"
    ]


def choose(
    archive: Archive,
    fleet: FleetStore,
    names: list[str],
    *,
    older_than_s: float | None = None,
    keep_bytes: int | None = None,
    now: float | None = None,
) -> tuple[list[Drive], list[str]]:
    """The drives to forget: those named (a locked one is an error) and those the policies pick
    (locked drives passed over and returned as the second list)."""
    cat = archive.catalogue
    metas = fleet.metas()
    chosen: dict[int, Drive] = {}
    for key in names:
        d = fleet.live_drive(key)
        m = metas.get(d.id)
        if m is not None and m.locked:
            note = f" ({m.lock_note})" if m.lock_note else ""
            raise EgovidError(f"drive {d.name} is locked{note}", f"unlock it first: egovid dashcam unlock ARCHIVE {d.name}")
        chosen[d.id] = d
    ages = _ages(archive, fleet)
    skipped = []
    if older_than_s is not None:
        cutoff = (time.time() if now is None else now) - older_than_s
        for i in older_than(ages, cutoff):
            chosen.setdefault(i, cat.drive(i))
        skipped += [cat.drive(a.id).name for a in ages if a.locked and a.start_utc < cutoff]
    if keep_bytes is not None:
        refs = segment_refs(archive)
        gone = {i for i, m in metas.items() if m.state != "live"} | set(chosen)
        live = [a for a in ages if a.id not in chosen]
        extra, _ = over_budget(live, refs, gone, keep_bytes - fleet.streams_bytes(exclude=gone))
        for i in extra:
            chosen.setdefault(i, cat.drive(i))
        skipped += [cat.drive(a.id).name for a in live if a.locked and a.id not in extra]
    return sorted(chosen.values(), key=lambda d: d.start_utc), sorted(set(skipped))


def forget_drives(
    archive: Archive,
    fleet: FleetStore,
    drives: list[Drive],
    *,
    verify: bool = True,
    dry_run: bool = False,
    say: Say | None = None,
) -> ForgetReport:
    """Forget ``drives`` (see the module docstring). ``say``: called with a line at each step."""
    say = say or (lambda _s: None)
    t0 = time.perf_counter()
    cat = archive.catalogue
    rep = ForgetReport(dry_run=dry_run)
    with archive.locks.maintenance("forget"), cat.transaction():
        metas = fleet.metas()
        targets = {d.id for d in drives}
        for d in drives:
            m = metas.get(d.id)
            if m is not None and m.locked:
                raise EgovidError(f"drive {d.name} is locked", f"unlock it first: egovid dashcam unlock ARCHIVE {d.name}")
        hidden = {i for i, m in metas.items() if m.state != "live"}
        everyone = {d.id: d for d in cat.drives()}
        live = [i for i in everyone if i not in targets and i not in hidden]
        plan: ForgetPlan = plan_forget(segment_refs(archive), live, targets | hidden)
        gone_segments = set(plan.delete_segments)
        dependents = sorted({x for v in plan.needed_by.values() for x in v})
        if verify and dependents:
            say(f"verifying {len(dependents)} drive(s) coded against the forgotten ones: "
                + ", ".join(everyone[i].name for i in dependents))  # fmt: skip
            view = _Without(archive, gone_segments)
            for i in dependents:
                for seg in view.segments(i):
                    if segment_digest(view, seg) != seg.params.get("recon_digest"):
                        raise EgovidError(
                            f"drive {everyone[i].name} would no longer decode as archived without the forgotten drives",
                            "nothing was changed; report this (the archive keeps every drive as it was)",
                        )
                rep.verified.append(everyone[i].name)
        rep.forgotten = [everyone[i].name for i in sorted(targets)]
        rep.purged = [everyone[i].name for i in plan.purge_drives if i in targets]
        rep.kept_as_reference = {
            everyone[i].name: [everyone[x].name for x in plan.needed_by.get(i, [])] for i in plan.keep_as_reference
        }
        streams = {i: metas[i].streams_blob for i in targets | hidden if i in metas and metas[i].streams_blob}
        sizes = {s.blob: s.bytes for s in segment_refs(archive)}
        sizes.update({metas[i].streams_blob: metas[i].streams_bytes for i in streams})
        if dry_run:
            rep.bytes_freed = plan.bytes_freed + sum(metas[i].streams_bytes for i in streams)
            rep.seconds = time.perf_counter() - t0
            return rep
        fleet.apply_forget(plan, targets, everyone)
    # Committed: the bitstreams nothing refers to any more can go.
    used = cat.blob_names() | fleet.blob_names()
    for sha in dict.fromkeys([*plan.delete_blobs, *streams.values()]):
        if sha in used:
            continue
        archive.blobs.delete(sha)
        rep.bytes_freed += sizes.get(sha, 0)
        rep.blobs_deleted += 1
    rep.seconds = time.perf_counter() - t0
    return rep
