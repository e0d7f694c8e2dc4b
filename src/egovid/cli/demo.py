"""``egovid demo``: run the main jobs end to end on generated data."""

from __future__ import annotations

from pathlib import Path

import typer

from egovid.cli.common import console


def demo(
    out: Path = typer.Option(Path("demo-output"), "--out", help="Folder for the demo's files."),
    quick: bool = typer.Option(False, help="Smaller clips (for CI)."),
) -> None:
    """Generate a shaky first-person clip and estimate its camera motion; print where results are."""
    import numpy as np

    from egovid.io.trajectory import read_motion_csv, write_motion_csv, write_tum
    from egovid.motion.estimate import estimate_motion
    from egovid.plots import plot_angles
    from egovid.synth import motions
    from egovid.synth.fpv import render_fpv

    out.mkdir(parents=True, exist_ok=True)
    w, h, n = (640, 360, 90) if quick else (1280, 720, 240)
    console.rule("[bold]1. synthetic shaky first-person clip")
    angles = motions.running(n, 8.0, 2.0, 24.0, 1.5) + motions.jitter(n, (0.15, 0.15, 0.1))
    clip = render_fpv(out / "shaky.mp4", angles, width=w, height=h, noise_std=2.0)
    console.print(f"video {clip.video}, ground truth {clip.motion_csv}")
    console.rule("[bold]2. camera motion")
    est = estimate_motion(clip.video)
    write_motion_csv(out / "motion.csv", est.trajectory)
    write_tum(out / "motion.tum", est.trajectory)
    gt = read_motion_csv(clip.motion_csv).relative_to_first()
    err = np.sqrt(np.mean((est.trajectory.euler() - gt.euler()) ** 2, axis=0))
    plot_angles(out / "motion.png", est.trajectory.times, {"estimated": est.trajectory.euler(), "truth": gt.euler()})
    console.print(f"RMS error yaw/pitch/roll: {err[0]:.3f}° {err[1]:.3f}° {err[2]:.3f}°")
    console.rule("[bold]results")
    console.print(f"All outputs are in {out.resolve()}")
