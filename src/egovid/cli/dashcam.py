"""``egovid dashcam``: the route-aware dashcam archive."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from egovid.cli.common import all_or_nothing, check_output, console, err_console, library_defaults, staged_progress

app = typer.Typer(
    help="Route-aware dashcam archive: drives on the same path are compressed against each other.",
    no_args_is_help=True,
)


_CHANNEL_HELP = (
    "Which camera of a multi-camera drive (front, rear, interior, Tesla's left_repeater …; default: the "
    "drive's main one), or all: every camera over the same time (≤ 1 frame apart), each to OUT-CAMERA.EXT "
    "beside the {what} named."
)


def _open(archive: Path):
    from egovid.dashcam.archive.store import open_archive

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
    from egovid.dashcam.archive.fleetstore import FleetStore
    from egovid.dashcam.archive.store import Archive
    from egovid.dashcam.codec.registry import describe

    output_folder(archive, what="archive folder")
    ar = Archive.create(archive, db, blobs, setup=FleetStore)  # the fleet tables (PostGIS where the server has it)
    console.print(f"archive {archive} created (catalogue: {ar.where}; blobs: {ar.blobs.url}; codec: {describe()})")


def _ingest_defaults() -> dict[str, object]:
    """The defaults ``ingest --help`` shows for the options it leaves to the library (IngestOptions'
    own, from a module light enough not to load OpenCV for a help text)."""
    from egovid.dashcam.codec import settings

    d = settings.ARCHIVE_DEFAULTS
    return {"q": d["q"], "gop": d["gop"], "random_access": d["refresh"]}


@app.command("ingest", cls=library_defaults(_ingest_defaults))
def ingest(
    archive: Path = typer.Argument(..., help="Archive folder (from `egovid dashcam init`)."),
    videos: list[Path] = typer.Argument(
        ...,
        help="Dashcam videos, or folders of them (searched recursively): the loop-recording files of one drive "
        "become one drive (a trip); event and parking files drives of their own kind.",
    ),
    gps: Path = typer.Option(
        None,
        "--gps",
        help="GPS log: GPX, NMEA 0183 or CSV (time,lat,lon,...); one log may cover several videos. Default: the "
        "file beside each video with its name and a .gpx, .nmea or .csv extension, else the GPS the camera "
        "embedded in the video (GoPro GPMF, Novatek/Viofo, BlackVue, Garmin, DJI, ... via ExifTool; NMEA text "
        "tracks).",
    ),
    name: str = typer.Option(
        None, help="Name of the drive in the archive (one drive only; default: its first file's name)."
    ),
    start: str = typer.Option(
        None, help="UTC start time of the video (ISO 8601) when nothing else tells it (one video only)."
    ),
    tz_offset: float = typer.Option(
        None,
        "--tz-offset",
        help="Hours the camera clock is ahead of UTC (8 for a camera set to UTC+8), for videos without GPS time "
        "whose creation_time or file names carry local time.",
    ),
    gps_offset: float = typer.Option(0.0, help="Seconds to add to each video's start to line it up with its GPS."),
    join: bool = typer.Option(True, help="Join consecutive loop-recording files into one drive (a trip)."),
    max_gap: float = typer.Option(10.0, "--max-gap", help="Longest gap in seconds between two files of one trip."),
    lock_events: bool = typer.Option(True, help="Lock event files as they are ingested (see `egovid dashcam lock`)."),
    preset: str = typer.Option(
        None,
        "--preset",
        help="realtime (default: pieces stored standalone in SVT-AV1 preset 10; a piece with an older drive "
        "is also coded against it in AV1 by libaom's realtime mode and the smaller at equal PSNR-Y kept) | "
        "balanced (SVT-AV1 preset 8; VP9 good-quality deadline, 2 threads) | archive (SVT-AV1 preset 6; the "
        "joint candidate in AV1 by libaom's good-quality mode, 1 thread: slowest). Figures in docs/dashcam.md "
        "say which baseline they are against: through this command, with the realtime preset, new drives of "
        "the different-day set are 33 % smaller than plain SVT-AV1 at the same preset and keyframe spacing "
        "(BD-rate, PSNR-Y), first drives within 0.3 % of it, and the whole archive 42 % smaller than the "
        "all-VP9 archive of before; against plain SVT-AV1 at the ingest's own speed (between presets 7 and 6) "
        "new drives are about as large (-4 % to +2 %); use --preset archive for the smallest files. The "
        "options below override it.",
    ),
    q: int = typer.Option(
        None,
        min=0,
        max=63,
        help="Quantiser on libvpx's 0-63 scale (0 = best quality, 63 = smallest): VP9 pieces at q, AV1 pieces at "
        "SVT-AV1 CRF q + 14, measured to give the same PSNR-Y.",
    ),
    codec: str = typer.Option(
        None,
        "--codec",
        help="What pieces stored standalone are coded with: av1 (default: SVT-AV1, decoded with dav1d) | vp9 "
        "(libvpx; with --joint-codec vp9 as archives before AV1). A piece with an older drive is coded both "
        "ways, against the older drive (--joint-codec) and standalone, and the smaller at equal PSNR-Y is kept.",
    ),
    joint_codec: str = typer.Option(
        None,
        "--joint-codec",
        help="What a piece with an older drive is also coded with, against it: aom (realtime and archive "
        "presets: AV1 by libaom with the older drive's aligned frame as a reference, extracted bit-exact by "
        "libaom's decoder with the same reference) | vp9 (balanced preset: libvpx; at the realtime preset's "
        "speed +29.6 % against plain SVT-AV1 preset 10 at equal PSNR-Y, so the standalone AV1 encode wins "
        "nearly every piece). Through this command on different-day drives (BD-rate, PSNR-Y; docs/dashcam.md): "
        "with --preset realtime (libaom's realtime mode, cpu-used 7) new drives are 32.9 % smaller than plain "
        "SVT-AV1 preset 10; with --preset archive (good quality) 39 % smaller than plain SVT-AV1 preset 6, "
        "32 % smaller than preset 4 and 25 % smaller than preset 3, the plain encoder at the ingest's own speed. "
        "The smaller of joint and standalone at equal PSNR-Y is kept, and why is recorded.",
    ),
    speed: int = typer.Option(
        None, min=0, max=9, help="libvpx cpu-used of the VP9 joint candidate (default: the preset's): higher = faster."
    ),
    threads: int = typer.Option(
        None, min=1, max=64, help="Encoder threads, libvpx's and SVT-AV1's (default: the preset's)."
    ),
    gop: int = typer.Option(
        None,
        min=1,
        max=64,
        help="Anchor spacing in frames: every GOP-th frame is coded first and the frames between "
        "refer to it (and to the older drive) at a coarser quantiser (+12). 1 = low delay.",
    ),
    random_access: int = typer.Option(
        None,
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
    verify: bool = typer.Option(
        True,
        help="Decode the new bitstream beside the encoder and compare: every random-access run with balanced "
        "and archive; the first, the last and a seeded quarter of the others with realtime (every run's digest "
        "is checked by every extract either way).",
    ),
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
    verify_known: bool = typer.Option(
        False,
        "--verify-known",
        help="Read a file the archive recognises (by its size and a sampled digest: its first and last MiB "
        "and 32 blocks between, docs/dashcam.md) whole and compare its SHA-256 too, as a file edited in place "
        "outside the sampled blocks would otherwise pass for the archived one. Reads the whole card.",
    ),
) -> None:
    """Add drives: split each into per-path sequences, pick older drives of the same path and light,
    align them frame by frame, and store each drive compressed against them.

    The time base is GPS time: the camera's own clock (creation_time, file names) counts only where
    the video holds no GPS time, and only where the GPS log confirms it. Several videos (or
    folders) are ingested oldest first; drives of different roads at the same time (--workers N,
    or a Dask cluster with --scheduler), a drive on a road another one of the batch covers after
    that one is in (so it can use it). Each drive is added in one transaction: a failure or a
    crash changes nothing for that drive. Files that cannot be used are listed with the reason.
    Files the archive holds already (by content, whatever their names) are skipped; a card that
    holds nothing new is answered before the ingest pipeline is even loaded.
    """
    from egovid.cli import validate
    from egovid.core.files import atomic_write_text

    validate.number(gps_offset, "--gps-offset", lo=-7 * 86400, hi=7 * 86400, unit="s")
    validate.number(tz_offset, "--tz-offset", lo=-14, hi=14, unit="hours")
    validate.number(max_gap, "--max-gap", lo=0, hi=3600, unit="s")
    ar = _open(archive)
    start_utc = _utc(start, "--start") if start is not None else None
    for v in videos:
        if v.is_dir():
            validate.input_folder(v, "folder")
        else:
            validate.input_file(v, "video")
    log = validate.gps_input(gps) if gps is not None else None
    validate.outputs(videos, (json_out, validate.JSON, "--json"))
    coding = {
        "q": q,
        "codec": codec,
        "joint_codec": joint_codec,
        "speed": speed,
        "threads": threads,
        "gop": gop,
        "refresh": random_access,
    }
    # Coding options given are checked before anything else, even when the card holds nothing new
    # (a typo in a sync job's options must not pass unseen until the day a new drive comes); with
    # the defaults the light first step stays light (the ingest pipeline is not imported).
    defaults = aligner == "orb" and baseline_align == "none"
    given = preset is not None or any(v is not None for v in coding.values()) or not defaults
    opts = _ingest_options(preset, coding, aligner, baseline_align, measure_savings, verify) if given else None
    single = len(videos) == 1 and not videos[0].is_dir()  # one file named: its problems are errors even when known
    if name is None and start_utc is None and not single and _nothing_new(ar, videos, verify_known, json_out):
        return
    from egovid.core.engine import EngineConfig, scheduler_address
    from egovid.dashcam import ingest as library

    if opts is None:
        opts = _ingest_options(preset, coding, aligner, baseline_align, measure_savings, verify)
    engine = EngineConfig(scheduler=scheduler_address(scheduler), workers=workers, retries=2)
    with staged_progress() as cb:
        result = library.ingest_videos(
            ar,
            videos,
            gps=log,
            clock=library.ClockOptions(start_utc, tz_offset, gps_offset),
            name=name,
            join=join,
            max_gap=max_gap,
            lock_events=lock_events,
            options=opts,
            engine=engine,
            verify_known=verify_known,
            hooks=library.IngestHooks(
                progress=cb,
                skipped=lambda path, why: err_console.print(f"skipped {path}: {why}"),
                batch=lambda n, where: console.print(f"{n} drives, oldest first, on {where} (preset {opts.preset})"),
                drive=_print_outcome,
            ),
        )
    if json_out is not None:
        atomic_write_text(json_out, json.dumps(result.to_dict(), indent=1, default=str))
    _say_known(result.known, result.nothing_new)
    result.check()


def _ingest_options(preset, coding: dict, aligner: str, baseline_align: str, measure_savings: bool, verify: bool):
    """The ingest's coding options from ``--preset`` and the options that override it, checked
    (:class:`EgovidError` for a bad value or combination)."""
    from egovid.dashcam.ingest import IngestOptions

    return IngestOptions.from_preset(
        preset,
        **coding,
        aligner=aligner,
        baseline_align=baseline_align,
        measure_savings=measure_savings,
        verify=verify,
    ).check()


def _say_known(known: int, nothing_new: bool) -> None:
    """The ingest's last words on the files the archive held already."""
    if known:
        console.print(f"{known} file(s) already archived (same content), skipped")
    if nothing_new:  # the same card again (a sync job): not a failure (the rest is listed above)
        console.print("nothing new: the drives of these videos are already in the archive")


def _nothing_new(ar, videos: list[Path], verify: bool, json_out: Path | None) -> bool:
    """The light first step of an ingest: when the archive holds every input file already (by
    content, :func:`egovid.dashcam.archive.identity.all_known`), say so (and write the JSON report
    the ingest would) and return True, without loading the ingest pipeline (its decoders, aligners
    and codecs take seconds to import); False: something may be new, the ingest proper decides."""
    from egovid.core.files import atomic_write_text
    from egovid.dashcam.archive.identity import all_known, already_in

    hits = all_known(ar, videos, verify=verify)
    if hits is None:
        return False
    if json_out is not None:  # as IngestResult.to_dict writes a batch with nothing added
        skipped = [{"file": str(f), "reason": already_in(k)} for f, k in hits]
        atomic_write_text(json_out, json.dumps({"drives": [], "failed": [], "skipped": skipped}, indent=1))
    _say_known(len(hits), True)
    return True


def _print_outcome(outcome) -> None:
    """A drive of the ingest ended: its report, or why it was not added."""
    if outcome.report is not None:
        _print_report(outcome.report, outcome.prepared)
    else:
        console.print(f"[red]drive {outcome.name!r} not added[/]: {outcome.error}")


def _print_report(rep, fleet=None) -> None:
    """An ingest's report on the console (``fleet``: the prepared drive, for its files and clock)."""
    for p in rep.pieces:
        saving = f", saving {100 * p.saving:.1f} % vs standalone AV1" if p.ref_drive and p.saving is not None else ""
        ref = f" against {p.ref_drive}" if p.ref_drive else " (root: no older drive of this path and light)"
        if not p.ref_drive and p.standalone_bytes is not None:
            ref = " (standalone: smaller than coded against the older drive)"
        console.print(
            f"{rep.name} frames {p.frames[0]}-{p.frames[1] - 1}: path {p.path_id}, {p.mode}{ref}, "
            f"{p.bytes / 1024:.0f} KiB, PSNR-Y {p.psnr_y:.2f} dB{saving}"
        )
    what = fleet.describe() if fleet is not None else ""
    console.print(
        f"drive {rep.name!r} added:{what} {rep.frames} frames in {rep.seconds:.1f} s ({rep.fps:.1f} fps); "
        f"new paths {rep.new_paths or 'none'}, split paths {rep.split_paths or 'none'}"
    )
    for note in fleet.notes if fleet is not None else ():
        err_console.print(f"note: {rep.name}: {note}")
    for why in rep.encoder_restarts:
        err_console.print(f"note: {rep.name}: an encoder was restarted ({why}); the piece was coded again")


def _table(title: str, columns: tuple[str, ...], rows, right: tuple[str, ...] | bool = ()):
    """A Rich table of ``rows`` (tuples of strings); ``right``: the columns aligned right (True: all)."""
    from rich.table import Table

    t = Table(title=title)
    for col in columns:
        t.add_column(col, justify="right" if right is True or col in right else "left")
    for row in rows:
        t.add_row(*row)
    return t


def _kib(n: float) -> str:
    return f"{n / 1024:.0f} KiB"


@app.command("list")
def list_cmd(archive: Path = typer.Argument(..., help="Archive folder.")) -> None:
    """List the drives in the archive: one row per drive, its other cameras (a dashcam's rear,
    interior) in the `cameras` column and their bytes in `stored`."""
    import datetime as dt

    from egovid.dashcam.report import list_drives

    rows = [
        (
            str(r.drive.id),
            r.drive.name,
            dt.datetime.fromtimestamp(r.drive.start_utc, dt.UTC).strftime("%Y-%m-%d %H:%M:%S"),
            str(r.drive.frames),
            f"{r.drive.width}x{r.drive.height}",
            _kib(r.bytes),
            ", ".join(r.modes),
            ", ".join(r.cameras),
        )
        for r in list_drives(_open(archive))
    ]
    head = ("id", "drive", "start (UTC)", "frames", "size", "stored", "modes", "cameras")
    console.print(_table(str(archive), head, rows))


@app.command("show")
def show(
    archive: Path = typer.Argument(..., help="Archive folder."),
    drive: str = typer.Argument(..., help="Drive name or id."),
) -> None:
    """Show how a drive is stored: its path sequences and segments."""
    from egovid.dashcam.report import describe_drive

    lay = describe_drive(_open(archive), drive)
    d = lay.drive
    console.print(f"[bold]{d.name}[/] (id {d.id}): {d.frames} frames, {d.width}x{d.height} @ {d.fps:g} fps")
    console.print(f"source {d.source}\nGPS    {d.gps_source}")
    for s in lay.sequences:
        console.print(
            f"  path {s.path_id}: frames {s.frame_start}-{s.frame_end - 1}, "
            f"{s.positions.min():.0f}-{s.positions.max():.0f} m along the path, segment {s.segment_id}"
        )
    for g, ref in lay.segments:
        alone = g.params.get("standalone_bytes")
        extra = f", standalone {_kib(alone)} ({100 * (1 - g.bytes / alone):.1f} % saved)" if alone else ""
        console.print(
            f"  segment {g.id}: frames {g.frame_start}-{g.frame_end - 1}, {g.mode}"
            f"{' against ' + ref if ref else ''}, {_kib(g.bytes)}, "
            f"PSNR-Y {g.params.get('psnr_y', float('nan')):.2f} dB{extra}"
        )


@app.command("extract")
def extract(
    archive: Path = typer.Argument(..., help="Archive folder."),
    drive: str = typer.Argument(..., help="Drive name or id."),
    out: Path = typer.Option(None, "-o", "--out", help="Output video: .mkv (FFV1) or .mp4 (lossless H.264)."),
    start: float = typer.Option(None, "--start", min=0.0, help="Write from this time (seconds into the drive)."),
    duration: float = typer.Option(None, "--duration", min=0.0, help="Write this many seconds (default: to the end)."),
    channel: str = typer.Option(None, "--channel", help=_CHANNEL_HELP.format(what="video")),
    readings_out: Path = typer.Option(
        None,
        "--readings",
        help="Also (or, without -o, only) write the readings the car recorded (speed, acceleration, "
        "steering …; Tesla) as CSV.",
    ),
) -> None:
    """Write a drive back as a video, bit-exact with what the encoder reconstructed.

    With --start/--duration only that stretch is decoded: decoding begins at the nearest
    random-access point before it (every 24 frames by default), in this drive and in the older
    drives it was coded against. A drive of a multi-camera dashcam writes its main camera, or
    the one --channel names (--channel all: each camera, recorded over the same time). --readings
    writes the drive's recorded readings over the same stretch as CSV (t_s: seconds into the
    drive, utc, then one column per channel).
    """
    from egovid.cli import validate
    from egovid.core.errors import EgovidError
    from egovid.dashcam.extract import (
        ALL_CHANNELS,
        ExtractJob,
        channel_jobs,
        channel_name,
        channel_output,
        extract_drive,
        plan_extract,
    )

    if out is None and readings_out is None:
        raise EgovidError("nothing to write", "give -o VIDEO (.mkv or .mp4), --readings FILE.csv, or both")
    channel = channel_name(channel)
    ar = _open(archive)
    if out is not None:
        check_output(out, exts=".mkv .mp4")
    validate.outputs([out], (readings_out, validate.CSV, "--readings"))
    job = plan_extract(ar, drive, start, duration)  # checked before the progress display starts
    if readings_out is not None:
        from egovid.dashcam.readings import drive_readings, require_readings, write_csv

        require_readings(ar, job.drive.id, job.drive.name)
    if out is not None:
        jobs = channel_jobs(ar, job.drive, job.frame_start, job.frame_end, channel)
        outs = [channel_output(out, j.channel, channel == ALL_CHANNELS) for j in jobs]
        for o in outs:
            check_output(o, exts=".mkv .mp4")
        with staged_progress() as cb:
            for j, o in zip(jobs, outs, strict=True):
                extract_drive(ar, ExtractJob(j.drive, j.frame_start, j.frame_end), o,
                              lambda k, n, c=j.channel: cb(f"extract {c}", k, n))  # fmt: skip
        for j, o in zip(jobs, outs, strict=True):
            what = job.drive.name if j.drive.id == job.drive.id else f"{job.drive.name} ({j.channel} camera)"
            console.print(f"{what}: frames {j.frame_start}-{j.frame_end - 1} of {j.drive.frames} → {o}")
    if readings_out is not None:
        fps = job.drive.fps
        rd = drive_readings(ar, job.drive.id, job.frame_start / fps, job.frame_end / fps)
        write_csv(rd, readings_out)
        console.print(f"{job.drive.name}: {len(rd)} readings ({rd.source}) → {readings_out}")


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
    console.print(f"{verb} {len(junk)} unreferenced file(s), {_kib(size)}")
    for f in junk:
        console.print(f"  {f.name} ({_kib(f.size)})")


@app.command("report")
def report(
    archive: Path = typer.Argument(..., help="Archive folder."),
    json_out: Path = typer.Option(None, "--json", help="Write the report as JSON."),
    html_out: Path = typer.Option(
        None, "--html", help="Also draw the drives on a map: one self-contained HTML page (works offline)."
    ),
    colour: str = typer.Option("drive", "--colour", help="Map tracks coloured by drive or by saving."),
    tiles: str = typer.Option(
        "osm",
        "--tiles",
        help="Map background: osm (OpenStreetMap tiles, fetched by the browser only when online), "
        "none, or an XYZ tile URL with {z}/{x}/{y}.",
    ),
    figures: Path = typer.Option(
        None,
        "--figures",
        help="Folder for figures: speed and acceleration over time of each drive whose car recorded them "
        "(DRIVE-readings.png).",
    ),
) -> None:
    """Bits per path and per drive, and the savings of joint coding; with --html, a map of the
    drives (tracks coloured by drive or by saving, click one for its details). A drive whose car
    recorded readings (Tesla) has their summary in the JSON (maximum speed and accelerations);
    --figures draws them."""
    from egovid.cli import validate
    from egovid.core.files import atomic_write_text
    from egovid.dashcam.mapdata import archive_map
    from egovid.dashcam.report import archive_report

    validate.choice(colour, "--colour", ("drive", "saving"))
    validate.outputs([], (json_out, validate.JSON, "--json"), (html_out, validate.HTML, "--html"))
    if figures is not None:
        validate.output_folder(figures, what="--figures folder")
    ar = _open(archive)
    rep = archive_report(ar)
    if figures is not None:
        _readings_figures(ar, rep, figures)
    saving = lambda v: f"{100 * v:.1f} %" if v is not None else "-"  # noqa: E731
    paths = [
        (
            str(p["path"]),
            f"{p['length_m']:.0f} m",
            str(p["sequences"]),
            str(p["frames"]),
            _kib(p["bytes"]),
            f"{p['bits_per_frame']:.0f}",
            saving(p["saving"]),
        )
        for p in rep["paths"]
    ]
    cols = ("path", "length", "sequences", "frames", "stored", "bits/frame", "saving")
    console.print(_table("paths", cols, paths, right=True))
    drives = [
        (
            d["drive"],
            str(d["frames"]),
            _kib(d["bytes"]),
            f"{d['bits_per_frame']:.0f}",
            str(d["joint_frames"]),
            saving(d["saving_on_joint_frames"]),
            ", ".join(d["references"]) or "-",
            _camera_cell(d),
        )
        for d in rep["drives"]
    ]
    cols = ("drive", "frames", "stored", "bits/frame", "joint frames", "saving", "references", "camera")
    console.print(_table("drives", cols, drives, right=True))
    console.print(f"bitstreams in {rep['blobs']}: {_kib(rep['blob_bytes'])}; {rep['codec']}")
    for d in (d for d in rep["drives"] if d.get("readings")):
        r, a = d["readings"], d["readings"]["max_abs_accel_mps2"]
        accel = ", ".join(f"{k} {v:.2f}" for k, v in a.items() if v is not None) or "-"
        speed = f"{3.6 * r['max_speed_mps']:.1f} km/h" if r["max_speed_mps"] is not None else "-"
        console.print(f"{d['drive']}: recorded readings ({r['source']}, {r['samples']} samples): "
                      f"max speed {speed}, max |acceleration| (m/s²) {accel}")  # fmt: skip
    if json_out is not None:
        atomic_write_text(json_out, json.dumps(rep, indent=1, default=str))
    if html_out is not None:
        page = archive_map(ar, colour_by=colour, tiles=tiles)
        atomic_write_text(html_out, page.html)
        note = f" ({len(page.missing)} drive(s) without a GPS track: {', '.join(page.missing)})" if page.missing else ""
        console.print(f"map of {len(page.drives)} drive(s) → {html_out}{note}")


def _camera_cell(row: dict) -> str:
    """A drive's camera in the report's table: ``front``, ``front (+rear)`` for a drive with other
    cameras, ``rear of NAME`` for such a camera's row."""
    if row.get("channel_of"):
        return f"{row['channel']} of {row['channel_of']}"
    more = [c for c in row.get("channels", {}) if c != row["channel"]]
    return row["channel"] + (f" (+{', '.join(more)})" if more else "")


def _readings_figures(ar, rep: dict, folder: Path) -> None:
    """Draw the recorded readings of the report's drives into ``folder``; each figure's path goes
    into its drive's ``readings`` summary."""
    from egovid.dashcam.archive.fleetstore import live_drives
    from egovid.dashcam.readings_figures import draw_report_figures

    drawn = draw_report_figures(ar, folder, live_drives(ar.catalogue))
    for d in rep["drives"]:
        if d["drive"] in drawn and d.get("readings"):
            d["readings"]["figure"] = str(drawn[d["drive"]])
    console.print(f"readings of {len(drawn)} drive(s) drawn → {folder}" if drawn else "no drive has recorded readings")


# -- the fleet commands: find, clip, forget, lock, unlock -------------------------------------------


def _utc(text: str, option: str) -> float:
    """``--at``/``--from``/``--to``: ISO 8601 (``2024-05-04T08:00:00Z``, ``+02:00``; no zone = UTC)."""
    from egovid.core.errors import EgovidError
    from egovid.core.times import iso_to_utc

    try:
        return iso_to_utc(text)
    except ValueError:
        raise EgovidError(f"{option} {text!r} is not an ISO 8601 time", "write e.g. 2024-05-04T08:00:00Z") from None


def _floats(text: str, n: int, option: str, example: str) -> tuple[float, ...]:
    from egovid.core.errors import EgovidError

    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != n:
        raise EgovidError(f"{option} {text!r} is not {n} comma-separated numbers", f"write e.g. {option} {example}")
    return vals


def _write_json(target: str, obj) -> None:
    """JSON to a file (checked before the work by the command) or, for ``-``, to stdout."""
    if target == "-":
        typer.echo(json.dumps(obj, indent=1, default=str))
        return
    from egovid.core.files import atomic_write_text

    atomic_write_text(Path(target), json.dumps(obj, indent=1, default=str))


def _json_output(json_out: str | None) -> None:
    """Check a ``--json`` file before the work (``-``, stdout, needs no check)."""
    if json_out not in (None, "-"):
        from egovid.cli import validate

        validate.outputs([], (Path(json_out), validate.JSON, "--json"))


@app.command("find")
def find_cmd(
    archive: Path = typer.Argument(..., help="Archive folder."),
    near: str = typer.Option(None, "--near", help="A place, LAT,LON in degrees (WGS 84), e.g. 48.1372,11.5756."),
    radius: float = typer.Option(50.0, "--radius", help="Metres around --near that count as near."),
    bbox: str = typer.Option(None, "--bbox", help="A box, WEST,SOUTH,EAST,NORTH in degrees."),
    t_from: str = typer.Option(None, "--from", help="Recorded at or after this time (ISO 8601; no zone = UTC)."),
    t_to: str = typer.Option(None, "--to", help="Recorded before this time (ISO 8601; no zone = UTC)."),
    json_out: str = typer.Option(None, "--json", help="Write the stretches as JSON to this file (- for stdout)."),
) -> None:
    """Find where and when drives were recorded: every stretch of a drive that passed within
    --radius metres of --near, inside --bbox, and/or between --from and --to (all given criteria
    must hold). Prints drive, UTC start and end, frames and closest distance; `egovid dashcam
    clip` cuts any of them out.

    Uses the catalogue's spatial index (SQLite R*Tree; PostGIS or a GiST index in PostgreSQL)
    over the drives' GPS tracks.
    """
    from egovid.dashcam.find import Query, search
    from egovid.dashcam.route.clock import iso

    q = Query(
        near=_floats(near, 2, "--near", "48.1372,11.5756") if near else None,
        radius=radius,
        bbox=_floats(bbox, 4, "--bbox", "11.50,48.10,11.60,48.20") if bbox else None,
        t_from=_utc(t_from, "--from") if t_from else None,
        t_to=_utc(t_to, "--to") if t_to else None,
    )
    _json_output(json_out)
    found = search(_open(archive), q)
    if json_out is not None:
        _write_json(json_out, [s.to_dict() for s in found])
        if json_out == "-":
            return
    cols = ("drive", "kind", "start (UTC)", "end (UTC)", "frames", "closest")
    rows = [
        (
            s.drive,
            s.kind,
            iso(s.start_utc),
            iso(s.end_utc),
            f"{s.frame_start}-{s.frame_end - 1}",
            f"{s.distance_m:.1f} m" if s.distance_m is not None else "-",
        )
        for s in found
    ]
    console.print(_table(f"{len(found)} stretch(es)", cols, rows, right=("frames", "closest")))


@app.command("clip")
@all_or_nothing
def clip_cmd(
    archive: Path = typer.Argument(..., help="Archive folder."),
    out: Path = typer.Option(..., "-o", "--out", help="The clip to write: an .mp4 (H.264; its .gpx goes beside it)."),
    at: str = typer.Option(None, "--at", help="The moment, ISO 8601 UTC (e.g. 2024-05-04T08:12:30Z)."),
    near: str = typer.Option(None, "--near", help="Or the place, LAT,LON: the closest pass of the latest drive there."),
    radius: float = typer.Option(50.0, "--radius", help="Metres around --near that count as a pass."),
    drive: str = typer.Option(None, "--drive", help="Only this drive (name or id)."),
    before: float = typer.Option(10.0, "--before", help="Seconds before the moment."),
    after: float = typer.Option(10.0, "--after", help="Seconds after the moment."),
    crf: int = typer.Option(18, "--crf", min=0, max=51, help="x264 quality (lower = better, larger)."),
    lossless: bool = typer.Option(False, "--lossless", help="Lossless H.264: every frame bit-exact with the archive."),
    channel: str = typer.Option(None, "--channel", help=_CHANNEL_HELP.format(what="clip")),
) -> None:
    """Cut an incident clip: the frames around a moment (--at) or a place (--near) as a shareable
    H.264 MP4, with the archived audio and telemetry of that stretch, and its GPS track as GPX
    beside it (incident.gpx). Frames are those the archive decodes, checked against the encoder's
    digests like extract; --lossless keeps them bit for bit.
    """
    from egovid.cli import validate
    from egovid.dashcam.clip import channel_plans, plan_clip, write_clip
    from egovid.dashcam.extract import ALL_CHANNELS, channel_name, channel_output

    channel = channel_name(channel)
    validate.outputs([], (out, ".mp4", "clip"), (out.with_suffix(".gpx"), ".gpx", "GPX beside the clip"))
    validate.number(radius, "--radius", lo=0, lo_open=True, hi=100_000, unit="m")
    validate.number(before, "--before", lo=0, hi=3600, unit="s")
    validate.number(after, "--after", lo=0, hi=3600, unit="s")
    moment = _utc(at, "--at") if at else None
    place = _floats(near, 2, "--near", "48.1372,11.5756") if near else None
    ar = _open(archive)
    plan = plan_clip(ar, at=moment, near=place, radius=radius, drive=drive, before=before, after=after)
    plans = channel_plans(ar, plan, channel)
    outs = [channel_output(out, ch, channel == ALL_CHANNELS) for ch in plans]
    for o in outs:
        validate.outputs([], (o, ".mp4", "clip"), (o.with_suffix(".gpx"), ".gpx", "GPX beside the clip"))
    with staged_progress() as cb:
        reps = [write_clip(ar, p, o, crf=crf, lossless=lossless, progress=lambda k, n, c=ch: cb(f"clip {c}", k, n))
                for (ch, p), o in zip(plans.items(), outs, strict=True)]  # fmt: skip
    for rep, o in zip(reps, outs, strict=True):
        extra = f", with {' and '.join(rep['streams'])}" if rep["streams"] else ""
        gpx = f"; {rep['gpx']} ({rep['gps_fixes']} fixes)" if rep["gpx"] else "; no GPS fixes in the stretch"
        console.print(
            f"{rep['drive']}: frames {rep['frame_start']}-{rep['frame_end'] - 1} from {rep['start']} → {o}{extra}{gpx}"
        )


@app.command("forget")
def forget_cmd(
    archive: Path = typer.Argument(..., help="Archive folder."),
    drives: list[str] = typer.Argument(None, help="Drives to forget (names or ids)."),
    older_than: str = typer.Option(
        None, "--older-than", help="Also every unlocked drive recorded longer ago than this: 90d, 12h, 2w, 1y."
    ),
    keep_bytes: str = typer.Option(
        None,
        "--keep-bytes",
        help="Also the oldest unlocked drives until the archive fits in this: 200G, 1.5T, 500M (binary units).",
    ),
    dry_run: bool = typer.Option(False, "--dry-run", help="Only say what would be forgotten and freed."),
    verify: bool = typer.Option(True, help="Decode every drive coded against a forgotten one before committing."),
    json_out: str = typer.Option(None, "--json", help="Write what was done as JSON (- for stdout)."),
) -> None:
    """Forget drives and free their space; locked drives are never forgotten.

    A drive other drives are coded against keeps exactly the frames they need (hidden, no longer
    listed), so every remaining drive extracts bit for bit as before (checked before anything
    changes, unless --no-verify). One transaction: a forget that is killed changes nothing, or
    leaves only unreferenced bitstreams for `egovid dashcam gc`.
    """
    from egovid.core.errors import EgovidError
    from egovid.dashcam.forget import forget
    from egovid.dashcam.retention import parse_duration, parse_size

    age = parse_duration(older_than) if older_than else None
    budget = parse_size(keep_bytes) if keep_bytes else None
    if not drives and age is None and budget is None:
        raise EgovidError("nothing to forget", "name drives, or give --older-than AGE and/or --keep-bytes SIZE")
    _json_output(json_out)
    rep = forget(
        _open(archive), list(drives or []), older_than_s=age, keep_bytes=budget, verify=verify, dry_run=dry_run,
        say=err_console.print,
    )  # fmt: skip
    out = err_console if json_out == "-" else console  # stdout holds only the JSON then
    if not rep.forgotten:
        if json_out is not None:
            _write_json(json_out, {"forgotten": [], "skipped_locked": rep.skipped_locked, "bytes_freed": 0})
        out.print("nothing to forget")
        return
    out.print(f"{'would forget' if dry_run else 'forgot'} {len(rep.forgotten)} drive(s): {', '.join(rep.forgotten)}")
    for name, needers in rep.kept_as_reference.items():
        out.print(f"  {name}: kept only the frames {', '.join(needers)} are coded against (hidden)")
    out.print(f"{'would free' if dry_run else 'freed'} {rep.bytes_freed / 1024**2:.2f} MiB ({rep.bytes_freed} bytes)")
    if json_out is not None:
        _write_json(json_out, rep.to_dict())


@app.command("lock")
def lock_cmd(
    archive: Path = typer.Argument(..., help="Archive folder."),
    drives: list[str] = typer.Argument(..., help="Drives to protect (names or ids)."),
    note: str = typer.Option(None, "--note", help="Why (shown by forget when it refuses)."),
) -> None:
    """Protect drives from `forget` and its policies (event files are locked when ingested)."""
    from egovid.dashcam.forget import set_lock

    found = set_lock(_open(archive), drives, True, note)
    console.print(f"locked {', '.join(d.name for d in found)}")


@app.command("unlock")
def unlock_cmd(
    archive: Path = typer.Argument(..., help="Archive folder."),
    drives: list[str] = typer.Argument(..., help="Drives to unprotect (names or ids)."),
) -> None:
    """Let `forget` remove drives again."""
    from egovid.dashcam.forget import set_lock

    found = set_lock(_open(archive), drives, False)
    console.print(f"unlocked {', '.join(d.name for d in found)}")


@app.command("backup")
def backup(
    archive: Path = typer.Argument(..., help="Archive folder."),
    file: Path = typer.Argument(..., help="The backup file to write (new; an SQLite database)."),
) -> None:
    """Write a consistent copy of the archive's catalogue (SQLite or PostgreSQL) to FILE, also
    while ingests run. The bitstreams are not in it: copy the blob store as it is."""
    from egovid.dashcam.backup import backup_catalogue

    rep = backup_catalogue(_open(archive), file)
    console.print(f"catalogue of {archive} ({rep.drives} drive(s)) written to {rep.file}")


@app.command("restore")
def restore(
    file: Path = typer.Argument(..., help="A backup file written by `egovid dashcam backup`."),
    archive: Path = typer.Argument(..., help="An empty archive (made by `egovid dashcam init`, any --db/--blobs)."),
) -> None:
    """Load a catalogue backup into an empty archive, in one transaction (an interruption leaves
    it empty). Copy the bitstreams into its blob store; `egovid dashcam check` says if any is missing."""
    from egovid.dashcam.backup import restore_catalogue

    rep = restore_catalogue(file, _open(archive))
    console.print(f"restored {rep.drives} drive(s) from {file} into {archive}")


@app.command("check")
def check(
    archive: Path = typer.Argument(..., help="Archive folder."),
    repair: bool = typer.Option(
        False,
        "--repair",
        help="Rebuild what can be rebuilt: restore a damaged or deleted catalogue from its last backup (or "
        "salvage what SQLite can read), rebuild the spatial index, delete temporary files of interrupted "
        "ingests. Bitstreams are never changed.",
    ),
    deep: bool = typer.Option(False, "--deep", help="Also decode every drive and compare with the encoder's digests."),
) -> None:
    """Verify an archive: its catalogue, every bitstream (present, SHA-256 intact), every drive's
    segments and reference chains (no loops, no missing drives).

    Prints what it found; exits with status 2 when something cannot be read back.
    """
    from egovid.cli.validate import input_folder, writable_folder
    from egovid.dashcam.check import check_archive

    input_folder(archive, "archive folder")
    if repair:  # it may write: refused up front on a read-only disk (a plain check works there)
        writable_folder(archive, "archive folder", "--repair")
    with staged_progress() as cb:
        rep = check_archive(archive, repair=repair, deep=deep, progress=cb)
    for f in rep.findings:
        mark = "repaired" if f.repaired else f.severity
        console.print(f"{mark:>8}  {f.problem}" + (f" ({f.fix})" if f.fix else ""), highlight=False, soft_wrap=True)
    mib = rep.blob_bytes / 2**20
    decoded = f", {rep.decoded_frames} frames decoded and compared" if deep else ""
    console.print(
        f"{rep.drives} drive(s), {rep.segments} segment(s), {rep.blobs} bitstream(s) ({mib:.1f} MiB) verified{decoded}",
        soft_wrap=True,
    )
    failure = rep.failure(repair)
    if failure is not None:
        raise failure
    console.print(f"archive {archive} is sound", soft_wrap=True)
