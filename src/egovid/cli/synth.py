"""``egovid synth``: synthetic test videos with ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from egovid.cli.common import all_or_nothing, console, parse_size, progress_bar
from egovid.cli.validate import CSV, TUM, VIDEO_OUT, choice, number, outputs
from egovid.core.errors import EgovidError

app = typer.Typer(help="Make synthetic test videos with known ground truth.", no_args_is_help=True)


@app.command("fpv")
@all_or_nothing
def synth_fpv(
    out: Path = typer.Argument(..., help="Output video (.mp4 = H.264, .mkv = lossless FFV1)."),
    motion: str = typer.Option("running", help="running | pan | random-walk | still."),
    frames: int = typer.Option(300, min=2, help="Number of frames."),
    size: str = typer.Option("1280x720", help="WIDTHxHEIGHT in pixels."),
    fps: float = typer.Option(30.0, min=1.0, max=240.0, help="Frame rate."),
    yaw_amp: float = typer.Option(10.0, help="running: yaw sine amplitude (degrees)."),
    pitch_amp: float = typer.Option(2.5, help="running: pitch sine amplitude (degrees), at twice the yaw rate."),
    period: float = typer.Option(24.0, min=2.0, help="running: yaw period in frames (one stride)."),
    roll_amp: float = typer.Option(1.5, help="Roll sway amplitude (degrees); 0 for none."),
    pan_deg: float = typer.Option(40.0, help="pan: total yaw of the pan (degrees)."),
    jitter_deg: float = typer.Option(0.1, min=0.0, help="Added white shake per axis (degrees, std)."),
    noise: float = typer.Option(2.0, min=0.0, max=50.0, help="Sensor noise std in 8-bit grey levels."),
    forward: float = typer.Option(0.0, min=0.0, max=0.2, help="Forward walk in metres per frame (scene radius 10 m)."),
    scene: str = typer.Option("panorama", help="'panorama' (photo mosaic) or a bundled photo name."),
    focal: float = typer.Option(None, help="Focal length in pixels (default: 830 px at 1920 px width)."),
    hfov: float = typer.Option(None, help="Horizontal field of view in degrees (instead of --focal)."),
    seed: int = typer.Option(0, help="Random seed (layout, shake, noise)."),
) -> None:
    """Render a first-person video of a panorama under a known rotation sequence.

    Writes OUT plus OUT-stem.gt.csv (frame,time,yaw,pitch,roll in degrees) and OUT-stem.gt.tum.
    Example: egovid synth fpv shaky.mp4 --motion running --yaw-amp 10 --pitch-amp 2.5
    """
    from egovid.core.camera.intrinsics import resolve_intrinsics
    from egovid.synth import motions
    from egovid.synth.fpv import ground_truth_paths, render_fpv
    from egovid.synth.photos import ALL

    choice(motion, "--motion", motions.MOTIONS)
    choice(scene, "--scene", ("panorama", *ALL))
    number(yaw_amp, "--yaw-amp", lo=-180, hi=180, unit="degrees")
    number(pitch_amp, "--pitch-amp", lo=-90, hi=90, unit="degrees")
    number(roll_amp, "--roll-amp", lo=-180, hi=180, unit="degrees")
    number(pan_deg, "--pan-deg", lo=-36000, hi=36000, unit="degrees")
    number(jitter_deg, "--jitter-deg", lo=0, hi=45, unit="degrees")
    outputs(
        [],
        (out, VIDEO_OUT, "video"),
        *zip(ground_truth_paths(out), (CSV, TUM), ("ground truth", "TUM file"), strict=True),
    )
    w, h = parse_size(size)
    intr = resolve_intrinsics(w, h, focal, hfov)
    if motion == "running":
        angles = motions.running(frames, yaw_amp, pitch_amp, period, roll_amp)
    elif motion == "pan":
        angles = motions.pan(frames, pan_deg)
        angles[:, 2] += roll_amp * np.sin(2 * np.pi * np.arange(frames) / period)
    elif motion == "random-walk":
        angles = motions.random_walk(frames, seed=seed)
    elif motion == "still":
        angles = np.zeros((frames, 3))
    else:
        raise EgovidError(f"unknown motion {motion!r}", f"choose one of {', '.join(motions.MOTIONS)}")
    if jitter_deg > 0:
        angles = angles + motions.jitter(frames, (jitter_deg, jitter_deg, jitter_deg), seed=seed)
    with progress_bar("rendering", frames) as update:
        res = render_fpv(
            out,
            angles,
            width=w,
            height=h,
            fps=fps,
            intrinsics=intr,
            scene=scene,
            noise_std=noise,
            forward_speed=forward,
            seed=seed,
            progress=lambda k: update(k),
        )
    console.print(f"video        {res.video}")
    console.print(f"ground truth {res.motion_csv}  {res.tum}")


@app.command("drive")
@all_or_nothing
def synth_drive(
    out: Path = typer.Argument(..., help="Output video (.mp4)."),
    route: str = typer.Option("main", help="main (the main road) or side (turn off the main road at 450 m)."),
    start_m: float = typer.Option(20.0, "--from", help="Start, metres along the main road."),
    end_m: float = typer.Option(300.0, "--to", help="End, metres along the main road (or the side street)."),
    cruise: float = typer.Option(11.0, min=1.0, max=40.0, help="Cruising speed in m/s."),
    stop: list[str] = typer.Option([], help="A stop as DISTANCE:SECONDS (metres from the start); repeatable."),
    lane_offset: float = typer.Option(0.0, help="Lateral offset from the lane centre, metres (+ = right)."),
    lane_change: str = typer.Option(None, help="Change to the left lane between A:B metres from the start."),
    light: str = typer.Option("noon", help="morning | noon | afternoon | cloudy | dusk."),
    vehicles: int = typer.Option(4, min=0, max=30, help="Other vehicles per leg (parked and oncoming)."),
    gps: str = typer.Option("gpx", help="GPS format: gpx | nmea | csv."),
    size: str = typer.Option("640x360", help="WIDTHxHEIGHT in pixels."),
    fps: float = typer.Option(30.0, min=5, max=120, help="Frame rate."),
    start: str = typer.Option("2026-05-04T08:00:00Z", help="UTC start time (ISO 8601), stored in the video."),
    seed: int = typer.Option(0, help="Random seed (vehicles, GPS noise, vibration)."),
) -> None:
    """Render a dashcam drive through the synthetic town, with its GPS track and ground truth.

    Writes OUT, OUT-stem.gpx (or .nmea / .gps.csv) and OUT-stem.truth.csv (frame positions).
    Example: egovid synth drive monday.mp4 --light morning --stop 120:3 --seed 1
    """
    from egovid.core.errors import EgovidError
    from egovid.core.times import parse_iso
    from egovid.synth.drive import DriveSpec, Light, render_drive

    choice(gps, "--gps", ("gpx", "nmea", "csv"))
    choice(route, "--route", ("main", "side"))
    light_preset = Light.preset(light)
    number(start_m, "--from", lo=0, hi=10_000, unit="m")
    number(end_m, "--to", lo=0, hi=10_000, unit="m")
    number(lane_offset, "--lane-offset", lo=-5, hi=5, unit="m")
    gps_path = out.parent / (out.stem + {"gpx": ".gpx", "nmea": ".nmea", "csv": ".gps.csv"}[gps])
    outputs(
        [],
        (out, ".mp4 .mkv .mov", "video"),
        (gps_path, "", "GPS track"),
        (out.parent / (out.stem + ".truth.csv"), CSV, "truth"),
    )
    w, h = parse_size(size)
    if route == "main":
        legs = [("main", start_m, end_m)]
    elif route == "side":
        legs = [("main", start_m, 445.0), ("side", 5.0, max(end_m, 50.0))]
    else:
        raise EgovidError(f"unknown route {route!r}", "choose main or side")
    stops = []
    for s in stop:
        try:
            d, wait = (float(x) for x in s.split(":"))
        except ValueError:
            raise EgovidError(f"--stop {s!r} is not DISTANCE:SECONDS", "write e.g. --stop 120:3") from None
        stops.append(
            (
                number(d, "--stop distance", lo=0, hi=10_000, unit="m"),
                number(wait, "--stop wait", lo=0, hi=3600, unit="s"),
            )
        )
    change = None
    if lane_change:
        try:
            a, b = (float(x) for x in lane_change.split(":"))
        except ValueError:
            raise EgovidError(f"--lane-change {lane_change!r} is not A:B", "write e.g. --lane-change 80:120") from None
        change = (
            number(a, "--lane-change start", lo=0, hi=10_000, unit="m"),
            number(b, "--lane-change end", lo=a, hi=10_000, unit="m"),
        )
    try:
        t0 = parse_iso(start)
    except ValueError:
        raise EgovidError(f"--start {start!r} is not ISO 8601", "write e.g. 2026-05-04T08:00:00Z") from None
    spec = DriveSpec(
        legs=legs,
        cruise=cruise,
        stops=stops,
        lane_offset=lane_offset,
        lane_change=change,
        light=light_preset,
        vehicles=vehicles,
        seed=seed,
        start_time=t0,
    )
    with progress_bar("rendering", None) as update:
        video, track, truth = render_drive(
            spec, out, width=w, height=h, fps=fps, gps_format=gps, progress=lambda k, n: update(k, n)
        )
    console.print(f"video {video} ({len(truth.times)} frames)\nGPS   {track}\ntruth {out.with_suffix('.truth.csv')}")
