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

FOCAL_HELP = (
    "Focal length in pixels (default: from the file: gyro fit, GoPro lens mode or 35 mm-equivalent "
    "focal length; else 830 px at 1920 px, GoPro-like)."
)
HFOV_HELP = "Field of view in degrees across the picture's long side (alternative to --focal)."
SOURCE_HELP = (
    "Where the camera motion comes from: auto (the camera's gyro when it has one and did not stabilise "
    "the picture itself; else its recorded image orientation, else vision) | vision (the pictures) | "
    "gyro | fused (gyro and vision in one pose graph)."
)


def source_option():
    """The ``--source`` option shared by ``fpv motion``, ``fpv score`` and ``fpv stabilize``."""
    return typer.Option("auto", "--source", help=SOURCE_HELP)


def check_source(source: str) -> None:
    """Refuse an unknown ``--source`` before any work."""
    from egovid.core.motion.source import REQUESTS

    choice(source, "--source", REQUESTS)


@app.command("motion")
@all_or_nothing
def motion(
    video: Path = typer.Argument(..., help="Input video."),
    out: Path = typer.Option(
        ..., "-o", "--out", help="Output CSV: frame,time,yaw,pitch,roll (degrees),confidence (1 measured, 0 guessed)."
    ),
    source: str = source_option(),
    json_out: Path = typer.Option(
        None,
        "--json",
        help="Summary JSON: source and why, intrinsics and their source, gyro sync (default: next to the CSV).",
    ),
    tum: Path = typer.Option(None, help="Also write a TUM trajectory here (default: next to the CSV)."),
    plot: Path = typer.Option(None, help="Also write a PNG plot of yaw/pitch/roll."),
    focal: float = typer.Option(None, help=FOCAL_HELP),
    hfov: float = typer.Option(None, help=HFOV_HELP),
    lags: str = typer.Option(
        "1,2,5",
        help="Frame distances of the vision pose-graph edges: 1 always, the longer ones take turns "
        "on every other frame (the thesis uses 1,5 on every frame; see docs/fpv.md).",
    ),
    features: str = typer.Option("orb", help="orb | sift."),
    work_width: int = typer.Option(640, min=160, max=3840, help="Width of the downscaled copy used for features."),
    allow_truncated: bool = ALLOW_TRUNCATED,
) -> None:
    """Estimate the camera rotation of every frame.

    Vision: features + RANSAC rotations between frames 1 apart and, on every other frame taking
    turns, 2 or 5 apart, refined by a pose graph on SO(3) (thesis ch. 6); above 1 Hz the
    frame-to-frame detail comes from the 1-apart pairs alone (the longer pairs only stop slow
    drift). With a gyro in the file (GoPro, Sony, Insta360, DJI) it is synced to the video and,
    by default, used instead; the JSON says which source was used and why.
    Angles are yaw-pitch-roll relative to the first frame (README: conventions).
    """
    import json

    from egovid.core.files import atomic_write_text
    from egovid.core.motion.estimate import MotionOptions
    from egovid.core.motion.source import camera_motion
    from egovid.core.trajectory import write_motion_csv, write_tum

    video_input(video, allow_truncated=allow_truncated)
    json_out = json_out or out.parent / (out.stem + ".json")
    tum = tum or out.parent / (out.stem + ".tum")
    outputs(
        [video],
        (out, CSV, "motion CSV"),
        (json_out, JSON, "summary JSON"),
        (tum, TUM, "TUM file"),
        (plot, PLOT, "plot"),
    )
    choice(features, "--features", ("orb", "sift"))
    check_source(source)
    opts = MotionOptions(lags=parse_ints(lags, "--lags"), features=features, work_width=work_width)
    with staged_progress() as cb:
        cm = camera_motion(video, source, focal=focal, hfov=hfov, options=opts, progress=cb)
    write_motion_csv(out, cm.trajectory, cm.confidence)
    write_tum(tum, cm.trajectory)
    doc = {"input": str(video), **cm.to_dict()}
    atomic_write_text(json_out, json.dumps(doc, indent=1))
    n = len(cm.trajectory)
    cam = cm.camera.intrinsics
    console.print(f"source       {cm.source} ({cm.reason})")
    console.print(
        f"intrinsics   focal {cam.focal:.1f} px, {cam.hfov_deg:.1f}° x {cam.vfov_deg:.1f}° "
        f"({cm.camera.source}: {cm.camera.detail})"
    )
    if cm.sync is not None:
        s = cm.sync
        console.print(f"gyro sync    offset {1000 * s.offset_s:+.1f} ms, r = {s.r_vector:.3f} over {s.frames} frames")
    if cm.comparison is not None:
        c = cm.comparison
        console.print(
            f"vision/gyro  r = {c.r:.3f}, magnitude ratio {c.ratio:.3f}, {c.rms_deg:.3f}°/frame RMS difference"
        )
    bridged = int((cm.confidence < 1.0).sum())
    console.print(f"{n} frames in {cm.seconds['total']:.1f} s, {bridged} bridged (confidence < 1)")
    console.print(f"motion CSV   {out}")
    console.print(f"TUM          {tum}")
    console.print(f"JSON         {json_out}")
    if plot is not None:
        from egovid.core.motion import gyro as gyro_mod
        from egovid.core.plots import plot_angles
        from egovid.core.trajectory import Trajectory

        curves = {cm.source: cm.trajectory.euler()}
        if cm.vision is not None and cm.source != "vision":
            curves["vision"] = cm.vision.trajectory.euler()
        if cm.sync is not None and cm.vision is not None and cm.source != "gyro" and cm.telemetry.has_gyro:
            R = gyro_mod.frame_rotations(
                gyro_mod.integrate(cm.telemetry.imu, bias=cm.sync.bias), cm.sync, cm.trajectory.times
            )
            curves["gyro"] = Trajectory(cm.trajectory.times, R).euler()
        plot_angles(plot, cm.trajectory.times, curves, f"Camera rotation of {video.name}")
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
    source: str = source_option(),
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

    from egovid.core.camera.intrinsics import resolve_intrinsics
    from egovid.core.errors import EgovidError
    from egovid.core.files import atomic_write_text
    from egovid.core.trajectory import read_motion_csv, write_motion_csv
    from egovid.fpv.perception.model import ViewingModel
    from egovid.fpv.perception.score import score_angles

    methods = ("ve", "sve", "ve2d") if method == "all" else (method,)
    for m in methods:
        if m not in ("ve", "sve", "ve2d"):
            raise EgovidError(f"unknown method {m!r}", "choose ve, sve, ve2d or all")
    if (video is None) == (motion is None):
        raise EgovidError("give either a VIDEO or --motion CSV", "e.g. `egovid fpv score clip.mp4`")
    choice(sve_variant, "--sve-variant", ("coverage", "thesis"))
    check_source(source)
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
    camera = None
    if video is not None:
        from egovid.core.camera.resolve import resolve_camera

        camera = resolve_camera(video, focal, hfov)
        intr = camera.intrinsics
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
        from egovid.cli.common import staged_progress
        from egovid.core.motion.source import camera_motion

        with staged_progress() as cb:
            cm = camera_motion(video, source, focal=focal, hfov=hfov, progress=cb)
        traj, camera, intr = cm.trajectory, cm.camera, cm.camera.intrinsics
        console.print(f"motion from {cm.source} ({cm.reason}); intrinsics: {camera.source}")
        if save_motion is not None:
            write_motion_csv(save_motion, traj, cm.confidence)
    for m in methods:
        if m == "ve2d":
            from egovid.fpv.perception.ve2d import ve2d_video

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
                "source": camera.source if camera is not None else ("flag" if focal or hfov else "default"),
            },
            "results": {m: r.to_dict() for m, r in results.items()},
        }
        atomic_write_text(json_out, json.dumps(doc, indent=1))
        console.print(f"JSON  {json_out}")
    if plot is not None:
        from egovid.core.plots import plot_scores

        plot_scores(plot, results, f"Viewing experience of {(video or motion).name}")
        console.print(f"plot  {plot}")


@app.command("stabilize")
@all_or_nothing
def stabilize_cmd(
    src: Path = typer.Argument(..., help="Input video."),
    out: Path = typer.Option(
        ..., "-o", "--out", help="Output video (MP4/H.264; audio, telemetry, timing and colour kept)."
    ),
    strength: float = typer.Option(1.0, help="0 = untouched … 1 = the optimum of eq. 9.4 (default)."),
    borders: str = typer.Option(
        "crop", help="crop (a zoom that follows the need, no borders) | black | fill (temporal mosaic)."
    ),
    max_zoom: float = typer.Option(
        1.10, "--max-zoom", help="Largest zoom the crop may use (1.10 = 10 %); the path bends to fit it."
    ),
    keep_roll: bool = typer.Option(False, "--keep-roll", help="Keep intentional roll instead of levelling it."),
    method: str = typer.Option("ve", help="Stability measure of the objective: ve | sve."),
    measure: bool = typer.Option(
        True, "--measure/--no-measure", help="Decode the output and measure it (VE, SVE, FPMI, 2D-VE, ITF, jitter)."
    ),
    report: Path = typer.Option(None, help="Write an HTML report (planned vs measured, plots, thumbnails) here."),
    json_out: Path = typer.Option(None, "--json", help="Write the measurements as JSON (deterministic: no timings)."),
    motion: Path = typer.Option(None, "--motion", help="Reuse a motion CSV from `egovid fpv motion` for this video."),
    save_motion: Path = typer.Option(
        None, help="Save the estimated (input) and rendered (output) motion CSVs: PREFIX."
    ),
    focal: float = typer.Option(None, help=FOCAL_HELP),
    hfov: float = typer.Option(None, help=HFOV_HELP),
    anchor_threshold: float = typer.Option(
        0.5, min=0.01, max=20.0, help="Degrees a motion must turn back to count as an intentional extreme."
    ),
    crf: int = typer.Option(18, min=0, max=51, help="H.264 quality of the output (lower = better)."),
    source: str = source_option(),
    allow_truncated: bool = ALLOW_TRUNCATED,
) -> None:
    """Stabilise a first-person video but keep its intentional motion (thesis ch. 9).

    Looking around and the head bob of running stay; shake, jitter and roll go. The camera path
    is rebuilt from its motion anchors (local extremes), whose amplitudes are reduced just until
    the video becomes comfortable to watch while the first-person feeling remains (maximising VE
    of the new motion minus VE of its zigzag), then eased between anchors. That plan is then bent
    into what a zoom of at most --max-zoom can cover, with the zoom itself changing smoothly over
    time. Unless --no-measure, the output is decoded and measured again, next to the plan.
    """
    import json

    from egovid.core.errors import EgovidError
    from egovid.core.files import atomic_write_text
    from egovid.core.trajectory import Trajectory, read_motion_csv, write_motion_csv
    from egovid.fpv.stabilize.optimize import OptimizeOptions
    from egovid.fpv.stabilize.pipeline import stabilize
    from egovid.fpv.stabilize.render import BORDERS

    if borders not in BORDERS:
        raise EgovidError(f"unknown border mode {borders!r}", f"choose one of {', '.join(BORDERS)}")
    if method not in ("ve", "sve"):
        raise EgovidError(f"unknown method {method!r}", "choose ve or sve")
    if not (0.0 <= strength <= 1.0):
        raise EgovidError(f"strength {strength} is outside [0, 1]", "use e.g. --strength 0.7")
    number(max_zoom, "--max-zoom", lo=1.0, hi=4.0)
    check_source(source)
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
    from egovid.core.camera.resolve import resolve_camera

    intr = resolve_camera(src, focal, hfov).intrinsics
    traj = read_motion_csv(motion) if motion is not None else None
    if traj is not None and len(traj) != info.frame_count:
        from egovid.core.video import count_frames

        n = count_frames(src)
        if len(traj) != n:
            raise EgovidError(
                f"motion {motion} has {len(traj)} frames but {src} has {n}", "estimate the motion of this video again"
            )
    with staged_progress() as cb:
        if traj is None:
            from egovid.core.motion.source import camera_motion

            cm = camera_motion(src, source, focal=focal, hfov=hfov, progress=cb)
            traj, intr = cm.trajectory, cm.camera.intrinsics
        res = stabilize(
            src,
            out,
            intrinsics=intr,
            motion=traj,
            strength=strength,
            borders=borders,
            max_zoom=max_zoom,
            keep_roll=keep_roll,
            method=method,
            opts=OptimizeOptions(anchor_threshold=anchor_threshold, method=method),
            crf=crf,
            measure=measure,
            progress=cb,
        )
    s = res.summary()
    pb, pa = s["planned"]["before"], s["planned"]["after"]
    console.print(
        f"planned   VE {pb['ve']:.3f} → {pa['ve']:.3f}   first-person motion kept "
        f"{100 * s['fpmi_retention_planned']:.1f} %   zoom {s['zoom']['mean']:.3f} (max {s['zoom']['max']:.3f})"
        f"   black {100 * s['black_share']:.2f} %"
    )
    if "measured" in s:
        mb, ma = s["measured"]["before"], s["measured"]["after"]
        console.print(
            f"measured  VE {mb['ve']:.3f} → {ma['ve']:.3f}   2D-VE {mb['ve2d']:.3f} → {ma['ve2d']:.3f}   "
            f"ITF {mb['itf_db']:.2f} → {ma['itf_db']:.2f} dB   "
            f"jitter {mb['jitter_px']:.3f} → {ma['jitter_px']:.3f} px   "
            f"first-person motion kept {100 * s['fpmi_retention_measured']:.1f} %"
        )
    secs = res.seconds
    console.print(
        f"{len(res.times) / max(secs['total'] - secs['measure'], 1e-9):.1f} fps stabilising"
        + (f", {secs['measure']:.1f} s measuring" if measure else "")
    )
    for note in s["notes"]:
        console.print(f"note    {note}")
    console.print(f"video   {out}")
    if save_motion is not None:
        write_motion_csv(
            save_motion.with_name(save_motion.name + ".input.csv"), Trajectory.from_euler(res.times, res.original)
        )
        write_motion_csv(
            save_motion.with_name(save_motion.name + ".output.csv"), Trajectory.from_euler(res.times, res.path)
        )
    if json_out is not None:
        atomic_write_text(json_out, json.dumps(s, indent=1, default=float))
        console.print(f"JSON    {json_out}")
    if report is not None:
        from egovid.fpv.stabilize.report import write_report

        write_report(report, res, str(src), intr, info.fps)
        console.print(f"report  {report}")
