"""``egovid fpv``: first-person video motion, scores and stabilisation."""

from __future__ import annotations

from pathlib import Path

import typer

from egovid.cli.common import (
    ALLOW_TRUNCATED,
    all_or_nothing,
    console,
    parse_ints,
    parse_size,
    progress_bar,
    staged_progress,
)
from egovid.cli.validate import CSV, HTML, JSON, PLOT, TUM, VIDEO_OUT, choice, input_file, number, outputs, video_input

app = typer.Typer(
    help="First-person video: camera motion, viewing-experience scores, FPMI-preserving stabilisation.",
    no_args_is_help=True,
)

FOCAL_HELP = "Focal length in pixels of the video (default: 830 px at 1920 px width, GoPro-like)."
HFOV_HELP = "Horizontal field of view in degrees (alternative to --focal)."


@app.command("motion")
@all_or_nothing
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
    allow_truncated: bool = ALLOW_TRUNCATED,
) -> None:
    """Estimate the camera rotation of every frame (thesis ch. 6).

    Features + RANSAC rotations between frames 1 and 5 apart, refined by a robust pose graph on
    SO(3); angles are the thesis' yaw-pitch-roll decomposition, relative to the first frame.
    """
    from egovid.io.camera import resolve_intrinsics
    from egovid.io.trajectory import write_motion_csv, write_tum
    from egovid.motion.estimate import MotionOptions, estimate_motion

    info = video_input(video, allow_truncated=allow_truncated)
    tum = tum or out.parent / (out.stem + ".tum")
    outputs([video], (out, CSV, "motion CSV"), (tum, TUM, "TUM file"), (plot, PLOT, "plot"))
    choice(features, "--features", ("orb", "sift"))
    intr = resolve_intrinsics(info.width, info.height, focal, hfov)
    opts = MotionOptions(lags=parse_ints(lags, "--lags"), features=features, work_width=work_width)
    with progress_bar("motion", info.frame_count) as update:
        est = estimate_motion(video, intr, opts, progress=update)
    write_motion_csv(out, est.trajectory)
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


@app.command("score")
@all_or_nothing
def score(
    video: Path = typer.Argument(None, help="Input video (omit when --motion is given)."),
    motion: Path = typer.Option(None, "--motion", help="Score this motion CSV (frame,time,yaw,pitch,roll) instead."),
    method: str = typer.Option("all", help="ve | sve | ve2d | all (ve2d needs the video)."),
    json_out: Path = typer.Option(None, "--json", help="Write scores and per-window curves as JSON."),
    plot: Path = typer.Option(None, help="Write a PNG of the per-window curves."),
    focal: float = typer.Option(None, help=FOCAL_HELP),
    hfov: float = typer.Option(None, help=HFOV_HELP),
    size: str = typer.Option(None, help="WIDTHxHEIGHT of the video a --motion CSV came from (default 1920x1080)."),
    fps: float = typer.Option(None, help="Frame rate of a --motion CSV (default: from its time column)."),
    d_over_f: float = typer.Option(4.0, help="Viewing distance over focal length (thesis: 4)."),
    bias: float = typer.Option(None, help="Bias b in degrees (default 0.0183 for VE/SVE, 0.038 for 2D-VE)."),
    mar: float = typer.Option(0.02, help="Minimum angular resolution of the eye, degrees."),
    sve_variant: str = typer.Option(
        "coverage", help="SVE loss term: coverage (default) | thesis (eq. 8.11 literally)."
    ),
    save_motion: Path = typer.Option(None, help="When scoring a video, also save its estimated motion CSV here."),
    allow_truncated: bool = ALLOW_TRUNCATED,
) -> None:
    """Score how watchable a first-person video is (thesis ch. 7–8).

    VE is the expected fraction of frames a viewer can follow a target by smooth pursuit
    (1 = perfectly watchable); SVE is its fast structural approximation; 2D-VE uses optical flow
    instead of the 3D camera motion. Scores are per window of 10 frames (VE/SVE) or 30 frames
    (2D-VE); the overall score is the RMS of the per-window minimum over yaw, pitch and roll.
    """
    import json

    import numpy as np

    from egovid.errors import EgovidError
    from egovid.io.camera import resolve_intrinsics
    from egovid.io.files import atomic_write_text
    from egovid.io.trajectory import read_motion_csv, write_motion_csv
    from egovid.perception.model import ViewingModel
    from egovid.perception.score import score_angles

    methods = ("ve", "sve", "ve2d") if method == "all" else (method,)
    for m in methods:
        if m not in ("ve", "sve", "ve2d"):
            raise EgovidError(f"unknown method {m!r}", "choose ve, sve, ve2d or all")
    if (video is None) == (motion is None):
        raise EgovidError("give either a VIDEO or --motion CSV", "e.g. `egovid fpv score clip.mp4`")
    choice(sve_variant, "--sve-variant", ("coverage", "thesis"))
    number(fps, "--fps", lo=0, lo_open=True, hi=1000)
    number(d_over_f, "--d-over-f", lo=0, lo_open=True, hi=1000)
    number(mar, "--mar", lo=0, lo_open=True, hi=10, unit="degrees")
    number(bias, "--bias", lo=0, hi=10, unit="degrees")
    input_file(motion, "motion CSV")
    info = video_input(video, allow_truncated=allow_truncated) if video is not None else None
    outputs(
        [video, motion],
        (json_out, JSON, "JSON"),
        (plot, PLOT, "plot"),
        (save_motion if video else None, CSV, "motion CSV"),
    )
    if motion is not None and "ve2d" in methods:
        if method != "all":
            raise EgovidError("2D-VE needs the video, not a motion CSV", "pass the VIDEO instead of --motion")
        methods = ("ve", "sve")
    results: dict = {}
    traj = None
    if video is not None:
        intr = resolve_intrinsics(info.width, info.height, focal, hfov)
        rate = info.fps
    else:
        w, h = parse_size(size) if size else (1920, 1080)
        intr = resolve_intrinsics(w, h, focal, hfov)
        traj = read_motion_csv(motion)
        if fps is None:
            dt = np.diff(traj.times)
            if len(dt) == 0 or not np.all(dt > 0):
                raise EgovidError(f"{motion} has no increasing time column", "pass --fps")
            fps = float(1.0 / np.median(dt))
        rate = fps
    model3d = ViewingModel(d_over_f=d_over_f, mar_deg=mar, bias_deg=0.0183 if bias is None else bias)
    model2d = ViewingModel.model_2d().with_(
        d_over_f=d_over_f, mar_deg=mar, **({} if bias is None else {"bias_deg": bias})
    )
    if traj is None and any(m in ("ve", "sve") for m in methods):
        from egovid.motion.estimate import estimate_motion

        with progress_bar("motion", info.frame_count) as update:
            traj = estimate_motion(video, intr, progress=update).trajectory
        if save_motion is not None:
            write_motion_csv(save_motion, traj)
    for m in methods:
        if m == "ve2d":
            from egovid.perception.ve2d import ve2d_video

            with progress_bar("2D-VE", info.frame_count) as update:
                results[m] = ve2d_video(video, intr, model2d, progress=update)
        else:
            results[m] = score_angles(
                traj.euler(), rate, intr.hfov_deg, intr.vfov_deg, model=model3d, method=m, sve_variant=sve_variant
            )
    from rich.table import Table

    table = Table(title=f"Viewing experience of {(video or motion).name}")
    table.add_column("method")
    for col in ("overall", "yaw", "pitch", "roll"):
        table.add_column(col, justify="right")
    for m, r in results.items():
        if m == "ve2d":
            table.add_row("2D-VE", f"{r.score:.3f}", "", "", "")
        else:
            table.add_row(m.upper(), f"{r.score:.3f}", *(f"{r.axis_scores[a]:.3f}" for a in ("yaw", "pitch", "roll")))
    console.print(table)
    console.print("1 = a viewer can pursue targets in every frame; 0 = never.")
    if json_out is not None:
        doc = {
            "input": str(video or motion),
            "intrinsics": {
                "width": intr.width,
                "height": intr.height,
                "focal_px": intr.focal,
                "hfov_deg": intr.hfov_deg,
                "vfov_deg": intr.vfov_deg,
            },
            "results": {m: r.to_dict() for m, r in results.items()},
        }
        atomic_write_text(json_out, json.dumps(doc, indent=1))
        console.print(f"JSON  {json_out}")
    if plot is not None:
        from egovid.plots import plot_scores

        plot_scores(plot, results, f"Viewing experience of {(video or motion).name}")
        console.print(f"plot  {plot}")


@app.command("stabilize")
@all_or_nothing
def stabilize_cmd(
    src: Path = typer.Argument(..., help="Input video."),
    out: Path = typer.Option(..., "-o", "--out", help="Output video (MP4/H.264; audio and timing kept)."),
    strength: float = typer.Option(1.0, help="0 = untouched … 1 = the optimum of eq. 9.4 (default)."),
    borders: str = typer.Option("crop", help="crop (fixed zoom, no borders) | black | fill (temporal mosaic)."),
    keep_roll: bool = typer.Option(False, "--keep-roll", help="Keep intentional roll instead of levelling it."),
    method: str = typer.Option("ve", help="Stability measure of the objective: ve | sve."),
    report: Path = typer.Option(None, help="Write an HTML report (plots, VE, FPMI, ITF) here."),
    json_out: Path = typer.Option(None, "--json", help="Write the measurements as JSON."),
    motion: Path = typer.Option(None, "--motion", help="Reuse a motion CSV from `egovid fpv motion` for this video."),
    save_motion: Path = typer.Option(None, help="Save the estimated (input) and planned (output) motion CSVs: PREFIX."),
    focal: float = typer.Option(None, help=FOCAL_HELP),
    hfov: float = typer.Option(None, help=HFOV_HELP),
    anchor_threshold: float = typer.Option(
        0.5, min=0.01, max=20.0, help="Degrees a motion must turn back to count as an intentional extreme."
    ),
    crf: int = typer.Option(18, min=0, max=51, help="H.264 quality of the output (lower = better)."),
    allow_truncated: bool = ALLOW_TRUNCATED,
) -> None:
    """Stabilise a first-person video but keep its intentional motion (thesis ch. 9).

    Looking around and the head bob of running stay; shake, jitter and roll go. The camera path
    is rebuilt from its motion anchors (local extremes), whose amplitudes are reduced just until
    the video becomes comfortable to watch while the first-person feeling remains (maximising VE
    of the new motion minus VE of its zigzag), then eased between anchors.
    """
    import json

    from egovid.errors import EgovidError
    from egovid.io.camera import resolve_intrinsics
    from egovid.io.files import atomic_write_text
    from egovid.io.trajectory import Trajectory, read_motion_csv, write_motion_csv
    from egovid.stabilize.optimize import OptimizeOptions
    from egovid.stabilize.pipeline import stabilize
    from egovid.stabilize.render import BORDERS

    if borders not in BORDERS:
        raise EgovidError(f"unknown border mode {borders!r}", f"choose one of {', '.join(BORDERS)}")
    if method not in ("ve", "sve"):
        raise EgovidError(f"unknown method {method!r}", "choose ve or sve")
    if not (0.0 <= strength <= 1.0):
        raise EgovidError(f"strength {strength} is outside [0, 1]", "use e.g. --strength 0.7")
    info = video_input(src, allow_truncated=allow_truncated)
    input_file(motion, "motion CSV")
    pre = (save_motion.parent / (save_motion.name + s) for s in (".input.csv", ".output.csv")) if save_motion else ()
    outputs(
        [src, motion],
        (out, VIDEO_OUT, "output video"),
        (report, HTML, "report"),
        (json_out, JSON, "JSON"),
        *((p, CSV, "motion CSV") for p in pre),
    )
    intr = resolve_intrinsics(info.width, info.height, focal, hfov)
    traj = read_motion_csv(motion) if motion is not None else None
    if traj is not None and len(traj) != info.frame_count:
        from egovid.io.video import count_frames

        n = count_frames(src)
        if len(traj) != n:
            raise EgovidError(
                f"motion {motion} has {len(traj)} frames but {src} has {n}", "estimate the motion of this video again"
            )
    with staged_progress() as cb:
        res = stabilize(
            src,
            out,
            intrinsics=intr,
            motion=traj,
            strength=strength,
            borders=borders,
            keep_roll=keep_roll,
            method=method,
            opts=OptimizeOptions(anchor_threshold=anchor_threshold, method=method),
            crf=crf,
            progress=cb,
        )
    s = res.summary()
    console.print(
        f"VE {s['ve_before']:.3f} → {s['ve_after']:.3f}   masked ITF {s['itf_before_db']:.2f} → "
        f"{s['itf_after_db']:.2f} dB   first-person motion kept {100 * s['fpmi_retention']:.1f} %   "
        f"crop {s['crop_factor']:.3f}   black {100 * s['black_share']:.2f} %   {s['fps_end_to_end']:.1f} fps"
    )
    console.print(f"video   {out}")
    if save_motion is not None:
        write_motion_csv(
            save_motion.with_name(save_motion.name + ".input.csv"), Trajectory.from_euler(res.times, res.original)
        )
        write_motion_csv(
            save_motion.with_name(save_motion.name + ".output.csv"), Trajectory.from_euler(res.times, res.edited)
        )
    if json_out is not None:
        atomic_write_text(json_out, json.dumps(s, indent=1, default=float))
        console.print(f"JSON    {json_out}")
    if report is not None:
        from egovid.stabilize.report import write_report

        write_report(report, res, str(src), intr.hfov_deg, intr.vfov_deg, info.fps)
        console.print(f"report  {report}")
