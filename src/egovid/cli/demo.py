"""``egovid demo``: run the main jobs end to end on generated data."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from egovid.cli.common import console


def demo(
    out: Path = typer.Option(Path("demo-output"), "--out", help="Folder for the demo's files."),
    quick: bool = typer.Option(False, help="Smaller, shorter clips (about a minute in all)."),
) -> None:
    """Run egovid's three systems on generated data and print where the results are.

    fpv: renders a shaky first-person clip with known motion, estimates its rotation, scores its
    viewing experience and stabilises it (with an HTML report). dashcam: renders two drives along
    the same road, archives them (the second compressed against the first) and extracts the
    second back. voeval: evaluates three visual odometers on the controlled test scenes.
    """
    from egovid.cli.validate import output_folder

    output_folder(out, what="demo folder")
    out.mkdir(parents=True, exist_ok=True)
    _fpv(out / "fpv", quick)

    console.rule("[bold]dashcam: two drives, one archive (egovid dashcam)")
    _dashcam(out / "dashcam", quick)

    console.rule("[bold]voeval: which visual odometer for which job (egovid voeval)")
    from egovid.voeval.report import write_report as voeval_report
    from egovid.voeval.runner import GridConfig, run_grid

    cfg = GridConfig(
        vos=["egovid", "ecc", "monovo"],
        frames=24 if quick else 36,
        width=160 if quick else 240,
        height=120 if quick else 180,
        levels=["lossless", "crf30", "crf48"],
    )
    r = run_grid(out / "voeval", cfg)
    html_path, _ = voeval_report(out / "voeval")
    console.print(f"{r['cells']} cells in {r['seconds']:.0f} s; report {html_path}")

    console.rule("[bold]results")
    console.print(f"All outputs are in {out.resolve()}:")
    for p in sorted(out.rglob("*")):
        if (
            p.is_file()
            and p.suffix in (".mp4", ".mkv", ".html", ".png", ".json", ".csv")
            and "results" not in p.parts
            and "blobs" not in p.parts
            and "scenes" not in p.parts
            and "videos" not in p.parts
        ):
            console.print(f"  {p.relative_to(out)}")


def _fpv(folder: Path, quick: bool) -> None:
    """The fpv jobs on a generated shaky clip: synth fpv, fpv motion (against the ground truth),
    fpv score and fpv stabilize, each through the function its command calls."""
    import numpy as np

    from egovid.core.plots import plot_angles
    from egovid.core.trajectory import read_motion_csv
    from egovid.fpv.motion import save_motion
    from egovid.fpv.score import score_video
    from egovid.fpv.stabilize.run import stabilize_video
    from egovid.synth.fpv import MotionSpec, synth_fpv

    folder.mkdir(exist_ok=True)
    w, h, n = (640, 360, 120) if quick else (1280, 720, 240)
    console.rule("[bold]fpv 1/4: synthetic shaky first-person clip (egovid synth fpv)")
    spec = MotionSpec("running", n, 8.0, 2.0, 24.0, 1.5, jitter_deg=(0.15, 0.15, 0.1))
    clip = synth_fpv(folder / "shaky.mp4", spec, width=w, height=h, noise_std=2.0)
    console.print(f"{clip.video} ({w}x{h}, {n} frames), ground truth {clip.motion_csv.name}")

    console.rule("[bold]fpv 2/4: camera motion (egovid fpv motion)")
    cm = save_motion(clip.video, folder / "motion.csv")
    est = cm.trajectory
    gt = read_motion_csv(clip.motion_csv).relative_to_first()
    err = np.sqrt(np.mean((est.euler() - gt.euler()) ** 2, axis=0))
    plot_angles(folder / "motion.png", est.times, {"estimated": est.euler(), "truth": gt.euler()})
    fps = len(est) / cm.seconds["total"]
    console.print(f"{fps:.0f} fps; RMS error yaw/pitch/roll {err[0]:.3f}° {err[1]:.3f}° {err[2]:.3f}°")

    console.rule("[bold]fpv 3/4: viewing experience (egovid fpv score)")
    scores = score_video(clip.video, estimated=cm, json_out=folder / "scores.json", plot=folder / "scores.png")
    r = scores.results
    console.print(
        f"VE {r['ve'].score:.3f}  SVE {r['sve'].score:.3f}  2D-VE {r['ve2d'].score:.3f}"
        " (1 = every frame can be followed by smooth pursuit)"
    )

    console.rule("[bold]fpv 4/4: FPMI-preserving stabilisation (egovid fpv stabilize)")
    res = stabilize_video(clip.video, folder / "stabilized.mp4", motion=est, report=folder / "stabilize-report.html")
    s = res.summary()
    mb, ma = s["measured"]["before"], s["measured"]["after"]
    console.print(
        f"measured on the output: VE {mb['ve']:.3f} → {ma['ve']:.3f}, ITF {mb['itf_db']:.1f} → "
        f"{ma['itf_db']:.1f} dB, first-person motion kept {100 * s['fpmi_retention_measured']:.0f} %, "
        f"zoom {s['zoom']['mean']:.3f}"
    )


def _dashcam(folder: Path, quick: bool) -> None:
    import shutil

    from egovid.dashcam.archive.store import Archive
    from egovid.dashcam.extract import extract_video
    from egovid.dashcam.ingest import IngestOptions, ingest_videos
    from egovid.dashcam.report import archive_report
    from egovid.synth.drive import DriveSpec, Light, render_drive

    folder.mkdir(parents=True, exist_ok=True)
    w, h = (320, 180) if quick else (640, 360)
    leg = [("main", 20.0, 90.0 if quick else 160.0)]
    noon = Light.preset("noon")
    monday = render_drive(
        DriveSpec(legs=leg, cruise=10.0, seed=1, light=noon), folder / "monday.mp4", width=w, height=h
    )
    tuesday = render_drive(
        DriveSpec(legs=leg, cruise=8.5, stops=[(40.0, 2.0)], seed=2, light=noon),
        folder / "tuesday.mp4",
        width=w,
        height=h,
        gps_format="nmea",
    )
    shutil.rmtree(folder / "archive", ignore_errors=True)
    ar = Archive.create(folder / "archive")
    for video, gps, _ in (monday, tuesday):
        (rep,) = ingest_videos(ar, [video], gps=gps, options=IngestOptions(measure_savings=True)).reports
        for p in rep.pieces:
            joint = p.ref_drive and p.saving is not None
            saving = f", {100 * p.saving:.1f} % smaller than standalone AV1" if joint else ""
            console.print(
                f"{rep.name}: {p.mode}{' against ' + p.ref_drive if p.ref_drive else ''}, "
                f"{p.bytes / 1024:.0f} KiB{saving}"
            )
    extract_video(ar, ar.drive_or_fail("tuesday"), folder / "tuesday-extracted.mkv")
    (folder / "report.json").write_text(json.dumps(archive_report(ar), indent=1, default=str))
    console.print(f"archive {folder / 'archive'}; tuesday extracted bit-exactly to {folder / 'tuesday-extracted.mkv'}")
