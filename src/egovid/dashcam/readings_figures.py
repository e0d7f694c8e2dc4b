"""Figures of a drive's recorded readings (``egovid dashcam report --figures``): speed and
accelerations over time, one PNG per drive (:mod:`egovid.dashcam.readings` makes and writes the
readings themselves; this module alone loads Matplotlib).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from egovid.core.plots import plt, save
from egovid.dashcam.archive import readings as table
from egovid.dashcam.archive.readings import DriveReadings
from egovid.dashcam.archive.store import Archive


def plot_readings(r: DriveReadings, path: str | os.PathLike, title: str = "") -> Path:
    """Speed (km/h, brake applied shaded), acceleration along the car's front/back and left/right
    axes, and along its up/down axis (m/s²) against seconds into the drive, one panel each, as a PNG."""
    ch = r.channels
    fig, axes = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True, height_ratios=(2, 2, 1))
    ax = axes[0]
    if "speed_mps" in ch:
        ax.plot(r.t, ch["speed_mps"] * 3.6, color="k", lw=1.2, label="speed")
    if "brake" in ch and np.nansum(ch["brake"]) > 0:
        ax.fill_between(r.t, 0, 1, where=ch["brake"] > 0.5, transform=ax.get_xaxis_transform(), color="tab:red",
                        alpha=0.15, step="mid", label="brake")  # fmt: skip
        ax.legend(loc="upper right", fontsize=8)
    ax.set_ylabel("speed (km/h)")
    for name, label in (("accel_x", "x (front/back)"), ("accel_y", "y (left/right)")):
        if name in ch:
            axes[1].plot(r.t, ch[name], lw=1.0, label=label)
    axes[1].axhline(0, color="0.5", lw=0.6)
    axes[1].set_ylabel("acceleration (m/s²)")
    axes[1].legend(loc="upper right", fontsize=8)
    if "accel_z" in ch:
        axes[2].plot(r.t, ch["accel_z"], lw=1.0, color="tab:green", label="z (up/down)")
        axes[2].legend(loc="upper right", fontsize=8)
    axes[2].set_ylabel("m/s²")
    axes[2].set_xlabel("time into the drive (s)")
    for a in axes:
        a.grid(alpha=0.3)
    axes[0].set_title(title or f"recorded readings ({r.source})")
    return save(fig, path)


def figure_name(drive_name: str) -> str:
    """The file name of a drive's readings figure (characters unsafe in file names replaced)."""
    return re.sub(r"[^\w.-]", "_", drive_name) + "-readings.png"


def draw_report_figures(archive: Archive, folder: str | os.PathLike, drives: list) -> dict[str, Path]:
    """One figure per drive of ``drives`` (catalogue drives) that has readings, in ``folder``
    (created); drive name → the figure."""
    out: dict[str, Path] = {}
    have = table.summaries(archive.catalogue)
    folder = Path(folder)
    for d in drives:
        if d.id not in have:
            continue
        r = table.get(archive.catalogue, d.id)
        if r is None or not len(r):
            continue
        folder.mkdir(parents=True, exist_ok=True)
        out[d.name] = plot_readings(r, folder / figure_name(d.name), f"{d.name}: recorded readings ({r.source})")
    return out
