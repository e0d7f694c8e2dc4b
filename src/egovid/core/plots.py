"""Matplotlib figures (Agg backend, written to PNG), shared by the CLI and reports."""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from egovid.core.files import atomic_path

AXES = ("yaw", "pitch", "roll")


class _Pyplot:
    """``matplotlib.pyplot`` (Agg backend), imported on first use: importing it costs about a
    second, which every command that imports a module with a figure in it (``egovid fpv
    stabilize`` without ``--report``) would otherwise pay without drawing anything."""

    _module: Any = None

    def __getattr__(self, name: str) -> Any:
        if _Pyplot._module is None:
            importlib.import_module("matplotlib").use("Agg")
            _Pyplot._module = importlib.import_module("matplotlib.pyplot")
        return getattr(_Pyplot._module, name)


plt: Any = _Pyplot()


def save(fig, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Write ``fig`` to ``path`` atomically and close it."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=Path(path).suffix.lstrip(".") or "png")
    plt.close(fig)
    return Path(path)


def plot_angles(
    path: str | os.PathLike,
    times: np.ndarray,
    curves: dict[str, np.ndarray],
    title: str = "Camera rotation",
) -> Path:
    """Yaw, pitch and roll (degrees) against time for one or more labelled (N, 3) arrays."""
    fig, axes = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True)
    for label, angles in curves.items():
        for k, ax in enumerate(axes):
            ax.plot(times[: len(angles)], angles[:, k], label=label, lw=1.2)
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{AXES[k]} (°)")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title(title)
    if len(curves) > 1:
        axes[0].legend(loc="upper right", fontsize=8)
    return save(fig, path)


def plot_scores(path: str | os.PathLike, results: dict, title: str = "Viewing experience") -> Path:
    """Per-window score curves: one panel per method (VE, SVE: per axis and combined; 2D-VE)."""
    n = len(results)
    fig, axes = plt.subplots(n, 1, figsize=(9, 2.8 * n), squeeze=False)
    for ax, (name, res) in zip(axes[:, 0], results.items(), strict=True):
        if name == "ve2d":
            t = np.arange(len(res.segments)) / res.fps
            ax.plot(t, res.segments, color="k", lw=1.4, label=f"2D-VE per segment (RMS {res.score:.3f})")
        else:
            for axis, curve in res.per_axis.items():
                ax.plot(res.window_times, curve, lw=0.9, alpha=0.8, label=f"{axis} ({res.axis_scores[axis]:.3f})")
            ax.plot(res.window_times, res.combined, color="k", lw=1.6, label=f"min over axes (RMS {res.score:.3f})")
        ax.set_ylim(-0.02, 1.02)
        ax.set_ylabel(name.upper())
        ax.grid(alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=7)
    axes[-1, 0].set_xlabel("window start (s)")
    axes[0, 0].set_title(title)
    return save(fig, path)
