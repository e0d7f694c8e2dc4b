"""The evaluation report: Markdown + HTML, figures as PNG, every number in ``matrices.json``.

Sections: the odometers (time per cell, cell status, frames before the first pose, the effect of
anchoring late starters), the "which VO for my application and factor" table (§22.1.3, see
:mod:`egovid.voeval.recommend`), absolute results with their spread over seeds, factor matrices
(eq. 22.2–22.6) per source, the influence of compression (Tables 22.1–22.3), and per-scene
rotation plots (truth against every odometer).
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

import numpy as np

from egovid.core.files import atomic_write_text
from egovid.core.plots import plt, save
from egovid.core.trajectory import Trajectory, read_tum
from egovid.voeval.layout import cell_path, scene_dir
from egovid.voeval.matrices import (
    METRICS,
    absolute_matrix,
    factor_matrices,
    mean_over_seeds,
    seed_spread,
)
from egovid.voeval.recommend import APPLICATION, answers, in_domain
from egovid.voeval.runner import RunResults, load_results
from egovid.voeval.scenes import SceneTruth

TITLES = {
    "pose_error": "pose error (robotic navigation, lower is better)",
    "oitf": "OITF in dB (video stabilisation, higher is better)",
    "ritf": "RITF in dB (augmented reality, higher is better)",
}
UNITS = {"pose_error": "", "oitf": " dB", "ritf": " dB"}


def _heatmap(
    path: Path,
    data: np.ndarray,
    rows: list[str],
    cols: list[str],
    title: str,
    fmt: str = "{:.2f}",
    cmap: str = "viridis",
) -> Path:
    fig, ax = plt.subplots(figsize=(1.6 + 1.15 * len(cols), 0.9 + 0.5 * len(rows)))
    im = ax.imshow(np.nan_to_num(data, nan=0.0), cmap=cmap, aspect="auto")
    ax.set_xticks(range(len(cols)), cols, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(rows)), rows, fontsize=8)
    finite = data[np.isfinite(data)]
    mid = float(np.mean(finite)) if finite.size else 0.0
    for i in range(len(rows)):
        for j in range(len(cols)):
            v = data[i, j]
            txt = "n/a" if not np.isfinite(v) else fmt.format(v)
            ax.text(j, i, txt, ha="center", va="center", fontsize=7, color="w" if np.isfinite(v) and v < mid else "k")
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.046)
    return save(fig, path)


def _fmt(v: float, metric: str) -> str:
    if not np.isfinite(v):
        return "n/a"
    return f"{v:.1f}" if metric != "pose_error" or abs(v) >= 10 else f"{v:.2f}"


def _answer_text(a) -> str:
    if a.best is None:
        return "n/a"
    if len(a.ranking) == 1:
        text = f"**{a.best}** (the only one ranked)"
    elif a.tie:
        margin, spread = _fmt(a.margin, a.metric), _fmt(a.spread, a.metric)
        text = f"tie: **{a.best}** ≈ {a.ranking[1][0]} (margin {margin} ≤ seed spread {spread})"
    else:
        spread = f" ± {_fmt(a.spread, a.metric)}" if a.spread else ""
        text = f"**{a.best}** by {_fmt(a.margin, a.metric)}{UNITS[a.metric]}{spread} over {a.ranking[1][0]}"
    return text


def _rotation_figure(path: Path, times: np.ndarray, reference: np.ndarray, curves: dict, title: str) -> Path:
    """Yaw, pitch, roll (degrees) of the reference (black) and each odometer. The vertical range
    follows the reference (its range + 50 %, at least ±2°), so one odometer that runs away does
    not flatten the others; it is marked "off scale" in the legend."""
    fig, axes = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True)
    for k, ax in enumerate(axes):
        lo, hi = float(reference[:, k].min()), float(reference[:, k].max())
        pad = max(0.5 * (hi - lo), 2.0)
        lo, hi = lo - pad, hi + pad
        ax.plot(times, reference[:, k], color="k", lw=2.0, label="reference")
        for name, a in curves.items():
            off = np.any((a[:, k] < lo) | (a[:, k] > hi))
            ax.plot(times[: len(a)], a[:, k], lw=1.0, label=name + (" (off scale)" if off else ""))
        ax.set_ylim(lo, hi)
        ax.set_ylabel(f"{('yaw', 'pitch', 'roll')[k]} (°)")
        ax.grid(alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=7)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title(title, fontsize=10)
    return save(fig, path)


def rotation_plots(out: Path, run: RunResults, figs: Path) -> list[tuple[str, str]]:
    """Per scene (no compression, first seed): reference against every odometer."""
    seed = run.seeds[0]
    imgs = []
    for s in run.scenes:
        info = run.scene_info[s]
        try:
            truth = SceneTruth.load(scene_dir(out, seed, info["seeded"]), s)
        except FileNotFoundError:
            continue
        curves = {}
        for vo in run.vos:
            tum = cell_path(out, vo, s, "lossless", seed).with_suffix(".tum")
            if tum.exists():
                curves[vo] = read_tum(tum).euler()
        if not curves:
            continue
        ref = Trajectory(truth.times, truth.R).euler()
        title = f"{s}: reference and odometers (lossless, seed {seed}; anchoring as scored)"
        path = _rotation_figure(figs / f"rotation_{s}.png", truth.times, ref, curves, title)
        imgs.append((f"Rotation, {s}", f"figures/{path.name}"))
    return imgs


def _odometer_table(run: RunResults) -> list[str]:
    md = [
        "| VO | cells | mean s per cell | status | mean frames before first pose "
        "| pose error as given → anchored to truth |",
        "|---|---|---|---|---|---|",
    ]
    for vo in run.vos:
        cs = [c for k, c in run.cells.items() if k[0] == vo]
        st: dict[str, int] = {}
        for c in cs:
            st[c["status"]] = st.get(c["status"], 0) + 1
        given = [c["pose_error"] if c.get("anchor", "none") == "none" else c["pose_error_other_anchor"] for c in cs]
        anch = [c["pose_error_other_anchor"] if c.get("anchor", "none") == "none" else c["pose_error"] for c in cs]
        md.append(
            f"| {vo} | {len(cs)} | {np.mean([c['seconds'] for c in cs]):.1f} | "
            + ", ".join(f"{k} {v}" for k, v in sorted(st.items()))
            + f" | {np.mean([c.get('first_pose_frame', 0) for c in cs]):.1f}"
            + f" | {np.mean(given):.2f} → {np.mean(anch):.2f} |"
        )
    return md


def write_report(run_dir: str | os.PathLike, norm: str = "thesis") -> tuple[Path, Path]:
    """Compute the matrices of a run and write DIR/report.md, DIR/report.html, DIR/matrices.json."""
    out = Path(run_dir)
    run = load_results(out)
    means = mean_over_seeds(run.cells)
    m = factor_matrices(means, run.vos, run.levels, run.factors, norm=norm)
    absolute = {k: absolute_matrix(means, run.vos, run.scenes, run.levels, k) for k in METRICS}
    spread = {k: seed_spread(run.cells, run.vos, run.scenes, run.levels, k) for k in METRICS}
    rows = answers(run)
    figs = out / "figures"
    figs.mkdir(exist_ok=True)
    sources = list(dict.fromkeys(f.source for f in run.factors))
    imgs: list[tuple[str, str]] = []
    for metric in METRICS:
        for src in sources:
            idx = [k for k, f in enumerate(run.factors) if f.source == src]
            cols = [run.factors[k].name for k in idx]
            tag = f"{metric}_{src}".replace("/", "-")
            for kind, eq in (("relative", "22.2-22.4"), ("absolute", "22.5-22.6")):
                _heatmap(
                    figs / f"{kind}_{tag}.png",
                    m[metric][kind][:, idx, 0],
                    run.vos,
                    cols,
                    f"{kind.capitalize()} influence on {metric}, {src} (eq. {eq}), {run.levels[0]}",
                    cmap="magma",
                )
                imgs.append(
                    (f"{kind.capitalize()} influence of factors on {metric} — {src}", f"figures/{kind}_{tag}.png")
                )
    imgs += rotation_plots(out, run, figs)

    n_seeds = len(run.seeds)
    md = [
        "# Visual-odometer evaluation",
        "",
        f"Run `{out}`: {len(run.vos)} odometers × {len(run.scenes)} scenes × {len(run.levels)} compression levels × "
        f"{n_seeds} seed(s) = {len(run.cells)} cells. Normalisation: {norm} (eq. 22.2–22.4"
        f"{' as written' if norm == 'thesis' else ', |ΔITF| and max|E|'}).",
        "",
        "## Odometers",
        "",
        *_odometer_table(run),
        "",
        "## Which VO for my application and factor (§22.1.3)",
        "",
        "Best score under the factor (challenging scene, no compression; for compression the ideal scene at "
        f"the strongest level), margin over the next odometer{' ± its spread over seeds' if n_seeds > 1 else ''}. "
        "Odometers out of their domain by design are not ranked.",
        "",
        "| source | factor | " + " | ".join(APPLICATION[k] for k in METRICS) + " | not ranked (out of domain) |",
        "|---|---|" + "---|" * (len(METRICS) + 1),
    ]
    for row in rows:
        a0 = row[0]
        md.append(
            f"| {a0.source} | {a0.factor} | "
            + " | ".join(_answer_text(a) for a in row)
            + f" | {', '.join(a0.out_of_domain) or '—'} |"
        )
    for metric in METRICS:
        md += [
            "",
            f"## {TITLES[metric]}",
            "",
            f"No compression, mean{' ± std over seeds' if n_seeds > 1 else ''}; † = out of the odometer's domain.",
            "",
            "| VO | " + " | ".join(run.scenes) + " |",
            "|---|" + "---|" * len(run.scenes),
        ]
        for i, vo in enumerate(run.vos):
            vals = []
            for j, s in enumerate(run.scenes):
                v, sd = absolute[metric][i, j, 0], spread[metric][i, j, 0]
                mark = "" if in_domain(vo, run.scene_info[s]["motion"]) else " †"
                vals.append(
                    _fmt(v, metric) + (f" ± {_fmt(sd, metric)}" if n_seeds > 1 and np.isfinite(sd) else "") + mark
                )
            md.append(f"| {vo} | " + " | ".join(vals) + " |")
        if len(run.levels) > 1 and run.factors:
            md += [
                "",
                f"Influence of compression (std of eq. 22.5 over {', '.join(run.levels)}):",
                "",
                "| VO | " + " | ".join(f.label for f in run.factors) + " |",
                "|---|" + "---|" * len(run.factors),
            ]
            for i, vo in enumerate(run.vos):
                md.append(
                    f"| {vo} | "
                    + " | ".join(f"{m[metric]['compression'][i, k]:.3g}" for k in range(len(run.factors)))
                    + " |"
                )
    md += ["", "## Figures", ""] + [f"![{t}]({p})" for t, p in imgs]
    md_path = atomic_write_text(out / "report.md", "\n".join(md) + "\n")
    atomic_write_text(out / "report.html", _html(md, imgs))
    dump = {
        "vos": run.vos,
        "scenes": run.scenes,
        "levels": run.levels,
        "seeds": run.seeds,
        "factors": [f.__dict__ for f in run.factors],
        "norm": norm,
        "absolute": {k: v.tolist() for k, v in absolute.items()},
        "seed_spread": {k: v.tolist() for k, v in spread.items()},
        "factor_matrices": {k: {kk: np.asarray(vv).tolist() for kk, vv in m[k].items()} for k in METRICS},
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
            }
            for row in rows
            for a in row
        ],
    }
    atomic_write_text(out / "matrices.json", json.dumps(_finite(dump), indent=1))
    return out / "report.html", md_path


def _finite(x):
    """JSON without NaN (null instead), which strict readers reject."""
    if isinstance(x, float):
        return x if np.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_finite(v) for v in x]
    return x


def _html(md: list[str], imgs: list[tuple[str, str]]) -> str:
    """A plain HTML rendering of the Markdown (tables and headings), images inline."""
    body, table = [], []

    def flush():
        if table:
            rows = [r.strip("|").split("|") for r in table if not set(r) <= set("|-")]
            head, *rest = rows
            body.append(
                "<table><tr>"
                + "".join(f"<th>{_inline(c)}</th>" for c in head)
                + "</tr>"
                + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in rest)
                + "</table>"
            )
            table.clear()

    for line in md:
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if line.startswith("!["):
            alt, src = line[2:].split("](")
            body.append(f"<h3>{html.escape(alt)}</h3><img src='{html.escape(src.rstrip(')'))}'>")
        elif line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            body.append(f"<h{level}>{_inline(line.lstrip('#').strip())}</h{level}>")
        elif line.strip():
            body.append(f"<p>{_inline(line)}</p>")
    flush()
    return (
        "<!doctype html><html><head><meta charset='utf-8'><title>VO evaluation</title><style>"
        "body{font-family:system-ui;max-width:1200px;margin:2em auto}img{max-width:100%}"
        "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px}"
        "</style></head><body>" + "\n".join(body) + "</body></html>"
    )


def _inline(text: str) -> str:
    import re

    t = html.escape(text.strip())
    t = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", t)
    return re.sub(r"`(.+?)`", r"<code>\1</code>", t)
