"""The evaluation report (HTML + Markdown, heatmaps as PNG files) and the answers of §22.1.3."""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

import numpy as np

from egovid.io.files import atomic_write_text
from egovid.plots import plt, save
from egovid.voeval.matrices import LOWER_IS_BETTER, METRICS, absolute_matrix, factor_matrices
from egovid.voeval.runner import load_results
from egovid.voeval.scenes import FACTORS

TITLES = {
    "pose_error": "pose error (robotic perception, lower is better)",
    "oitf": "OITF (video stabilisation, higher is better)",
    "ritf": "RITF (augmented reality, higher is better)",
}
APPLICATION = {"pose_error": "robotic navigation", "oitf": "video stabilisation", "ritf": "augmented reality"}


def _heatmap(
    path: Path,
    data: np.ndarray,
    rows: list[str],
    cols: list[str],
    title: str,
    fmt: str = "{:.2f}",
    cmap: str = "viridis",
) -> Path:
    fig, ax = plt.subplots(figsize=(1.3 + 1.15 * len(cols), 0.9 + 0.5 * len(rows)))
    im = ax.imshow(np.nan_to_num(data, nan=0.0), cmap=cmap, aspect="auto")
    ax.set_xticks(range(len(cols)), cols, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(rows)), rows, fontsize=8)
    for i in range(len(rows)):
        for j in range(len(cols)):
            v = data[i, j]
            ax.text(
                j,
                i,
                "n/a" if not np.isfinite(v) else fmt.format(v),
                ha="center",
                va="center",
                fontsize=7,
                color="w" if np.isfinite(v) and v < np.nanmean(data) else "k",
            )
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.046)
    return save(fig, path)


def answers(m: dict, absolute: dict, vos: list[str], scenes: list[str], level: int = 0) -> list[str]:
    """The practical conclusions of §22.1.3, at compression level index ``level`` (0 = lossless)."""
    lines = []
    factors = m["factors"]
    for metric in METRICS:
        rel = m[metric]["relative"][:, :, level]
        ab = m[metric]["absolute"][:, :, level]
        for i, vo in enumerate(vos):
            if np.all(~np.isfinite(rel[i])):
                continue
            k = int(np.nanargmax(rel[i]))
            lines.append(f"{APPLICATION[metric]}: the factor that hurts **{vo}** most is **{factors[k]}**.")
        for k, f in enumerate(factors):
            if np.all(~np.isfinite(ab[:, k])):
                continue
            i = int(np.nanargmax(ab[:, k]))
            lines.append(f"{APPLICATION[metric]}: the VO most sensitive to **{f}** is **{vos[i]}**.")
        # Which VO to choose when a factor dominates: best absolute score in its challenging scene.
        a = absolute[metric][:, :, level]
        for f, (_, hard) in FACTORS.items():
            if hard not in scenes:
                continue
            col = a[:, scenes.index(hard)]
            if np.all(~np.isfinite(col)):
                continue
            best = int(np.nanargmin(col) if LOWER_IS_BETTER[metric] else np.nanargmax(col))
            lines.append(f"For **{APPLICATION[metric]}** where **{f}** is the main problem, choose **{vos[best]}**.")
        mean = np.nanmean(a, axis=1)
        best = int(np.nanargmin(mean) if LOWER_IS_BETTER[metric] else np.nanargmax(mean))
        lines.append(
            f"For **{APPLICATION[metric]}** with no known main factor, choose **{vos[best]}** "
            "(best average over all scenes)."
        )
    return lines


def write_report(run: str | os.PathLike) -> tuple[Path, Path]:
    """Compute the matrices of a run and write DIR/report.html and DIR/report.md."""
    run = Path(run)
    results, vos, scenes, levels = load_results(run)
    m = factor_matrices(results, vos, levels)
    absolute = {metric: absolute_matrix(results, vos, scenes, levels, metric) for metric in METRICS}
    figs = run / "figures"
    figs.mkdir(exist_ok=True)
    imgs: list[tuple[str, str]] = []
    factors = m["factors"]
    for metric in METRICS:
        _heatmap(
            figs / f"absolute_{metric}.png",
            absolute[metric][:, :, 0],
            vos,
            scenes,
            f"Absolute {TITLES[metric]}, {levels[0]}",
            cmap="viridis_r" if LOWER_IS_BETTER[metric] else "viridis",
        )
        imgs.append((f"Absolute {TITLES[metric]}", f"figures/absolute_{metric}.png"))
        _heatmap(
            figs / f"relative_{metric}.png",
            m[metric]["relative"][:, :, 0],
            vos,
            factors,
            f"Relative influence of factors on {metric} (eq. 22.2-22.4), {levels[0]}",
            cmap="magma",
        )
        imgs.append((f"Which factor hurts each VO most — {metric}", f"figures/relative_{metric}.png"))
        _heatmap(
            figs / f"absolute_influence_{metric}.png",
            m[metric]["absolute"][:, :, 0],
            vos,
            factors,
            f"Absolute influence of factors on {metric} (eq. 22.5-22.6), {levels[0]}",
            cmap="magma",
        )
        imgs.append((f"Which VO each factor hurts most — {metric}", f"figures/absolute_influence_{metric}.png"))
        _heatmap(
            figs / f"compression_{metric}.png",
            m[metric]["compression"],
            vos,
            factors,
            f"Influence of compression on {metric} (std over levels)",
            fmt="{:.3g}",
            cmap="cividis",
        )
        imgs.append((f"Influence of compression — {metric}", f"figures/compression_{metric}.png"))
    status = {}
    for (vo, _s, _l), c in results.items():
        status.setdefault(vo, {}).setdefault(c["status"], 0)
        status[vo][c["status"]] += 1
    times = {vo: float(np.mean([c["seconds"] for (v, _, _), c in results.items() if v == vo])) for vo in vos}
    ans = answers(m, absolute, vos, scenes)
    md = [
        "# Visual-odometer evaluation",
        "",
        f"Run `{run}`: {len(vos)} odometers × {len(scenes)} scenes × "
        f"{len(levels)} compression levels = {len(results)} cells.",
        "",
        "## Odometers",
        "",
        "| VO | mean seconds per clip | cell status |",
        "|---|---|---|",
    ]
    for vo in vos:
        st = ", ".join(f"{k}: {v}" for k, v in sorted(status[vo].items()))
        md.append(f"| {vo} | {times[vo]:.1f} | {st} |")
    md += ["", "## Which VO for my application", ""] + [f"- {a}" for a in ans] + [""]
    for metric in METRICS:
        md += [f"## {TITLES[metric]}", "", "| VO | " + " | ".join(scenes) + " |", "|---|" + "---|" * len(scenes)]
        for i, vo in enumerate(vos):
            md.append(f"| {vo} | " + " | ".join(f"{absolute[metric][i, j, 0]:.3f}" for j in range(len(scenes))) + " |")
        md += [
            "",
            f"Influence of compression (std over {', '.join(levels)}):",
            "",
            "| VO | " + " | ".join(factors) + " |",
            "|---|" + "---|" * len(factors),
        ]
        for i, vo in enumerate(vos):
            md.append(
                f"| {vo} | " + " | ".join(f"{m[metric]['compression'][i, k]:.4f}" for k in range(len(factors))) + " |"
            )
        md.append("")
    md += ["## Figures", ""] + [f"![{t}]({p})" for t, p in imgs]
    md_path = atomic_write_text(run / "report.md", "\n".join(md) + "\n")
    body = "".join(f"<h3>{html.escape(t)}</h3><img src='{p}'>" for t, p in imgs)
    items = "".join(f"<li>{html.escape(a).replace('**', '')}</li>" for a in ans)
    doc = (
        f"<!doctype html><html><head><meta charset='utf-8'><title>VO evaluation</title>"
        "<style>body{font-family:system-ui;max-width:1100px;margin:2em auto}img{max-width:100%}</style></head>"
        f"<body><h1>Visual-odometer evaluation</h1><p>{len(results)} cells: {', '.join(vos)} × "
        f"{', '.join(scenes)} × {', '.join(levels)}.</p><h2>Which VO for my application</h2><ul>{items}</ul>"
        f"{body}<h2>Data</h2><p>Cells: <code>results/VO/SCENE__LEVEL.json</code>; matrices: "
        "<code>matrices.json</code>.</p></body></html>"
    )
    html_path = atomic_write_text(run / "report.html", doc)
    dump = {
        "vos": vos,
        "scenes": scenes,
        "levels": levels,
        "factors": factors,
        "absolute": {k: v.tolist() for k, v in absolute.items()},
        "factor_matrices": {k: {kk: np.asarray(vv).tolist() for kk, vv in m[k].items()} for k in METRICS},
        "answers": ans,
    }
    atomic_write_text(run / "matrices.json", json.dumps(dump, indent=1, default=lambda x: None))
    return html_path, md_path
