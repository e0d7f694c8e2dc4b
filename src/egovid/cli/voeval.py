"""``egovid voeval``: evaluate visual odometers on controlled synthetic videos and real sequences."""

from __future__ import annotations

from pathlib import Path

import typer

from egovid.cli.common import console, staged_progress

app = typer.Typer(
    help="Evaluate visual odometers: which factor hurts which VO, for robots (pose error), "
    "stabilisation (OITF) and augmented reality (RITF), on synthetic scenes and real sequences.",
    no_args_is_help=True,
)

SEQUENCE_HELP = (
    "A real sequence FORMAT:PATH, repeatable: tum:FOLDER (TUM RGB-D), euroc:FOLDER (EuRoC MAV), "
    "kitti:FOLDER (KITTI odometry sequence with poses), frames:FOLDER (images + TUM trajectory + "
    "camera.txt), gyro:VIDEO (a camera's embedded gyro is the reference). Cells are named after "
    "the folder or file."
)


@app.command("run")
def run(
    out: Path = typer.Option(..., "--out", help="Run folder (created; an existing run is resumed)."),
    vo: str = typer.Option(
        None,
        help="Built-in odometers, comma-separated: egovid, ecc, monovo, colmap, orbslam3 (default: all available; "
        "'' for none, with --vo-cmd).",
    ),
    vo_cmd: list[str] = typer.Option(
        [], help='External VO: "[NAME=]tool {video} {out}" writing TUM (matched by time) or KITTI; repeatable.'
    ),
    sequence: list[str] = typer.Option([], "--sequence", help=SEQUENCE_HELP),
    synthetic: bool = typer.Option(
        True, help="Include the synthetic factor scenes (--no-synthetic: real sequences only)."
    ),
    scenes: str = typer.Option(
        None,
        help="Synthetic scenes, comma-separated (default all: orbit-ideal, orbit-fog, orbit-unseen, orbit-sensor, "
        "pano-ideal, pano-motion).",
    ),
    real_factors: str = typer.Option(
        "noise,blur,illumination", help="Image-level factors applied to the frames of real sequences."
    ),
    frames: int = typer.Option(
        None,
        min=10,
        max=100000,
        help="Frames per synthetic scene, and the most taken from each real sequence (default 300; 48 with --quick).",
    ),
    size: str = typer.Option(
        None, help="WIDTHxHEIGHT of the synthetic scenes (default 640x480; 320x240 with --quick)."
    ),
    quick: bool = typer.Option(False, "--quick", help="The small smoke-test grid: 48 frames at 320x240."),
    levels: str = typer.Option("lossless,crf18,crf24,crf30,crf36,crf42,crf48", help="Compression levels."),
    seeds: str = typer.Option("0", help="Seeds, comma-separated: each scene is made and scored once per seed."),
    anchor: str = typer.Option(
        "none",
        help="Late-starting odometers: 'none' scores their output as given, 'truth' anchors their first "
        "pose to the true orientation (favours late starters; see docs/voeval.md).",
    ),
    scheduler: str = typer.Option(
        None,
        help="Dask scheduler (tcp://HOST:8786) to run the cells on; default $DASK_SCHEDULER_ADDRESS, else this "
        "machine. The run folder must be reachable at the same path from every worker.",
    ),
    workers: int = typer.Option(
        2, min=1, max=512, help="Local worker processes without a scheduler (1: in this process)."
    ),
    vo_timeout: float = typer.Option(
        600.0, min=1.0, help="Seconds an odometer may run on one video in its own process (then: timed out)."
    ),
    report: bool = typer.Option(True, help="Write the report when done."),
) -> None:
    """Make the test videos (synthetic scenes, real sequences and their degraded copies, the H.264
    ladder), run every odometer on every video (finished cells are kept: re-running resumes), and
    score pose error, OITF, RITF, ATE and RPE, beside the floors (stationary, constant velocity)."""
    from egovid.cli.common import parse_ints, parse_size
    from egovid.cli.validate import output_folder
    from egovid.core.engine import EngineConfig, scheduler_address
    from egovid.voeval.runner import DEFAULT_FRAMES, DEFAULT_SIZE, QUICK_FRAMES, QUICK_SIZE, GridConfig, evaluate

    output_folder(out, inputs=[Path(x.partition(":")[2]) for x in sequence], what="run folder")
    w, h = parse_size(size) if size else (QUICK_SIZE if quick else DEFAULT_SIZE)
    cfg = GridConfig(
        commands=list(vo_cmd),
        frames=frames or (QUICK_FRAMES if quick else DEFAULT_FRAMES),
        width=w,
        height=h,
        levels=_names(levels),
        sequences=list(sequence),
        real_factors=_names(real_factors),
        seeds=list(parse_ints(seeds, "--seeds")),
        anchor=anchor.strip().lower(),
        timeout=vo_timeout,
    )
    if vo is not None:
        cfg.vos = _names(vo)
    if scenes is not None or not synthetic:
        cfg.scenes = _names(scenes or "") if synthetic else []
    engine = EngineConfig(scheduler=scheduler_address(scheduler), workers=workers)
    with staged_progress() as cb:
        r = evaluate(out, cfg, engine, progress=cb, report=report)
    console.print(f"{r['cells']} cells ({r['computed']} computed now) in {r['seconds']:.0f} s → {out}/results")
    if r["report"]:
        console.print(f"report {r['report'][0]}\n       {r['report'][1]}")


def _names(text: str) -> list[str]:
    return [x.strip() for x in text.split(",") if x.strip()]


@app.command("report")
def report_cmd(
    run_dir: Path = typer.Argument(..., help="Run folder of `egovid voeval run`."),
    norm: str = typer.Option(
        "thesis",
        help="Factor normalisation: 'thesis' (eq. 22.2-22.4 as written) or 'max_abs' (|OITF-RITF| and max|E|).",
    ),
) -> None:
    """Factor matrices, rotation plots, the "which VO for my application and factor" table, the
    cells that did not run and why, ATE / RPE and the compression each odometer takes (HTML +
    Markdown + matrices.json)."""
    from egovid.voeval.report import write_report

    h_, m_ = write_report(run_dir, norm=norm)
    console.print(f"report {h_}\n       {m_}")
