"""``egovid dashcam``: the route-aware dashcam archive."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from egovid.cli.common import check_output, console, staged_progress

app = typer.Typer(
    help="Route-aware dashcam archive: drives on the same path are compressed against each other.",
    no_args_is_help=True,
)


def _open(archive: Path):
    from egovid.dashcam.archive import Archive

    return Archive(archive)


@app.command("init")
def init(
    archive: Path = typer.Argument(..., help="Folder to create the archive in (new or empty)."),
    db: str = typer.Option(
        None,
        "--db",
        help="Catalogue database: leave out for the embedded SQLite file in the archive folder, or give "
        "postgresql://USER@HOST[:PORT]/DATABASE to keep the catalogue in a new schema of that database "
        "(the bitstreams stay in the folder; keep passwords in PGPASSWORD or ~/.pgpass, not in the URL).",
    ),
) -> None:
    """Create an empty archive."""
    from egovid.cli.validate import output_folder
    from egovid.dashcam.archive import Archive
    from egovid.dashcam.catalogue import redact_url
    from egovid.dashcam.vpx import self_test

    output_folder(archive, what="archive folder")
    ar = Archive.create(archive, db)
    cat = ar.meta["catalogue"]
    where = "SQLite" if cat["backend"] == "sqlite" else f"PostgreSQL {redact_url(cat['url'])}, schema {cat['schema']}"
    console.print(f"archive {archive} created (catalogue: {where}; codec: {self_test()})")


@app.command("ingest")
def ingest(
    archive: Path = typer.Argument(..., help="Archive folder (from `egovid dashcam init`)."),
    video: Path = typer.Argument(..., help="Dashcam video of the drive."),
    gps: Path = typer.Option(..., "--gps", help="GPS track of the drive: GPX, NMEA 0183 or CSV (time,lat,lon,...)."),
    name: str = typer.Option(None, help="Name of the drive in the archive (default: the video's file name)."),
    start: str = typer.Option(None, help="UTC start time of the video (ISO 8601) if its metadata lacks it."),
    gps_offset: float = typer.Option(0.0, help="Seconds to add to the video's start to line it up with the GPS."),
    q: int = typer.Option(32, min=0, max=63, help="VP9 quantiser (0 = best quality, 63 = smallest)."),
    speed: int = typer.Option(5, min=0, max=9, help="libvpx cpu-used: higher = faster, larger files."),
    realtime: bool = typer.Option(False, help="Realtime encoder deadline (about 3x faster, ~10 % larger)."),
    gop: int = typer.Option(
        8,
        min=1,
        max=64,
        help="Anchor spacing in frames: every GOP-th frame is coded first and the frames between "
        "refer to it (and to the older drive) at a coarser quantiser (+12). 1 = low delay.",
    ),
    random_access: int = typer.Option(
        24,
        min=0,
        max=65535,
        help="Random-access period in frames: decoding can begin at every N-th frame (a keyframe "
        "for a first drive, a frame predicted from the older drive alone for a later one). "
        "0 = only at the start (smallest files, no seeking).",
    ),
    aligner: str = typer.Option("orb", help="orb (default) | orb-plain (thesis only) | seqslam | gps."),
    baseline_align: str = typer.Option("none", help="Global alignment of the reference: none | gain | similarity."),
    savings: bool = typer.Option(True, help="Also encode standalone to measure the saving (doubles encoding)."),
    verify: bool = typer.Option(True, help="Decode the new bitstreams as extract will and compare."),
    json_out: Path = typer.Option(None, "--json", help="Write the ingest report as JSON."),
) -> None:
    """Add a drive: split it into per-path sequences, pick older drives of the same path and light,
    align them frame by frame, and store the drive compressed against them.

    Nothing is changed in the archive unless the whole ingest succeeds.
    """
    import datetime as dt

    from egovid.cli.validate import number
    from egovid.dashcam.archive import IngestOptions
    from egovid.errors import EgovidError

    number(gps_offset, "--gps-offset", lo=-7 * 86400, hi=7 * 86400, unit="s")
    ar = _open(archive)
    start_utc = None
    if start is not None:
        try:
            t = dt.datetime.fromisoformat(start.replace("Z", "+00:00"))
        except ValueError:
            raise EgovidError(f"--start {start!r} is not an ISO 8601 time", "write e.g. 2026-05-04T08:00:00Z") from None
        start_utc = (t if t.tzinfo else t.replace(tzinfo=dt.UTC)).timestamp()
    if json_out is not None:
        check_output(json_out)
    opts = IngestOptions(
        q=q,
        speed=speed,
        realtime=realtime,
        gop=gop,
        refresh=random_access,
        aligner=aligner,
        baseline_align=baseline_align,
        measure_savings=savings,
        verify=verify,
        name=name,
        start_utc=start_utc,
        gps_offset=gps_offset,
    )
    with staged_progress() as cb:
        rep = ar.ingest(video, gps, opts, progress=cb)
    for p in rep.pieces:
        saving = f", saving {100 * p.saving:.1f} % vs standalone" if p.saving is not None else ""
        ref = f" against {p.ref_drive}" if p.ref_drive else " (root: no older drive of this path and light)"
        console.print(
            f"frames {p.frames[0]}-{p.frames[1] - 1}: path {p.path_id}, {p.mode}{ref}, {p.bytes / 1024:.0f} KiB, "
            f"PSNR-Y {p.psnr_y:.2f} dB{saving}"
        )
    console.print(
        f"drive {rep.name!r} added: {rep.frames} frames in {rep.seconds:.1f} s ({rep.fps:.1f} fps); "
        f"new paths {rep.new_paths or 'none'}, split paths {rep.split_paths or 'none'}"
    )
    if json_out is not None:
        from egovid.io.files import atomic_write_text

        atomic_write_text(json_out, json.dumps(rep.to_dict(), indent=1, default=str))


@app.command("list")
def list_cmd(archive: Path = typer.Argument(..., help="Archive folder.")) -> None:
    """List the drives in the archive."""
    import datetime as dt

    from rich.table import Table

    ar = _open(archive)
    t = Table(title=str(archive))
    for col in ("id", "drive", "start (UTC)", "frames", "size", "stored", "modes"):
        t.add_column(col)
    for d in ar.catalogue.drives():
        segs = ar.catalogue.segments(d.id)
        size = sum(s.bytes for s in segs)
        modes = ", ".join(sorted({s.mode for s in segs}))
        start = dt.datetime.fromtimestamp(d.start_utc, dt.UTC).strftime("%Y-%m-%d %H:%M:%S")
        t.add_row(str(d.id), d.name, start, str(d.frames), f"{d.width}x{d.height}", f"{size / 1024:.0f} KiB", modes)
    console.print(t)


@app.command("show")
def show(
    archive: Path = typer.Argument(..., help="Archive folder."),
    drive: str = typer.Argument(..., help="Drive name or id."),
) -> None:
    """Show how a drive is stored: its path sequences and segments."""
    ar = _open(archive)
    d = ar.drive_or_fail(drive)
    console.print(f"[bold]{d.name}[/] (id {d.id}): {d.frames} frames, {d.width}x{d.height} @ {d.fps:g} fps")
    console.print(f"source {d.source}\nGPS    {d.gps_source}")
    for s in ar.catalogue.sequences(drive_id=d.id):
        console.print(
            f"  path {s.path_id}: frames {s.frame_start}-{s.frame_end - 1}, "
            f"{s.positions.min():.0f}-{s.positions.max():.0f} m along the path, segment {s.segment_id}"
        )
    for g in ar.catalogue.segments(d.id):
        ref = ar.catalogue.drive(g.ref_drive_id).name if g.ref_drive_id else None
        alone = g.params.get("standalone_bytes")
        extra = f", standalone {alone / 1024:.0f} KiB ({100 * (1 - g.bytes / alone):.1f} % saved)" if alone else ""
        console.print(
            f"  segment {g.id}: frames {g.frame_start}-{g.frame_end - 1}, {g.mode}"
            f"{' against ' + ref if ref else ''}, {g.bytes / 1024:.0f} KiB, "
            f"PSNR-Y {g.params.get('psnr_y', float('nan')):.2f} dB{extra}"
        )


@app.command("extract")
def extract(
    archive: Path = typer.Argument(..., help="Archive folder."),
    drive: str = typer.Argument(..., help="Drive name or id."),
    out: Path = typer.Option(..., "-o", "--out", help="Output video: .mkv (FFV1) or .mp4 (lossless H.264)."),
    start: float = typer.Option(None, "--start", min=0.0, help="Write from this time (seconds into the drive)."),
    duration: float = typer.Option(None, "--duration", min=0.0, help="Write this many seconds (default: to the end)."),
) -> None:
    """Write a drive back as a video, bit-exact with what the encoder reconstructed.

    With --start/--duration only that stretch is decoded: decoding begins at the nearest
    random-access point before it (every 24 frames by default), in this drive and in the older
    drives it was coded against.
    """
    from egovid.errors import EgovidError

    ar = _open(archive)
    check_output(out)
    d = ar.drive_or_fail(drive)
    f0 = round((start or 0.0) * d.fps)
    f1 = d.frames if duration is None else min(d.frames, f0 + max(1, round(duration * d.fps)))
    if f0 >= d.frames:
        raise EgovidError(
            f"--start {start} s is past the end of drive {d.name} ({d.frames / d.fps:.1f} s)", "choose an earlier start"
        )
    with staged_progress() as cb:
        ar.extract(drive, out, progress=lambda k, n: cb("extract", k, n), frames=(f0, f1))
    console.print(f"{d.name}: frames {f0}-{f1 - 1} of {d.frames} → {out}")


@app.command("gc")
def gc(
    archive: Path = typer.Argument(..., help="Archive folder."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Only list what would be deleted."),
) -> None:
    """Delete bitstreams no drive refers to (left behind by an ingest that crashed or was killed).

    They are harmless, only wasted space: a crashed ingest never changes the catalogue. Waits for
    nothing: if an ingest is running, gc refuses and says so.
    """
    ar = _open(archive)
    junk, size = ar.collect_garbage(dry_run=dry_run)
    verb = "would delete" if dry_run else "deleted"
    console.print(f"{verb} {len(junk)} unreferenced file(s), {size / 1024:.0f} KiB")
    for p in junk:
        console.print(f"  {p.relative_to(archive)}")


@app.command("report")
def report(
    archive: Path = typer.Argument(..., help="Archive folder."),
    json_out: Path = typer.Option(None, "--json", help="Write the report as JSON."),
) -> None:
    """Bits per path and per drive, and the savings of joint coding."""
    from rich.table import Table

    ar = _open(archive)
    rep = ar.report()
    t = Table(title="paths")
    for col in ("path", "length", "sequences", "frames", "stored", "bits/frame", "saving"):
        t.add_column(col, justify="right")
    for p in rep["paths"]:
        sv = f"{100 * p['saving']:.1f} %" if p["saving"] is not None else "-"
        t.add_row(
            str(p["path"]),
            f"{p['length_m']:.0f} m",
            str(p["sequences"]),
            str(p["frames"]),
            f"{p['bytes'] / 1024:.0f} KiB",
            f"{p['bits_per_frame']:.0f}",
            sv,
        )
    console.print(t)
    t = Table(title="drives")
    for col in ("drive", "frames", "stored", "bits/frame", "joint frames", "saving", "references"):
        t.add_column(col, justify="right")
    for d in rep["drives"]:
        sv = f"{100 * d['saving_on_joint_frames']:.1f} %" if d["saving_on_joint_frames"] is not None else "-"
        t.add_row(
            d["drive"],
            str(d["frames"]),
            f"{d['bytes'] / 1024:.0f} KiB",
            f"{d['bits_per_frame']:.0f}",
            str(d["joint_frames"]),
            sv,
            ", ".join(d["references"]) or "-",
        )
    console.print(t)
    console.print(f"bitstreams on disk: {rep['blob_bytes'] / 1024:.0f} KiB; {rep['codec']}")
    if json_out is not None:
        from egovid.io.files import atomic_write_text

        atomic_write_text(json_out, json.dumps(rep, indent=1, default=str))
