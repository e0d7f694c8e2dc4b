"""``egovid synth``: synthetic test videos with ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from egovid.cli.common import check_output, console, parse_size, progress_bar
from egovid.errors import EgovidError

app = typer.Typer(help="Make synthetic test videos with known ground truth.", no_args_is_help=True)


@app.command("fpv")
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
    from egovid.io.camera import resolve_intrinsics
    from egovid.synth import motions
    from egovid.synth.fpv import render_fpv

    check_output(out)
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
