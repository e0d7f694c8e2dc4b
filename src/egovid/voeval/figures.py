"""Figures of the evaluation report: factor heatmaps and per-scene rotation plots (PNG)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egovid.core.plots import plt, save
from egovid.core.trajectory import Trajectory, read_tum
from egovid.voeval.layout import cell_path, scene_dir
from egovid.voeval.matrices import METRICS
from egovid.voeval.results import RunResults
from egovid.voeval.scenes import SceneTruth


def heatmap(
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


def rotation_figure(path: Path, times: np.ndarray, reference: np.ndarray, curves: dict, title: str) -> Path:
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
        path = rotation_figure(figs / f"rotation_{s}.png", truth.times, ref, curves, title)
        imgs.append((f"Rotation, {s}", f"figures/{path.name}"))
    return imgs


def factor_heatmaps(m: dict, run: RunResults, figs: Path) -> list[tuple[str, str]]:
    """Relative (eq. 22.2-22.4) and absolute (eq. 22.5-22.6) influence heatmaps of every metric
    and source at the run's first level; returns (title, relative path) per figure."""
    imgs = []
    for metric in METRICS:
        for src in dict.fromkeys(f.source for f in run.factors):
            idx = [k for k, f in enumerate(run.factors) if f.source == src]
            cols = [run.factors[k].name for k in idx]
            tag = f"{metric}_{src}".replace("/", "-")
            for kind, eq in (("relative", "22.2-22.4"), ("absolute", "22.5-22.6")):
                title = f"{kind.capitalize()} influence on {metric}, {src} (eq. {eq}), {run.levels[0]}"
                heatmap(figs / f"{kind}_{tag}.png", m[metric][kind][:, idx, 0], run.vos, cols, title, cmap="magma")
                imgs.append(
                    (f"{kind.capitalize()} influence of factors on {metric} — {src}", f"figures/{kind}_{tag}.png")
                )
    return imgs
