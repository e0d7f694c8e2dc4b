"""``egovid fpv``: first-person video motion, scores and stabilisation."""

from __future__ import annotations

from pathlib import Path

import typer

from egovid.cli.common import (
    ALLOW_TRUNCATED,
    all_or_nothing,
    console,
    err_console,
    parse_ints,
    parse_size,
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
    "the picture itself, by the file's tag or, without one, measured from the picture; else its recorded "
    "image orientation, else vision) | vision (the pictures) | "
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
    from egovid.fpv.motion import MotionOptions, save_motion, sidecar_paths

    video_input(video, allow_truncated=allow_truncated)
    default_json, default_tum = sidecar_paths(out)
    json_out, tum = json_out or default_json, tum or default_tum
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
        cm = save_motion(
            video, out, json_out=json_out, tum=tum, plot=plot, source=source, focal=focal, hfov=hfov, options=opts,
            progress=cb,
        )  # fmt: skip
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
    if cm.picture_share is not None:
        p = cm.picture_share
        share = "n/a" if p.to_dict()["share"] is None else f"{p.share:.2f}"
        console.print(
            f"picture/gyro share {share} of the gyro's 2-8 Hz shake ({p.gyro_rms_deg_s:.2f} deg/s RMS, "
            f"{100 * p.measured:.0f} % measured): {p.verdict}"
        )
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
    from egovid.fpv.score import check_request, score_video

    check_request(video, motion, method)
    choice(sve_variant, "--sve-variant", ("coverage", "thesis"))
    check_source(source)
    number(fps, "--fps", lo=0, lo_open=True, hi=1000)
    number(d_over_f, "--d-over-f", lo=0, lo_open=True, hi=1000)
    number(mar, "--mar", lo=0, lo_open=True, hi=10, unit="degrees")
    number(bias, "--bias", lo=0, hi=10, unit="degrees")
    input_file(motion, "motion CSV")
    if video is not None:
        video_input(video, allow_truncated=allow_truncated)
    outputs(
        [video, motion],
        (json_out, JSON, "JSON"),
        (plot, PLOT, "plot"),
        (save_motion if video else None, CSV, "motion CSV"),
    )
    with staged_progress() as cb:
        rep = score_video(
            video, motion=motion, method=method, focal=focal, hfov=hfov, size=parse_size(size) if size else None,
            fps=fps, d_over_f=d_over_f, bias=bias, mar=mar, sve_variant=sve_variant, source=source,
            json_out=json_out, plot=plot, save_motion=save_motion, progress=cb,
        )  # fmt: skip
    if rep.motion is not None:
        console.print(f"motion from {rep.motion.source} ({rep.motion.reason}); intrinsics: {rep.intrinsics_source}")
    from rich.table import Table

    table = Table(title=f"Viewing experience of {rep.input.name}")
    table.add_column("method")
    for col in ("overall", "yaw", "pitch", "roll"):
        table.add_column(col, justify="right")
    for m, r in rep.results.items():
        if m == "ve2d":
            table.add_row("2D-VE", f"{r.score:.3f}", "", "", "")
        else:
            table.add_row(m.upper(), f"{r.score:.3f}", *(f"{r.axis_scores[a]:.3f}" for a in ("yaw", "pitch", "roll")))
    console.print(table)
    console.print("1 = a viewer can pursue targets in every frame; 0 = never.")
    if json_out is not None:
        console.print(f"JSON  {json_out}")
    if plot is not None:
        console.print(f"plot  {plot}")


@app.command("stabilize")
@all_or_nothing
def stabilize_cmd(
    src: Path = typer.Argument(..., help="Input video."),
    out: Path = typer.Option(
        ...,
        "-o",
        "--out",
        help="Output video (MP4: H.264, or HEVC Main10 at 10 bits; audio, telemetry, timing, colour and HDR kept).",
    ),
    strength: float = typer.Option(1.0, help="0 = untouched … 1 = the optimum of eq. 9.4 (default)."),
    borders: str = typer.Option(
        "crop", help="crop (a zoom that follows the need, no borders) | black | fill (temporal mosaic)."
    ),
    max_zoom: float = typer.Option(
        1.10,
        "--max-zoom",
        help="Largest zoom the crop may use (1.10 = 10 %); the zoom follows the need frame by frame and the "
        "path bends to stay within it.",
    ),
    horizon_lock: bool = typer.Option(
        False,
        "--horizon-lock",
        help="Level every view with gravity (the accelerometer's where the camera logs one, else the path's "
        "mean down direction).",
    ),
    readout: float = typer.Option(
        None,
        "--readout",
        help="Rolling-shutter frame readout in ms (negative: bottom row first; 0: global shutter). Default: the "
        "file's (GoPro SROT) or its lens profile's where known, else none.",
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
    crf: int = typer.Option(18, min=0, max=51, help="x264/x265 quality of the output (lower = better)."),
    bit_depth: str = typer.Option(
        "auto",
        "--bit-depth",
        help="Bits per sample of the output: auto (the input's: 10-bit and HDR phone video gives 10-bit HEVC "
        "Main10 with its BT.2020/HLG/PQ tags and HDR10 metadata, 8-bit gives H.264) | 8 (H.264) | 10 (HEVC Main10).",
    ),
    source: str = source_option(),
    allow_truncated: bool = ALLOW_TRUNCATED,
) -> None:
    """Stabilise a first-person video but keep its intentional motion (thesis ch. 9).

    Looking around and the head bob of running stay; shake, jitter and roll go. The camera path
    is rebuilt from its motion anchors (local extremes), whose amplitudes are reduced just until
    the video becomes comfortable to watch while the first-person feeling remains (maximising VE
    of the new motion minus VE of its zigzag), then eased between anchors. That plan is then bent
    into what a zoom of at most --max-zoom can cover, with the zoom itself changing smoothly over
    time. Below the plan, what a viewer sees as shake is removed as far as the plan's first-person
    motion allows (the plan low-passed at the lowest cutoff that keeps 90 % of its FPMI; where that
    keeps under 92 % of the input's, the swings the plan reduced are given back below 1 Hz). With a
    known rolling-shutter readout (--readout, GoPro SROT, the lens profile) every row band is warped
    from its own time. Unless --no-measure, the output is decoded and measured again, next to the plan.
    """
    from egovid.fpv.stabilize.render import BIT_DEPTHS
    from egovid.fpv.stabilize.run import check_options, saved_motion_paths, stabilize_video

    check_options(strength, borders, method)
    choice(bit_depth, "--bit-depth", BIT_DEPTHS)
    number(max_zoom, "--max-zoom", lo=1.0, hi=4.0)
    number(readout, "--readout", lo=-100.0, hi=100.0, unit="ms")
    check_source(source)
    video_input(src, allow_truncated=allow_truncated)
    input_file(motion, "motion CSV")
    outputs(
        [src, motion],
        (out, VIDEO_OUT, "output video"),
        (report, HTML, "report"),
        (json_out, JSON, "JSON"),
        *((p, CSV, "motion CSV") for p in (saved_motion_paths(save_motion) if save_motion else ())),
    )
    with staged_progress() as cb:
        res = stabilize_video(
            src, out, source=source, focal=focal, hfov=hfov, motion=motion, strength=strength, borders=borders,
            max_zoom=max_zoom, keep_roll=keep_roll, method=method, anchor_threshold=anchor_threshold, crf=crf,
            bit_depth=bit_depth, measure=measure, horizon_lock=horizon_lock, readout_ms=readout,
            save_motion=save_motion, json_out=json_out, report=report, progress=cb,
        )  # fmt: skip
    s = res.summary()
    if "motion_source" in s:
        console.print(f"motion    {s['motion_source']['source']} ({s['motion_source']['reason']})")
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
            f"shake {mb['shake_px']:.3f} → {ma['shake_px']:.3f} px   "
            f"first-person motion kept {100 * s['fpmi_retention_measured']:.1f} %"
        )
    secs = res.seconds
    # The motion stage ran before the stabiliser when the source was resolved: count it too.
    motion_s = res.camera_motion.seconds.get("total", 0.0) if res.camera_motion is not None else 0.0
    console.print(
        f"{len(res.times) / max(motion_s + secs['total'] - secs['measure'], 1e-9):.1f} fps stabilising"
        + (f", {secs['measure']:.1f} s measuring" if measure else "")
    )
    for note in s["notes"]:
        console.print(f"note    {note}")
    for warning in s["warnings"]:
        err_console.print(f"warning: {warning}")
    console.print(f"video   {out}")
    if json_out is not None:
        console.print(f"JSON    {json_out}")
    if report is not None:
        console.print(f"report  {report}")
