"""``dashcam forget`` / ``lock`` / ``unlock``: retention applied to an archive.

:func:`forget_drives` runs under the archive's maintenance lock (no ingest or gc at the same time)
and changes the catalogue in one transaction, like an ingest:

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
from egovid.dashcam.archive.fleetstore import FleetStore
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
    metas = fleet.metas()
    return [
        DriveAge(d.id, d.start_utc, metas[d.id].locked if d.id in metas else False)
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
    (locked drives passed over and returned as the second list)."""
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
        for d in drives:
            _refuse_locked(fleet, d)
        metas = fleet.metas()
        targets = {d.id for d in drives}
        hidden = {i for i, m in metas.items() if m.state != "live"}
        everyone = {d.id: d for d in cat.drives()}
        live = [i for i in everyone if i not in targets and i not in hidden]
        plan: ForgetPlan = plan_forget(segment_refs(archive), live, targets | hidden)
        segs = {i: cat.segments(i) for i in everyone}
        by_id = {s.id: s for ss in segs.values() for s in ss}
        streams = {i: metas[i].streams_blob for i in targets | hidden if i in metas and metas[i].streams_blob}
        rep.forgotten = [everyone[i].name for i in sorted(targets)]
        rep.purged = [everyone[i].name for i in plan.purge_drives if i in targets]
        rep.kept_as_reference = {
            everyone[i].name: [everyone[x].name for x in plan.needed_by.get(i, [])] for i in plan.keep_as_reference
        }
        if dry_run:
            rep.bytes_freed = plan.bytes_freed + sum(metas[i].streams_bytes for i in streams)
            rep.seconds = time.perf_counter() - t0
            return rep
        # Trimmed segments, then the archive as extract will see it afterwards.
        trimmed: dict[int, list[Segment]] = {}
        for sid, ranges in plan.trim_segments.items():
            trimmed[sid] = [trim_segment(archive, by_id[sid], r0, r1) for r0, r1 in ranges]
        gone = set(plan.delete_segments)
        after = {i: [t for s in ss if s.id not in gone for t in trimmed.get(s.id, [s])] for i, ss in segs.items()}
        view = SegmentSnapshot(archive.blobs, after)
        for sid, news in trimmed.items():
            for k, t in enumerate(news):
                trimmed[sid][k] = replace(t, params={**t.params, "recon_digest": segment_digest(view, t)})
        after = {i: [t for s in ss if s.id not in gone for t in trimmed.get(s.id, [s])] for i, ss in segs.items()}
        view = SegmentSnapshot(archive.blobs, after)
        for i, ss in after.items():
            if i in plan.keep_as_reference:
                rep.frames_kept[everyone[i].name] = sum(s.frame_end - s.frame_start for s in ss)
        dependents = sorted({x for v in plan.needed_by.values() for x in v})
        if verify and dependents:
            say(f"verifying {len(dependents)} drive(s) coded against the forgotten ones: "
                + ", ".join(everyone[i].name for i in dependents))  # fmt: skip
            for i in dependents:
                for seg in after[i]:
                    if segment_digest(view, seg) != seg.params.get("recon_digest"):
                        raise EgovidError(
                            f"drive {everyone[i].name} would no longer decode as archived without the forgotten drives",
                            "nothing was changed; report this (the archive keeps every drive as it was)",
                        )
                rep.verified.append(everyone[i].name)
        fleet.apply_forget(plan, targets, everyone, trimmed)
    # Committed: the bitstreams nothing refers to any more can go.
    used = cat.blob_names()
    sizes = {s.blob: s.bytes for s in by_id.values()}
    sizes.update({metas[i].streams_blob: metas[i].streams_bytes for i in streams})
    for sha in dict.fromkeys([*plan.delete_blobs, *streams.values()]):
        if sha in used:
            continue
        archive.blobs.delete(sha)
        rep.bytes_freed += sizes.get(sha, 0)
        rep.blobs_deleted += 1
    rep.bytes_freed -= sum(t.bytes for news in trimmed.values() for t in news)
    rep.seconds = time.perf_counter() - t0
    return rep
