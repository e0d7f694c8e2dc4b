"""``dashcam forget`` / ``lock`` / ``unlock``: retention applied to an archive.

:func:`forget` picks the drives (:func:`choose`: named ones and the policies' picks, locked drives
passed over; the other cameras of a multi-camera drive go with it) and forgets them
(:func:`forget_drives`); :func:`set_lock` locks and unlocks. :func:`forget_drives` runs under the
archive's maintenance lock (no ingest or gc at the same time) and changes the catalogue in one
transaction, like an ingest:

1. plan (:func:`egovid.dashcam.retention.plan_forget`): which segments go, which are trimmed to the
   random-access runs live drives are still coded against, which drives stay as hidden references;
2. trim: the kept runs of a trimmed segment become new, smaller segment blobs (its packets as they
   are, a new header), written to the blob store before anything else changes;
3. verify (on by default): every live drive that depends on a forgotten one is decoded the way
   ``extract`` will decode it afterwards — from the trimmed segments, without the deleted ones — and
   each of its segments is compared with the encoder's reconstruction digest; any mismatch aborts
   with the catalogue unchanged;
4. commit: delete and replace the segments, delete the forgotten drives' sequences (so no new drive
   is coded against them), purge the drives nothing needs and hide the others (renamed
   ``NAME~forgotten-ID``, so the name is free again), all in one transaction;
5. only then delete the bitstreams nothing refers to any more (and the forgotten drives' audio and
   telemetry). A kill before the commit leaves the catalogue as it was (and at most new blobs no
   segment refers to); a kill after it leaves at most unreferenced blobs: ``egovid dashcam gc``
   deletes both.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from egovid.core.errors import EgovidError
from egovid.dashcam.archive.catalogue import Drive, Segment
from egovid.dashcam.archive.fleetstore import DriveMeta, FleetStore, hidden_drive_ids
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.codec import segment as codec
from egovid.dashcam.extract import SegmentSnapshot, segment_digest
from egovid.dashcam.retention import DriveAge, ForgetPlan, SegmentRef, older_than, over_budget, plan_forget

Say = Callable[[str], None]


@dataclass
class ForgetReport:
    """What a forget did: the drives forgotten (purged, or kept as hidden references with the live
    drives that need them), how many of their frames were kept for those, the locked drives a
    policy passed over, the live drives verified, the bytes freed (blobs deleted minus the trimmed
    blobs written) and how long it took."""

    forgotten: list[str] = field(default_factory=list)
    purged: list[str] = field(default_factory=list)
    kept_as_reference: dict[str, list[str]] = field(default_factory=dict)
    frames_kept: dict[str, int] = field(default_factory=dict)
    skipped_locked: list[str] = field(default_factory=list)
    verified: list[str] = field(default_factory=list)
    bytes_freed: int = 0
    blobs_deleted: int = 0
    dry_run: bool = False
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _run_bytes(seg: Segment) -> tuple[int, ...]:
    offsets = seg.params.get("run_offsets") or []
    return tuple(int(b - a) for a, b in itertools.pairwise(offsets))


def segment_refs(archive: Archive) -> list[SegmentRef]:
    """Every segment of the archive as retention sees it."""
    out = []
    for d in archive.catalogue.drives():
        for s in archive.catalogue.segments(d.id):
            joint = s.mode == "joint"
            out.append(
                SegmentRef(s.id, s.drive_id, s.frame_start, s.frame_end, s.blob, s.bytes,
                           s.ref_drive_id if joint else None, s.refmap if joint else None,
                           int(s.params.get("refresh") or 0), _run_bytes(s))
            )  # fmt: skip
    return out


def trim_segment(archive: Archive, seg: Segment, r0: int, r1: int) -> Segment:
    """A segment of runs [r0, r1) of ``seg``: its packets unchanged under a new header, written to
    the blob store (not yet in the catalogue: id 0, no reconstruction digest until decoded)."""
    blob = archive.blobs.get(seg.blob)
    lay, _ = codec.parse_header(blob)
    parsed = codec.parse(blob)
    (p0, _), (_, p1) = lay.run_packets()[r0], lay.run_packets()[r1 - 1]
    new = codec.pack(
        lay.width, lay.height, lay.q, parsed.packets[p0:p1], lay.gop, lay.refresh, lay.starts[r0:r1], lay.codec
    )
    k0 = r0 * lay.refresh
    k1 = min(r1 * lay.refresh, seg.frame_end - seg.frame_start)
    params = {**seg.params, "run_offsets": codec.run_offsets(new), "recon_digest": None, "trimmed_from": seg.blob}
    if seg.params.get("run_digests"):
        params["run_digests"] = seg.params["run_digests"][r0:r1]
    align = dict(seg.align)
    if isinstance(align.get("params"), list):
        align["params"] = align["params"][k0:k1]
    refmap = seg.refmap[k0:k1] if len(seg.refmap) else seg.refmap
    sha = archive.blobs.put(new)
    return replace(seg, id=0, frame_start=seg.frame_start + k0, frame_end=seg.frame_start + k1, refmap=refmap,
                   align=align, blob=sha, bytes=len(new), params=params)  # fmt: skip


def _ages(archive: Archive, fleet: FleetStore) -> list[DriveAge]:
    """The live drives for the policies; a camera of a multi-camera drive is locked with its drive."""
    metas = fleet.metas()
    locked = lambda i: metas[i].locked if i in metas else False  # noqa: E731
    return [
        DriveAge(d.id, d.start_utc, locked(fleet.primary_of(d.id)))
        for d in archive.catalogue.drives()
        if d.id not in metas or metas[d.id].state == "live"
    ]


def _refuse_locked(fleet: FleetStore, d: Drive) -> None:
    m = fleet.meta(d.id)
    if m.locked:
        note = f" ({m.lock_note})" if m.lock_note else ""
        raise EgovidError(f"drive {d.name} is locked{note}", f"unlock it first: egovid dashcam unlock ARCHIVE {d.name}")


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
    (locked drives passed over and returned as the second list). ``older_than_s``: every unlocked
    drive recorded longer ago than this (seconds before ``now``, default the clock);
    ``keep_bytes``: the oldest unlocked drives until the archive fits in this many bytes."""
    cat = archive.catalogue
    chosen: dict[int, Drive] = {}
    for key in names:
        d = fleet.live_drive(key)
        _refuse_locked(fleet, d)
        chosen[d.id] = d
    ages = _ages(archive, fleet)
    skipped = []
    if older_than_s is not None:
        cutoff = (time.time() if now is None else now) - older_than_s
        for i in older_than(ages, cutoff):
            chosen.setdefault(i, cat.drive(i))
        skipped += [cat.drive(a.id).name for a in ages if a.locked and a.start_utc < cutoff]
    if keep_bytes is not None:
        hidden = {i for i, m in fleet.metas().items() if m.state != "live"}
        live = [a for a in ages if a.id not in chosen]
        budget = keep_bytes - fleet.streams_bytes(exclude=hidden | set(chosen))
        extra, _ = over_budget(live, segment_refs(archive), hidden | set(chosen), budget)
        for i in extra:
            chosen.setdefault(i, cat.drive(i))
        skipped += [cat.drive(a.id).name for a in live if a.locked and a.id not in extra]
    mains = {fleet.primary_of(i) for i in chosen}  # a camera goes with its drive, and back
    picked = [chosen.get(i) or cat.drive(i) for i in mains]
    cameras = {cat.drive(i).name for i in hidden_drive_ids(cat)}  # told with their drive
    return sorted(picked, key=lambda d: d.start_utc), sorted(set(skipped) - cameras)


def forget(
    archive: Archive,
    names: list[str],
    *,
    older_than_s: float | None = None,
    keep_bytes: int | None = None,
    verify: bool = True,
    dry_run: bool = False,
    say: Say | None = None,
) -> ForgetReport:
    """``egovid dashcam forget``: forget the drives :func:`choose` picks (:func:`forget_drives`).
    ``say`` hears ``kept NAME: locked`` for each locked drive a policy passed over, then each step.
    When nothing is picked, the report lists no drive forgotten and only the locked ones kept."""
    say = say or (lambda _s: None)
    fleet = FleetStore(archive.catalogue)
    chosen, skipped = choose(archive, fleet, names, older_than_s=older_than_s, keep_bytes=keep_bytes)
    for name in skipped:
        say(f"kept {name}: locked")
    if not chosen:
        return ForgetReport(skipped_locked=skipped, dry_run=dry_run)
    rep = forget_drives(archive, fleet, chosen, verify=verify, dry_run=dry_run, say=say)
    rep.skipped_locked = skipped
    return rep


def set_lock(archive: Archive, keys: list[str], locked: bool, note: str | None = None) -> list[Drive]:
    """``egovid dashcam lock`` / ``unlock``: protect the live drives ``keys`` (names or ids) from
    :func:`forget` and its policies, or let it remove them again (``note``: why, kept with a lock);
    one transaction: an unknown drive changes nothing. Returns the drives."""
    fleet = FleetStore(archive.catalogue)
    with archive.catalogue.transaction():
        found = [fleet.live_drive(k) for k in keys]
        for d in found:
            fleet.set_lock(d.id, locked, note if locked else None)
    return found


@dataclass
class _Forget:
    """A forget under way (inside its transaction): the drives forgotten now (``targets``) and
    hidden earlier, every drive, the plan, every segment as it is and the trimmed ones replacing
    some, and the forgotten drives' audio/telemetry blobs."""

    targets: set[int]
    everyone: dict[int, Drive]
    metas: dict[int, DriveMeta]
    plan: ForgetPlan
    segs: dict[int, list[Segment]]
    streams: dict[int, str]
    trimmed: dict[int, list[Segment]] = field(default_factory=dict)

    def name(self, i: int) -> str:
        return self.everyone[i].name

    def after(self) -> dict[int, list[Segment]]:
        """Each drive's segments as extract will see them once the forget is committed."""
        gone = set(self.plan.delete_segments)
        return {
            i: [t for s in ss if s.id not in gone for t in self.trimmed.get(s.id, [s])] for i, ss in self.segs.items()
        }


def _plan(archive: Archive, fleet: FleetStore, drives: list[Drive]) -> _Forget:
    cat = archive.catalogue
    for d in drives:
        _refuse_locked(fleet, d)
    metas = fleet.metas()
    targets = {i for d in drives for i in fleet.channels(d.id).values()}  # with its other cameras
    hidden = {i for i, m in metas.items() if m.state != "live"}
    everyone = {d.id: d for d in cat.drives()}
    live = [i for i in everyone if i not in targets and i not in hidden]
    plan = plan_forget(segment_refs(archive), live, targets | hidden)
    streams = {i: metas[i].streams_blob for i in targets | hidden if i in metas and metas[i].streams_blob}
    return _Forget(targets, everyone, metas, plan, {i: cat.segments(i) for i in everyone}, streams)


def _trim(archive: Archive, f: _Forget) -> None:
    """Write the trimmed segments' blobs and give each its reconstruction digest, decoded from
    the archive as it will be."""
    by_id = {s.id: s for ss in f.segs.values() for s in ss}
    for sid, ranges in f.plan.trim_segments.items():
        f.trimmed[sid] = [trim_segment(archive, by_id[sid], r0, r1) for r0, r1 in ranges]
    view = SegmentSnapshot(archive.blobs, f.after())
    for sid, news in f.trimmed.items():
        f.trimmed[sid] = [replace(t, params={**t.params, "recon_digest": segment_digest(view, t)}) for t in news]


def _verify_dependents(archive: Archive, f: _Forget, rep: ForgetReport, say: Say) -> None:
    """Decode every live drive coded against a forgotten one as extract will afterwards and compare
    each segment with the encoder's digest; a mismatch aborts (the transaction rolls back)."""
    after = f.after()
    view = SegmentSnapshot(archive.blobs, after)
    dependents = sorted({x for v in f.plan.needed_by.values() for x in v})
    if not dependents:
        return
    say(f"verifying {len(dependents)} drive(s) coded against the forgotten ones: "
        + ", ".join(f.name(i) for i in dependents))  # fmt: skip
    for i in dependents:
        for seg in after[i]:
            if segment_digest(view, seg) != seg.params.get("recon_digest"):
                raise EgovidError(
                    f"drive {f.name(i)} would no longer decode as archived without the forgotten drives",
                    "nothing was changed; report this (the archive keeps every drive as it was)",
                )
        rep.verified.append(f.name(i))


def _delete_unused_blobs(archive: Archive, f: _Forget, rep: ForgetReport) -> None:
    """After the commit: delete the bitstreams (and audio/telemetry) nothing refers to any more,
    counting the bytes freed less the trimmed blobs written."""
    used = archive.catalogue.blob_names()
    sizes = {s.blob: s.bytes for ss in f.segs.values() for s in ss}
    sizes.update({f.metas[i].streams_blob: f.metas[i].streams_bytes for i in f.streams})
    for sha in dict.fromkeys([*f.plan.delete_blobs, *f.streams.values()]):
        if sha in used:
            continue
        archive.blobs.delete(sha)
        rep.bytes_freed += sizes.get(sha, 0)
        rep.blobs_deleted += 1
    rep.bytes_freed -= sum(t.bytes for news in f.trimmed.values() for t in news)


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
    rep = ForgetReport(dry_run=dry_run)
    with archive.locks.maintenance("forget"), archive.catalogue.transaction():
        f = _plan(archive, fleet, drives)
        plan = f.plan
        rep.forgotten = [f.name(i) for i in sorted(f.targets)]
        rep.purged = [f.name(i) for i in plan.purge_drives if i in f.targets]
        rep.kept_as_reference = {
            f.name(i): [f.name(x) for x in plan.needed_by.get(i, [])] for i in plan.keep_as_reference
        }
        if dry_run:
            rep.bytes_freed = plan.bytes_freed + sum(f.metas[i].streams_bytes for i in f.streams)
            rep.seconds = time.perf_counter() - t0
            return rep
        _trim(archive, f)
        after = f.after()
        for i, ss in after.items():
            if i in plan.keep_as_reference:
                rep.frames_kept[f.name(i)] = sum(s.frame_end - s.frame_start for s in ss)
        if verify:
            _verify_dependents(archive, f, rep, say)
        fleet.apply_forget(
            forgotten=f.targets,
            delete_segments=plan.delete_segments,
            trimmed=f.trimmed,
            hide=plan.keep_as_reference,
            purge=plan.purge_drives,
        )
    _delete_unused_blobs(archive, f, rep)  # committed: what nothing refers to any more can go
    rep.seconds = time.perf_counter() - t0
    return rep
