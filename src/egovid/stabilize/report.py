"""Self-contained HTML report of a stabilisation run (plots embedded as PNG data URIs)."""

from __future__ import annotations

import base64
import html
import io
import os
from pathlib import Path

import numpy as np

from egovid.io.files import atomic_write_text
from egovid.perception.score import score_angles
from egovid.plots import AXES, plt
from egovid.stabilize.pipeline import StabilizeResult


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _angles_figure(res: StabilizeResult) -> str:
    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    t = res.times
    for k, ax in enumerate(axes):
        ax.plot(t, res.original[:, k], color="0.55", lw=1.0, label="original")
        ax.plot(t, res.edited[:, k], color="C0", lw=1.6, label="stabilised")
        plan = res.plans.get(AXES[k])
        if plan is not None:
            ax.plot(t[plan.anchors], plan.anchor_values, "o", ms=3, color="C3", label="motion anchors")
            ax.plot(t[plan.anchors], plan.new_anchor_values, "o", ms=3, mfc="none", color="C0", label="reduced anchors")
        ax.set_ylabel(f"{AXES[k]} (°)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=4)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title("Camera rotation before and after")
    return _png(fig)


def _ve_figure(res: StabilizeResult, hfov: float, vfov: float, fps: float) -> str:
    before = score_angles(res.original, fps, hfov, vfov)
    after = score_angles(res.edited, fps, hfov, vfov)
    fig, ax = plt.subplots(figsize=(10, 3))
    ax.plot(before.window_times, before.combined, color="0.55", label=f"original (VE {before.score:.3f})")
    ax.plot(after.window_times, after.combined, color="C0", label=f"stabilised (VE {after.score:.3f})")
    ax.set_ylim(-0.02, 1.02)
    ax.set_ylabel("VE per window")
    ax.set_xlabel("window start (s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


def write_report(
    path: str | os.PathLike, res: StabilizeResult, source: str, hfov: float, vfov: float, fps: float
) -> Path:
    """Write the HTML report of ``res`` to ``path`` (atomically)."""
    s = res.summary()
    rows = [
        ("Viewing experience VE (1 = every frame can be pursued)", f"{s['ve_before']:.3f}", f"{s['ve_after']:.3f}"),
        (
            "VE of the pure FPM (lower = more first-person motion information)",
            f"{s['pure_fpm_ve_before']:.3f}",
            f"{s['pure_fpm_ve_after']:.3f}",
        ),
        ("Masked ITF (dB, higher = steadier)", f"{s['itf_before_db']:.2f}", f"{s['itf_after_db']:.2f}"),
        ("Share of black (uncovered) pixels", "0 %", f"{100 * s['black_share']:.2f} %"),
    ]
    amp = [(AXES[k], float(np.ptp(res.original[:, k])), float(np.ptp(res.edited[:, k]))) for k in range(3)]
    table = "\n".join(f"<tr><td>{html.escape(a)}</td><td>{b}</td><td>{c}</td></tr>" for a, b, c in rows)
    amp_rows = "\n".join(f"<tr><td>{a}</td><td>{b:.2f}°</td><td>{c:.2f}°</td></tr>" for a, b, c in amp)
    params = "".join(f"<li>{html.escape(str(k))}: {html.escape(str(v))}</li>" for k, v in s["params"].items())
    secs = s["seconds"]
    doc = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>egovid stabilisation report</title>
<style>body{{font-family:system-ui,sans-serif;max-width:1000px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #ccc;padding:4px 10px;text-align:right}}
td:first-child,th:first-child{{text-align:left}}img{{max-width:100%}}</style></head><body>
<h1>Stabilisation report</h1>
<p>Input <code>{html.escape(source)}</code> → output <code>{html.escape(s["output"])}</code>,
{s["frames"]} frames. Shake removed while keeping the first-person motion (thesis ch. 9):
anchors of the motion were reduced and re-eased to maximise VE minus the VE of the pure FPM.</p>
<table><tr><th>measure</th><th>before</th><th>after</th></tr>{table}
<tr><td>First-person motion information kept</td><td></td><td>{100 * s["fpmi_retention"]:.1f} %</td></tr>
<tr><td>Crop (fraction of the frame kept, then scaled back)</td><td></td><td>{s["crop_factor"]:.3f}</td></tr>
</table>
<h2>Motion range per axis</h2>
<table><tr><th>axis</th><th>before</th><th>after</th></tr>{amp_rows}</table>
<img src="{_angles_figure(res)}" alt="angles">
<img src="{_ve_figure(res, hfov, vfov, fps)}" alt="VE">
<h2>Run</h2><p>{s["fps_end_to_end"]:.1f} frames/s end to end: motion {secs["motion"]:.1f} s,
optimisation {secs["optimise"]:.1f} s, rendering {secs["render"]:.1f} s.</p><ul>{params}</ul>
</body></html>
"""
    return atomic_write_text(path, doc)
