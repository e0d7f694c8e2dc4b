"""``egovid synth``: synthetic test videos with ground truth."""

from __future__ import annotations

from pathlib import Path

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
    from egovid.synth.fpv import ALL, MOTIONS, MotionSpec, ground_truth_paths, synth_fpv

    choice(motion, "--motion", MOTIONS)
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
    spec = MotionSpec(motion, frames, yaw_amp, pitch_amp, period, roll_amp, pan_deg, jitter_deg, seed)
    with progress_bar("rendering", frames) as update:
        res = synth_fpv(
            out, spec, width=w, height=h, fps=fps, focal=focal, hfov=hfov, scene=scene, noise_std=noise,
            forward_speed=forward, seed=seed, progress=lambda k: update(k),
        )  # fmt: skip
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
    from egovid.core.times import parse_iso
    from egovid.synth.drive import DriveSpec, Light, drive_files, render_drive, route_legs

    choice(gps, "--gps", ("gpx", "nmea", "csv"))
    choice(route, "--route", ("main", "side"))
    light_preset = Light.preset(light)
    number(start_m, "--from", lo=0, hi=10_000, unit="m")
    number(end_m, "--to", lo=0, hi=10_000, unit="m")
    number(lane_offset, "--lane-offset", lo=-5, hi=5, unit="m")
    gps_path, truth_path = drive_files(out, gps)
    outputs(
        [],
        (out, ".mp4 .mkv .mov", "video"),
        (gps_path, "", "GPS track"),
        (truth_path, CSV, "truth"),
    )
    w, h = parse_size(size)
    legs = route_legs(route, start_m, end_m)
    stops = _stops(stop)
    change = _lane_change(lane_change) if lane_change else None
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
    console.print(f"video {video} ({len(truth.times)} frames)\nGPS   {track}\ntruth {truth_path}")


def _stops(texts: list[str]) -> list[tuple[float, float]]:
    """``--stop DISTANCE:SECONDS`` options as (metres from the start, seconds of wait)."""
    stops = []
    for s in texts:
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
    return stops


def _lane_change(text: str) -> tuple[float, float]:
    """``--lane-change A:B`` as (start, end) metres from the start of the drive."""
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise EgovidError(f"--lane-change {text!r} is not A:B", "write e.g. --lane-change 80:120") from None
    return (
        number(a, "--lane-change start", lo=0, hi=10_000, unit="m"),
        number(b, "--lane-change end", lo=a, hi=10_000, unit="m"),
    )
