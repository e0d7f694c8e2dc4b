"""``egovid demo``: run the main jobs end to end on generated data."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from egovid.cli.common import console


def demo(
    out: Path = typer.Option(Path("demo-output"), "--out", help="Folder for the demo's files."),
    quick: bool = typer.Option(False, help="Smaller clips (for CI)."),
) -> None:
    """Run egovid's main jobs on generated data and print where the results are.

    1. renders a shaky first-person clip with known camera motion;
    2. estimates its camera rotation and compares it with the truth;
    3. scores its viewing experience (VE, SVE, 2D-VE).
    """
    import numpy as np

    from egovid.io.files import atomic_write_text
    from egovid.io.trajectory import read_motion_csv, write_motion_csv, write_tum
    from egovid.motion.estimate import estimate_motion
    from egovid.perception.score import score_angles
    from egovid.perception.ve2d import ve2d_video
    from egovid.plots import plot_angles, plot_scores
    from egovid.synth import motions
    from egovid.synth.fpv import render_fpv

    out.mkdir(parents=True, exist_ok=True)
    w, h, n = (640, 360, 90) if quick else (1280, 720, 240)
    console.rule("[bold]1. synthetic shaky first-person clip")
    angles = motions.running(n, 8.0, 2.0, 24.0, 1.5) + motions.jitter(n, (0.15, 0.15, 0.1))
    clip = render_fpv(out / "shaky.mp4", angles, width=w, height=h, noise_std=2.0)
    console.print(f"{clip.video} ({w}x{h}, {n} frames), ground truth {clip.motion_csv.name}")

    console.rule("[bold]2. camera motion (egovid fpv motion)")
    est = estimate_motion(clip.video)
    write_motion_csv(out / "motion.csv", est.trajectory)
    write_tum(out / "motion.tum", est.trajectory)
    gt = read_motion_csv(clip.motion_csv).relative_to_first()
    err = np.sqrt(np.mean((est.trajectory.euler() - gt.euler()) ** 2, axis=0))
    plot_angles(out / "motion.png", est.trajectory.times, {"estimated": est.trajectory.euler(), "truth": gt.euler()})
    fps = len(est.trajectory) / est.seconds["total"]
    console.print(f"{fps:.0f} fps; RMS error yaw/pitch/roll {err[0]:.3f}° {err[1]:.3f}° {err[2]:.3f}°")

    console.rule("[bold]3. viewing experience (egovid fpv score)")
    intr = est.intrinsics
    e = est.trajectory.euler()
    results = {m: score_angles(e, 30.0, intr.hfov_deg, intr.vfov_deg, method=m) for m in ("ve", "sve")}
    results["ve2d"] = ve2d_video(clip.video, intr)
    atomic_write_text(out / "scores.json", json.dumps({m: r.to_dict() for m, r in results.items()}, indent=1))
    plot_scores(out / "scores.png", results, "Viewing experience of the shaky clip")
    console.print(
        f"VE {results['ve'].score:.3f}  SVE {results['sve'].score:.3f}  2D-VE {results['ve2d'].score:.3f} "
        "(1 = every frame can be followed by smooth pursuit)"
    )

    console.rule("[bold]results")
    console.print(f"All outputs are in {out.resolve()}:")
    for p in sorted(out.iterdir()):
        console.print(f"  {p.name}")
