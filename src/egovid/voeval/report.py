"""The evaluation report: Markdown + HTML, figures as PNG, every number in ``matrices.json``.

Sections: the odometers (time per cell, cell outcomes, frames before the first pose, the effect
of anchoring late starters), the "which VO for my application and factor" table (§22.1.3, see
:mod:`egovid.voeval.recommend`), the cells that did not run and why, absolute results with their
spread over seeds (thesis metrics, then ATE / RPE as evo computes them), the compression each
odometer takes (:mod:`egovid.voeval.limits`), the factor matrices (eq. 22.2–22.6) with what they
left out, the influence of compression (Tables 22.1–22.3), and per-scene rotation plots. Every
table of results has floor rows (:mod:`egovid.voeval.floors`); a cell that did not run is shown
as failed or partial with its tracked share instead of a score.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_text
from egovid.voeval.figures import factor_heatmaps, rotation_plots
from egovid.voeval.floors import FLOOR_LABELS
from egovid.voeval.limits import LIMIT_METRICS, compression_limits
from egovid.voeval.matrices import (
    ALL_METRICS,
    METRICS,
    NORMS,
    absolute_matrix,
    factor_matrices,
    mean_over_seeds,
    seed_spread,
)
from egovid.voeval.outcome import RAN_SHARE, outcome
from egovid.voeval.recommend import APPLICATION, answers, in_domain
from egovid.voeval.report_html import markdown_to_html
from egovid.voeval.results import RunResults, load_results

TITLES = {
    "pose_error": "pose error (robotic navigation, lower is better)",
    "oitf": "OITF in dB (video stabilisation, higher is better)",
    "ritf": "RITF in dB (augmented reality, higher is better)",
}
UNITS = {"pose_error": "", "oitf": " dB", "ritf": " dB", "ate_rot_deg": "°", "rpe_rot_deg": "°"}
#: Rows of the failures table written to the Markdown (all of them are in matrices.json).
MAX_FAILURE_ROWS = 200


def _fmt(v: float | None, metric: str) -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    if metric in ("oitf", "ritf"):
        return f"{v:.1f}"
    return f"{v:.1f}" if abs(v) >= 10 else f"{v:.2f}" if abs(v) >= 0.1 else f"{v:.3g}"


def _label(vo: str) -> str:
    return FLOOR_LABELS.get(vo, vo)


def _entry(r: dict | None, metric: str, sd: float = float("nan"), mark: str = "") -> str:
    """A table entry: the seed mean (± spread), or the outcome and tracked share of a cell that did not run."""
    if r is None:
        return "—"
    share = f"{100 * r['tracked_share']:.0f} %"
    if r["outcome"] == "failed":
        return f"failed ({share})"
    text = _fmt(r[metric], metric) + (f" ± {_fmt(sd, metric)}" if np.isfinite(sd) and sd > 0 else "") + mark
    return text if r["outcome"] == "ran" else f"{text} partial ({share})"


def _answer_text(a) -> str:
    if a.best is None:
        return "none ran" if a.not_run else "n/a"
    if len(a.ranking) == 1:
        text = f"**{a.best}** (the only one ranked)"
    elif a.tie:
        margin, spread = _fmt(a.margin, a.metric), _fmt(a.spread, a.metric)
        text = f"tie: **{a.best}** ≈ {a.ranking[1][0]} (margin {margin} ≤ seed spread {spread})"
    else:
        spread = f" ± {_fmt(a.spread, a.metric)}" if a.spread else ""
        text = f"**{a.best}** by {_fmt(a.margin, a.metric)}{UNITS[a.metric]}{spread} over {a.ranking[1][0]}"
    floor = a.no_better_than
    if floor:
        text += f"; no better than {_label(floor)} ({_fmt(a.floors[floor], a.metric)})"
    return text


def _not_ranked(a) -> str:
    parts = [f"{v} (out of domain)" for v in a.out_of_domain]
    parts += [f"{v} ({how}, {100 * share:.0f} % tracked)" for v, how, share in a.not_run]
    return ", ".join(parts) or "—"


def _odometer_section(run: RunResults) -> list[str]:
    md = [
        "## Odometers",
        "",
        f"Outcome of each cell: ran (poses for ≥ {100 * RAN_SHARE:.0f} % of the frames), partial, failed.",
        "",
        "| VO | cells | mean s per cell | status | outcome | mean frames before first pose "
        "| pose error as given → anchored to truth |",
        "|---|---|---|---|---|---|---|",
    ]
    for vo in run.vos:
        cs = [c for k, c in run.cells.items() if k[0] == vo]
        st: dict[str, int] = {}
        oc: dict[str, int] = {}
        for c in cs:
            st[c["status"]] = st.get(c["status"], 0) + 1
            how = c.get("outcome") or outcome(c)
            oc[how] = oc.get(how, 0) + 1
        given = [c["pose_error"] if c.get("anchor", "none") == "none" else c["pose_error_other_anchor"] for c in cs]
        anch = [c["pose_error_other_anchor"] if c.get("anchor", "none") == "none" else c["pose_error"] for c in cs]
        md.append(
            f"| {vo} | {len(cs)} | {np.mean([c['seconds'] for c in cs]):.1f} | "
            + ", ".join(f"{k} {v}" for k, v in sorted(st.items()))
            + " | "
            + ", ".join(f"{k} {oc[k]}" for k in ("ran", "partial", "failed") if k in oc)
            + f" | {np.mean([c.get('first_pose_frame', 0) for c in cs]):.1f}"
            + f" | {np.mean(given):.2f} → {np.mean(anch):.2f} |"
        )
    return md


def _recommendation_section(rows: list, n_seeds: int) -> list[str]:
    if not rows:
        return [
            "## Which VO for my application and factor (§22.1.3)",
            "",
            "No row: the run has no real sequence and no complete factor pair (both scenes of a factor, lossless).",
        ]
    md = [
        "## Which VO for my application and factor (§22.1.3)",
        "",
        "Best score under the factor (challenging scene, no compression; for compression the ideal scene at "
        f"the strongest level), margin over the next odometer{' ± its spread over seeds' if n_seeds > 1 else ''}. "
        "Only odometers that ran are ranked: those out of their domain by design, and those whose cell failed or "
        "tracked too few frames, are listed apart. A winner that does not beat a floor (an odometer that sees "
        "no image) is marked.",
        "",
        "| source | factor | " + " | ".join(APPLICATION[k] for k in METRICS) + " | not ranked "
        "| floors: stationary / constant velocity |",
        "|---|---|" + "---|" * (len(METRICS) + 2),
    ]
    for row in rows:
        a0 = row[0]
        texts = " | ".join(_answer_text(a) for a in row)
        md.append(f"| {a0.source} | {a0.factor} | {texts} | {_not_ranked(a0)} | {_floor_values(row)} |")
    return md


def _floor_values(row: list) -> str:
    """The floors' scores of one recommendation row, per application (pose error · OITF · RITF)."""
    parts = [" / ".join(_fmt(v, a.metric) for v in a.floors.values()) + UNITS[a.metric] for a in row if a.floors]
    return " · ".join(parts) or "—"


def failures(run: RunResults) -> list[dict]:
    """Every odometer cell that did not run: where, its outcome and tracked share, and why."""
    out = []
    for (vo, scene, level, seed), c in run.cells.items():
        how = c.get("outcome") or outcome(c)
        if vo not in run.vos or how == "ran":
            continue
        d = c.get("diagnosis") or {"reason": c.get("message", "")}
        out.append(
            {
                "vo": vo,
                "scene": scene,
                "level": level,
                "seed": seed,
                "outcome": how,
                "tracked_share": c["tracked"] / max(c["frames"], 1),
                **d,
            }
        )
    return out


def _cell_text(text: str) -> str:
    return text.replace("|", "/").replace("\n", " ")


def _failures_section(fails: list[dict]) -> list[str]:
    md = ["## Cells that did not run, and why", ""]
    if not fails:
        return [*md, "Every odometer cell ran.", ""]
    md += [
        "| VO | scene | level | seed | outcome | reason | exit | last lines of its output |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for f in fails[:MAX_FAILURE_ROWS]:
        why = f.get("reason") or "(no reason given)"
        if f.get("reference_motion"):
            why += f"; {f['reference_motion']}"
        exit_ = "timeout" if f.get("timed_out") else ("—" if f.get("exit_status") is None else str(f["exit_status"]))
        tail = " ⏎ ".join(f.get("log_tail", [])[-2:]) or "—"
        md.append(
            f"| {f['vo']} | {f['scene']} | {f['level']} | {f['seed']} | {f['outcome']} "
            f"({100 * f['tracked_share']:.0f} %) | {_cell_text(why)} | {exit_} | {_cell_text(tail)} |"
        )
    if len(fails) > MAX_FAILURE_ROWS:
        md.append(f"\n{len(fails) - MAX_FAILURE_ROWS} more in matrices.json (`failures`).")
    return [*md, ""]


def _absolute_table(run: RunResults, means: dict, spread: dict, metric: str, level: str = "lossless") -> list[str]:
    md = ["| VO | " + " | ".join(run.scenes) + " |", "|---|" + "---|" * len(run.scenes)]
    j = run.levels.index(level)
    for i, vo in enumerate([*run.vos, *run.floors]):
        vals = []
        for m, s in enumerate(run.scenes):
            sd = spread[metric][i, m, j] if i < len(run.vos) else float("nan")
            mark = "" if in_domain(vo, run.scene_info[s]["motion"]) else " †"
            vals.append(_entry(means.get((vo, s, level)), metric, sd, mark))
        md.append(f"| {_label(vo)} | " + " | ".join(vals) + " |")
    return md


def _thesis_sections(run: RunResults, means: dict, spread: dict, m: dict) -> list[str]:
    md = []
    n_seeds = len(run.seeds)
    for metric in METRICS:
        md += [
            "",
            f"## {TITLES[metric]}",
            "",
            f"No compression, mean{' ± std over seeds' if n_seeds > 1 else ''}; † = out of the odometer's domain.",
            "",
            *_absolute_table(run, means, spread, metric),
        ]
        if len(run.levels) > 1 and run.factors:
            md += [
                "",
                f"Influence of compression (std of eq. 22.5 over {', '.join(run.levels)}):",
                "",
                "| VO | " + " | ".join(f.label for f in run.factors) + " |",
                "|---|" + "---|" * len(run.factors),
            ]
            for i, vo in enumerate(run.vos):
                ic = m[metric]["compression"][i]
                vals = [f"{ic[k]:.3g}" if np.isfinite(ic[k]) else "n/a" for k in range(len(run.factors))]
                md.append(f"| {vo} | " + " | ".join(vals) + " |")
    return md


def _evo_section(run: RunResults, means: dict, spread: dict) -> list[str]:
    md = [
        "",
        "## ATE and RPE (evo)",
        "",
        "RMSE over frames (ATE) and consecutive frame pairs (RPE), computed with evo's own functions on the "
        "trajectories the pose error scores, no compression. Rotation in degrees; the estimate's first pose is "
        "the reference's.",
        "",
        "ATE rotation (°):",
        "",
        *_absolute_table(run, means, spread, "ate_rot_deg"),
        "",
        "RPE rotation (° per frame):",
        "",
        *_absolute_table(run, means, spread, "rpe_rot_deg"),
    ]
    has_t = any(c.get("ate_trans") is not None for k, c in run.cells.items() if k[0] in run.vos)
    if has_t:
        md += [
            "",
            "Translation after a Sim(3) alignment (`evo_ape -as`; in the reference's units; n/a: the odometer gives "
            "no positions, the reference has none, or they lie on a line):",
            "",
            "ATE translation:",
            "",
            *_absolute_table(run, means, spread, "ate_trans"),
            "",
            "RPE translation (per frame):",
            "",
            *_absolute_table(run, means, spread, "rpe_trans"),
        ]
    return md


def _limits_section(limits: list) -> list[str]:
    if not limits:
        return []
    md = [
        "",
        "## How much compression each odometer takes",
        "",
        f"The first compression level at which the error is more than 10 % above its lossless value, and the "
        f"first at which the odometer stops running (outcome partial or failed); — = not within the ladder "
        f"(up to {limits[0].strongest}).",
        "",
        "| scene | VO | pose error lossless | +10 % at | ATE rotation lossless (°) | +10 % at | fails at |",
        "|---|---|---|---|---|---|---|",
    ]
    pe, ate = LIMIT_METRICS
    for lim in limits:
        none = "n/a" if lim.fails == "lossless" else "—"
        md.append(
            f"| {lim.scene} | {lim.vo} | {_fmt(lim.lossless[pe], pe)} | {lim.grows[pe] or none} "
            f"| {_fmt(lim.lossless[ate], ate)} | {lim.grows[ate] or none} | {lim.fails or '—'} |"
        )
    return md


def _left_out_section(m: dict) -> list[str]:
    lo = m["left_out"]
    md = ["", "## Factor matrices", ""]
    if not m["factors"]:
        return [*md, "The run has no factor pair (both scenes of a factor): no factor matrix."]
    if not lo:
        return [*md, "Every factor pair of every odometer ran; nothing was left out of the matrices (figures below)."]
    md += [
        f"{len(lo)} (odometer, factor, level) pairs are left out of the matrices (NaN, n/a in the figures), "
        "because a cell of the pair did not run:",
        "",
        "| VO | factor | level | scene | outcome |",
        "|---|---|---|---|---|",
    ]
    md += [
        f"| {d['vo']} | {d['factor']} | {d['level']} | {d['scene']} | {d['outcome']} "
        f"({100 * d['tracked_share']:.0f} %) |"
        for d in lo
    ]
    return md


def write_report(run_dir: str | os.PathLike, norm: str = "thesis") -> tuple[Path, Path]:
    """Compute the matrices of a run and write DIR/report.md, DIR/report.html, DIR/matrices.json;
    ``norm``: "thesis" (eq. 22.2-22.4 as written) or "max_abs". Returns (html, md) paths."""
    if norm not in NORMS:
        raise EgovidError(f"unknown normalisation {norm!r}", f"use one of {', '.join(NORMS)}")
    out = Path(run_dir)
    run = load_results(out)
    means = mean_over_seeds(run.cells)
    m = factor_matrices(means, run.vos, run.levels, run.factors, norm=norm)
    spread = {k: seed_spread(run.cells, run.vos, run.scenes, run.levels, k) for k in ALL_METRICS}
    rows = answers(run)
    fails = failures(run)
    limits = compression_limits(means, run.vos, run.scenes, run.levels)
    figs = out / "figures"
    figs.mkdir(exist_ok=True)
    imgs = factor_heatmaps(m, run, figs) + rotation_plots(out, run, figs)
    md = [
        "# Visual-odometer evaluation",
        "",
        f"Run `{out}`: {len(run.vos)} odometers × {len(run.scenes)} scenes × {len(run.levels)} compression levels × "
        f"{len(run.seeds)} seed(s), and {len(run.floors)} floors. Normalisation: {norm} (eq. 22.2–22.4"
        f"{' as written' if norm == 'thesis' else ', |ΔITF| and max|E|'}).",
        "",
        *_odometer_section(run),
        "",
        *_recommendation_section(rows, len(run.seeds)),
        "",
        *_failures_section(fails),
        *_thesis_sections(run, means, spread, m),
        *_evo_section(run, means, spread),
        *_limits_section(limits),
        *_left_out_section(m),
        "",
        "## Figures",
        "",
        *[f"![{t}]({p})" for t, p in imgs],
    ]
    md_path = atomic_write_text(out / "report.md", "\n".join(md) + "\n")
    atomic_write_text(out / "report.html", markdown_to_html(md))
    dump = _dump(run, means, m, spread, rows, fails, limits, norm)
    atomic_write_text(out / "matrices.json", json.dumps(_finite(dump), indent=1))
    return out / "report.html", md_path


def _dump(run: RunResults, means, m, spread, rows, fails, limits, norm) -> dict:
    """Every number of the report, for matrices.json."""
    vos = [*run.vos, *run.floors]
    return {
        "vos": run.vos,
        "floors": run.floors,
        "scenes": run.scenes,
        "levels": run.levels,
        "seeds": run.seeds,
        "factors": [f.__dict__ for f in run.factors],
        "norm": norm,
        "absolute_rows": vos,
        "absolute": {k: absolute_matrix(means, vos, run.scenes, run.levels, k).tolist() for k in ALL_METRICS},
        "outcome": {f"{vo}/{s}/{lv}": r["outcome"] for (vo, s, lv), r in means.items()},
        "seed_spread": {k: v.tolist() for k, v in spread.items()},
        "factor_matrices": {k: {kk: np.asarray(vv).tolist() for kk, vv in m[k].items()} for k in METRICS},
        "left_out": m["left_out"],
        "failures": fails,
        "compression_limits": [lim.to_dict() for lim in limits],
        "answers": [
            {
                "source": a.source,
                "factor": a.factor,
                "scene": a.scene,
                "level": a.level,
                "application": APPLICATION[a.metric],
                "metric": a.metric,
                "ranking": a.ranking,
                "margin": a.margin,
                "spread": a.spread,
                "tie": a.tie,
                "out_of_domain": a.out_of_domain,
                "not_run": a.not_run,
                "floors": a.floors,
                "no_better_than": a.no_better_than,
            }
            for row in rows
            for a in row
        ],
    }


def _finite(x):
    """JSON without NaN (null instead), which strict readers reject."""
    if isinstance(x, float):
        return x if np.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_finite(v) for v in x]
    return x
