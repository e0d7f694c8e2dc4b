"""``egovid voeval``: evaluate visual odometers on controlled synthetic videos."""

from __future__ import annotations

from pathlib import Path

import typer

from egovid.cli.common import console, staged_progress

app = typer.Typer(
    help="Evaluate visual odometers: which factor hurts which VO, for robots (pose error), "
    "stabilisation (OITF) and augmented reality (RITF).",
    no_args_is_help=True,
)


@app.command("run")
def run(
    out: Path = typer.Option(..., "--out", help="Run folder (created; an existing run is resumed)."),
    vo: str = typer.Option(
        None, help="Built-in odometers: egovid, ecc, monovo, colmap, orbslam3 (default: all available)."
    ),
    vo_cmd: list[str] = typer.Option(
        [], help='External VO: "[NAME=]tool {video} {out}" writing TUM/KITTI; repeatable.'
    ),
    frames: int = typer.Option(48, min=10, max=2000, help="Frames per test video."),
    size: str = typer.Option("320x240", help="WIDTHxHEIGHT of the test videos."),
    levels: str = typer.Option("lossless,crf18,crf24,crf30,crf36,crf42,crf48", help="Compression levels."),
    workers: int = typer.Option(2, min=1, max=64, help="Parallel worker processes."),
    report: bool = typer.Option(True, help="Write the report when done."),
) -> None:
    """Render the test scenes and their compression ladder, run every odometer on every video
    (finished cells are kept: re-running resumes), and score pose error, OITF and RITF."""
    from egovid.cli.common import parse_size
    from egovid.cli.validate import output_folder
    from egovid.errors import EgovidError
    from egovid.voeval.runner import LEVELS, GridConfig, run_grid

    output_folder(out, what="run folder")
    w, h = parse_size(size)
    lv = [x.strip() for x in levels.split(",") if x.strip()]
    bad = [x for x in lv if x not in LEVELS]
    if bad:
        raise EgovidError(f"unknown compression level(s) {', '.join(bad)}", f"use some of {', '.join(LEVELS)}")
    cfg = GridConfig(
        vos=[x.strip() for x in vo.split(",") if x.strip()],
        commands=list(vo_cmd),
        frames=frames,
        width=w,
        height=h,
        levels=lv,
        workers=workers,
    )
    with staged_progress() as cb:
        r = run_grid(out, cfg, progress=cb)
    console.print(f"{r['cells']} cells ({r['computed']} computed now) in {r['seconds']:.0f} s → {out}/results")
    if report:
        from egovid.voeval.report import write_report

        h_, m_ = write_report(out)
        console.print(f"report {h_}\n       {m_}")


@app.command("report")
def report_cmd(run_dir: Path = typer.Argument(..., help="Run folder of `egovid voeval run`.")) -> None:
    """Factor matrices, heatmaps and the "which VO for my application" answers (HTML + Markdown)."""
    from egovid.voeval.report import write_report

    h_, m_ = write_report(run_dir)
    console.print(f"report {h_}\n       {m_}")
