"""``egovid fpv``: first-person video motion, scores and stabilisation."""

from __future__ import annotations

from pathlib import Path

import typer

from egovid.cli.common import check_output, console, parse_ints, progress_bar

app = typer.Typer(
    help="First-person video: camera motion, viewing-experience scores, FPMI-preserving stabilisation.",
    no_args_is_help=True,
)

FOCAL_HELP = "Focal length in pixels of the video (default: 830 px at 1920 px width, GoPro-like)."
HFOV_HELP = "Horizontal field of view in degrees (alternative to --focal)."


@app.command("motion")
def motion(
    video: Path = typer.Argument(..., help="Input video."),
    out: Path = typer.Option(..., "-o", "--out", help="Output CSV: frame,time,yaw,pitch,roll (degrees)."),
    tum: Path = typer.Option(None, help="Also write a TUM trajectory here (default: next to the CSV)."),
    plot: Path = typer.Option(None, help="Also write a PNG plot of yaw/pitch/roll."),
    focal: float = typer.Option(None, help=FOCAL_HELP),
    hfov: float = typer.Option(None, help=HFOV_HELP),
    lags: str = typer.Option("1,5", help="Frame distances of pose-graph edges (thesis: 1 and 5)."),
    features: str = typer.Option("orb", help="orb | sift."),
    work_width: int = typer.Option(640, min=160, max=3840, help="Width of the downscaled copy used for features."),
) -> None:
    """Estimate the camera rotation of every frame (thesis ch. 6).

    Features + RANSAC rotations between frames 1 and 5 apart, refined by a robust pose graph on
    SO(3); angles are the thesis' yaw-pitch-roll decomposition, relative to the first frame.
    """
    from egovid.io.camera import resolve_intrinsics
    from egovid.io.trajectory import write_motion_csv, write_tum
    from egovid.io.video import probe
    from egovid.motion.estimate import MotionOptions, estimate_motion

    check_output(out)
    info = probe(video)
    intr = resolve_intrinsics(info.width, info.height, focal, hfov)
    opts = MotionOptions(lags=parse_ints(lags, "--lags"), features=features, work_width=work_width)
    with progress_bar("motion", info.frame_count) as update:
        est = estimate_motion(video, intr, opts, progress=update)
    write_motion_csv(out, est.trajectory)
    tum = tum or out.with_suffix(".tum")
    write_tum(tum, est.trajectory)
    n = len(est.trajectory)
    console.print(
        f"{n} frames in {est.seconds['total']:.1f} s ({n / est.seconds['total']:.1f} fps), "
        f"{est.failed_pairs} of {len(est.pairs)} frame pairs unmatched"
    )
    console.print(f"motion CSV   {out}")
    console.print(f"TUM          {tum}")
    if plot is not None:
        from egovid.plots import plot_angles

        title = f"Camera rotation of {video.name}"
        plot_angles(plot, est.trajectory.times, {"estimated": est.trajectory.euler()}, title)
        console.print(f"plot         {plot}")
