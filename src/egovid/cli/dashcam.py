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
    from egovid.dashcam.store import open_archive

    return open_archive(archive)


@app.command("init")
def init(
    archive: Path = typer.Argument(..., help="Folder to create the archive in (new or empty)."),
    db: str = typer.Option(
        None,
        "--db",
        help="Catalogue database: leave out for the embedded SQLite file in the archive folder, or give "
        "postgresql://USER@HOST[:PORT]/DATABASE to keep the catalogue in a new schema of that database "
        "(keep passwords in PGPASSWORD or ~/.pgpass, not in the URL).",
    ),
    blobs: str = typer.Option(
        None,
        "--blobs",
        help="Where the bitstreams go: leave out for the archive folder, or give an fsspec URL such as "
        "s3://BUCKET/PREFIX (credentials and endpoint from the standard AWS_ACCESS_KEY_ID, "
        "AWS_SECRET_ACCESS_KEY and AWS_ENDPOINT_URL variables).",
    ),
) -> None:
    """Create an empty archive.

    For an archive spread over machines, keep the catalogue in PostgreSQL (--db) and the bitstreams
    in an object store (--blobs); the folder then holds only the marker that names them.
    """
    from egovid.cli.validate import output_folder
    from egovid.dashcam.catalogue import redact_url
    from egovid.dashcam.store import Archive
    from egovid.dashcam.vpx import self_test

    output_folder(archive, what="archive folder")
    ar = Archive.create(archive, db, blobs)
    cat = ar.meta["catalogue"]
    where = "SQLite" if cat["backend"] == "sqlite" else f"PostgreSQL {redact_url(cat['url'])}, schema {cat['schema']}"
    console.print(f"archive {archive} created (catalogue: {where}; blobs: {ar.blobs.url}; codec: {self_test()})")


VIDEO_EXTENSIONS = (".mp4", ".mov", ".mkv", ".avi", ".ts", ".m4v", ".webm")


def _videos(paths: list[Path]) -> list[Path]:
    """The videos named, folders searched (recursively) for video files."""
    from egovid.errors import EgovidError

    out: list[Path] = []
    for p in paths:
        if p.is_dir():
            found = sorted(f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in VIDEO_EXTENSIONS)
            if not found:
                raise EgovidError(
                    f"folder {p} holds no videos", f"give videos ({', '.join(VIDEO_EXTENSIONS)}) or folders of them"
                )
            out += found
        elif not p.exists():
            raise EgovidError(f"video not found: {p}", "check the path")
        else:
            out.append(p)
    return out


@app.command("ingest")
def ingest(
    archive: Path = typer.Argument(..., help="Archive folder (from `egovid dashcam init`)."),
    videos: list[Path] = typer.Argument(
        ..., help="Dashcam videos, or folders of them (searched for .mp4, .mov, .mkv, .avi, .ts, .m4v, .webm)."
    ),
    gps: Path = typer.Option(
        None,
        "--gps",
        help="GPS track of the drive (one video only): GPX, NMEA 0183 or CSV (time,lat,lon,...). Default: the "
        "file beside each video with the same name and a .gpx, .nmea or .csv extension.",
    ),
    name: str = typer.Option(None, help="Name of the drive in the archive (one video only; default: its file name)."),
    start: str = typer.Option(
        None, help="UTC start time of the video (ISO 8601) if its metadata lacks it (one video only)."
    ),
    gps_offset: float = typer.Option(0.0, help="Seconds to add to each video's start to line it up with its GPS."),
    preset: str = typer.Option(
        None,
        "--preset",
        help="realtime (default: keeps up with a 30 fps camera at 720p on two cores) | balanced | archive "
        "(libvpx's good-quality deadline: smallest files, several times slower). The options below override it.",
    ),
    q: int = typer.Option(32, min=0, max=63, help="VP9 quantiser (0 = best quality, 63 = smallest)."),
    speed: int = typer.Option(None, min=0, max=9, help="libvpx cpu-used (default: the preset's): higher = faster."),
    threads: int = typer.Option(None, min=1, max=64, help="libvpx threads (default: the preset's)."),
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
    measure_savings: bool = typer.Option(
        False, "--measure-savings", help="Also encode each joint piece alone, to report the saving (doubles encoding)."
    ),
    verify: bool = typer.Option(True, help="Decode each new bitstream beside the encoder and compare (cheap)."),
    workers: int = typer.Option(
        1, "--workers", min=1, max=512, help="Drives ingested at once on this machine (worker processes)."
    ),
    scheduler: str = typer.Option(
        None,
        "--scheduler",
        help="Run on a Dask cluster: its scheduler's address, tcp://HOST:8786 (default: $DASK_SCHEDULER_ADDRESS; "
        "without either, this machine). The workers must reach the videos, the catalogue and the blob store.",
    ),
    json_out: Path = typer.Option(None, "--json", help="Write the ingest report(s) as JSON."),
) -> None:
    """Add drives: split each into per-path sequences, pick older drives of the same path and light,
    align them frame by frame, and store each drive compressed against them.

    Several videos (or folders) are ingested oldest first; drives of different roads at the same
    time (--workers N, or a Dask cluster with --scheduler), a drive on a road another one of the
    batch covers after that one is in (so it can use it). Each drive is added in one transaction:
    a failure or a crash changes nothing for that drive.
    """
    import datetime as dt

    from egovid.cli.validate import number
    from egovid.dashcam.ingest import DriveInput, IngestOptions
    from egovid.dashcam.ingest.run import ingest_drive, ingest_many, plan_batch
    from egovid.engine import EngineConfig, scheduler_address
    from egovid.errors import EgovidError

    number(gps_offset, "--gps-offset", lo=-7 * 86400, hi=7 * 86400, unit="s")
    ar = _open(archive)
    files = _videos(videos)
    if len(files) > 1 and (gps is not None or name is not None or start is not None):
        raise EgovidError("--gps, --name and --start name one drive", "give one video with them, or leave them out")
    start_utc = None
    if start is not None:
        try:
            t = dt.datetime.fromisoformat(start.replace("Z", "+00:00"))
        except ValueError:
            raise EgovidError(f"--start {start!r} is not an ISO 8601 time", "write e.g. 2026-05-04T08:00:00Z") from None
        start_utc = (t if t.tzinfo else t.replace(tzinfo=dt.UTC)).timestamp()
    if json_out is not None:
        check_output(json_out)
    opts = IngestOptions.from_preset(
        preset,
        q=q,
        speed=speed,
        threads=threads,
        gop=gop,
        refresh=random_access,
        aligner=aligner,
        baseline_align=baseline_align,
        measure_savings=measure_savings,
        verify=verify,
    ).check()
    config = EngineConfig(scheduler=scheduler_address(scheduler), workers=workers, retries=2)
    drives = [DriveInput(f, gps, name, start_utc, gps_offset) for f in files]
    if len(drives) == 1 and config.scheduler is None:
        with staged_progress() as cb:
            rep = ingest_drive(ar, drives[0], opts, progress=cb)
        _print_report(rep)
        if json_out is not None:
            from egovid.io.files import atomic_write_text

            atomic_write_text(json_out, json.dumps(rep.to_dict(), indent=1, default=str))
        return
    batch = plan_batch(ar, drives, opts)
    where = f"Dask cluster {config.scheduler}" if config.scheduler else f"{workers} local worker(s)"
    console.print(f"{len(batch.jobs)} drives, oldest first, on {where} (preset {opts.preset})")
    results, failed = [], []
    with staged_progress() as cb:
        cb("drives", 0, len(batch.jobs))
        for res in ingest_many(ar, batch, config):
            if res.report is not None:
                results.append(res.report)
                _print_report(res.report)
            else:
                failed.append(res)
                console.print(f"[red]drive {res.name!r} not added[/]: {res.error}")
            cb("drives", len(results) + len(failed), len(batch.jobs))
    if json_out is not None:
        from egovid.io.files import atomic_write_text

        doc = {
            "drives": [r.to_dict() for r in results],
            "failed": [{"drive": f.name, "error": f.error} for f in failed],
        }
        atomic_write_text(json_out, json.dumps(doc, indent=1, default=str))
    if failed:
        raise EgovidError(
            f"{len(failed)} of {len(batch.jobs)} drives were not added ({', '.join(f.name for f in failed)})",
            "see the reasons above; the other drives are in the archive, run the command again for these",
        )


def _print_report(rep) -> None:
    for p in rep.pieces:
        saving = f", saving {100 * p.saving:.1f} % vs standalone" if p.saving is not None else ""
        ref = f" against {p.ref_drive}" if p.ref_drive else " (root: no older drive of this path and light)"
        console.print(
            f"{rep.name} frames {p.frames[0]}-{p.frames[1] - 1}: path {p.path_id}, {p.mode}{ref}, "
            f"{p.bytes / 1024:.0f} KiB, PSNR-Y {p.psnr_y:.2f} dB{saving}"
        )
    console.print(
        f"drive {rep.name!r} added: {rep.frames} frames in {rep.seconds:.1f} s ({rep.fps:.1f} fps); "
        f"new paths {rep.new_paths or 'none'}, split paths {rep.split_paths or 'none'}"
    )


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
    from egovid.dashcam.extract import extract_video

    with staged_progress() as cb:
        extract_video(ar, d, out, progress=lambda k, n: cb("extract", k, n), frames=(f0, f1))
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
    for f in junk:
        console.print(f"  {f.name} ({f.size / 1024:.0f} KiB)")


@app.command("report")
def report(
    archive: Path = typer.Argument(..., help="Archive folder."),
    json_out: Path = typer.Option(None, "--json", help="Write the report as JSON."),
) -> None:
    """Bits per path and per drive, and the savings of joint coding."""
    from rich.table import Table

    from egovid.dashcam.report import archive_report

    rep = archive_report(_open(archive))
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
    console.print(f"bitstreams in {rep['blobs']}: {rep['blob_bytes'] / 1024:.0f} KiB; {rep['codec']}")
    if json_out is not None:
        from egovid.io.files import atomic_write_text

        atomic_write_text(json_out, json.dumps(rep, indent=1, default=str))
