"""Self-contained HTML report of a stabilisation run (plots and thumbnails embedded as PNG data
URIs): planned and measured scores side by side, the motion before and after, the zoom over time,
VE per window, and frames of the input and the output at the same moments."""

from __future__ import annotations

import base64
import html
import io
import os
from pathlib import Path

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.files import atomic_write_text
from egovid.core.plots import AXES, plt
from egovid.core.video import iter_frames
from egovid.fpv.perception.score import score_angles
from egovid.fpv.stabilize.pipeline import StabilizeResult


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _angles_figure(res: StabilizeResult) -> str:
    fig, axes = plt.subplots(4, 1, figsize=(10, 8.5), sharex=True, gridspec_kw={"height_ratios": [3, 3, 3, 1.6]})
    t = res.times
    for k, ax in enumerate(axes[:3]):
        ax.plot(t, res.original[:, k], color="0.55", lw=1.0, label="recorded")
        ax.plot(t, res.plan[:, k], color="C1", lw=1.0, ls="--", label="planned (thesis ch. 9)")
        ax.plot(t, res.path[:, k], color="C0", lw=1.6, label="rendered (within the crop)")
        ax.set_ylabel(f"{AXES[k]} (°)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[3].plot(t, 1.0 / res.keep, color="C2")
    axes[3].set_ylabel("zoom")
    axes[3].grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title("Camera rotation and zoom")
    return _png(fig)


def _ve_figure(res: StabilizeResult, intr: Intrinsics, fps: float) -> str:
    h, v = intr.hfov_deg, intr.vfov_deg
    curves = [("recorded", res.original, "0.55"), ("planned", res.path, "C1")]
    if res.after is not None and res.after.motion is not None:
        curves.append(("measured on the output", res.after.motion, "C0"))
    fig, ax = plt.subplots(figsize=(10, 3))
    for name, angles, colour in curves:
        s = score_angles(angles, fps, h, v)
        ax.plot(s.window_times, s.combined, color=colour, label=f"{name} (VE {s.score:.3f})")
    ax.set_ylim(-0.02, 1.02)
    ax.set_ylabel("VE per window")
    ax.set_xlabel("window start (s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


def _thumbnails(source: str, output: str, n_frames: int, count: int = 3, width: int = 320) -> list[tuple[int, str]]:
    """(frame, data URI) of input | output side by side at ``count`` moments."""
    picks = sorted({round(float(x)) for x in np.linspace(0.15, 0.85, count) * (n_frames - 1)})

    def grab(path: str) -> dict[int, np.ndarray]:
        got: dict[int, np.ndarray] = {}
        for f in iter_frames(path, max_frames=picks[-1] + 1):
            if f.index in picks:
                img = f.image
                got[f.index] = cv2.resize(
                    img, (width, round(img.shape[0] * width / img.shape[1])), interpolation=cv2.INTER_AREA
                )
        return got

    a, b = grab(source), grab(output)
    out = []
    for k in picks:
        if k in a and k in b:
            gap = np.full((a[k].shape[0], 6, 3), 255, np.uint8)
            ok, png = cv2.imencode(".png", np.hstack([a[k], gap, b[k]]))
            if ok:
                out.append((k, "data:image/png;base64," + base64.b64encode(png.tobytes()).decode()))
    return out


def _scores_rows(s: dict) -> str:
    """The HTML rows of the planned and measured scores of a run's summary ``s``."""
    pb, pa = s["planned"]["before"], s["planned"]["after"]
    mb = s.get("measured", {}).get("before", {})
    ma = s.get("measured", {}).get("after", {})

    def f(x, fmt=".3f") -> str:
        return "" if x is None else format(x, fmt)

    rows = [  # (label, key, format, planned too)
        ("Viewing experience VE (1 = every frame can be pursued)", "ve", ".3f", True),
        ("Structure VE (SVE)", "sve", ".3f", True),
        ("VE of the pure FPM (lower = more first-person motion)", "pure_fpm_ve", ".3f", True),
        ("2D-VE (optical flow)", "ve2d", ".3f", False),
        ("ITF (dB, higher = steadier)", "itf_db", ".2f", False),
        ("High-frequency jitter (px at 480 px width, above 3 Hz)", "jitter_px", ".3f", False),
        ("Visible shake (px at 480 px width, as shake.py: path minus its 15-frame mean)", "shake_px", ".3f", False),
    ]
    cells = [
        (name, pb.get(key) if planned else None, pa.get(key) if planned else None, mb.get(key), ma.get(key), fm)
        for name, key, fm, planned in rows
    ]
    return "\n".join(
        f"<tr><td>{html.escape(name)}</td>" + "".join(f"<td>{f(x, fm)}</td>" for x in (a, b, c, d)) + "</tr>"
        for name, a, b, c, d, fm in cells
    )


def write_report(path: str | os.PathLike, res: StabilizeResult, source: str, intr: Intrinsics, fps: float) -> Path:
    """Write the HTML report of ``res`` to ``path`` (atomically)."""
    s = res.summary()
    ma = s.get("measured", {}).get("after", {})
    table = _scores_rows(s)
    kept_meas = s.get("fpmi_retention_measured")
    thumbs = "".join(
        f'<figure><img src="{uri}" alt="frame {k}"><figcaption>frame {k}: input | output</figcaption></figure>'
        for k, uri in _thumbnails(source, s["output"], s["frames"])
    )
    params = "".join(f"<li>{html.escape(str(k))}: {html.escape(str(v))}</li>" for k, v in s["params"].items())
    kept = "".join(f"<li>{html.escape(x)}</li>" for x in s["kept_from_input"]) or "<li>nothing to keep</li>"
    dropped = "".join(f"<li>{html.escape(x)}</li>" for x in s["not_kept"])
    notes = "".join(f"<li>{html.escape(x)}</li>" for x in [*s.get("warnings", []), *s["notes"]])
    secs = res.seconds
    measured_note = (
        ""
        if ma
        else "<p><b>Not measured</b> (run without <code>--no-measure</code> to decode the output and measure it).</p>"
    )
    doc = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>egovid stabilisation report</title>
<style>body{{font-family:system-ui,sans-serif;max-width:1000px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #ccc;padding:4px 10px;text-align:right}}
td:first-child,th:first-child{{text-align:left}}img{{max-width:100%}}figure{{margin:0.5em 0}}</style></head><body>
<h1>Stabilisation report</h1>
<p>Input <code>{html.escape(source)}</code> → output <code>{html.escape(s["output"])}</code>,
{s["frames"]} frames. Shake removed while keeping the first-person motion (thesis ch. 9): the
motion's anchors were reduced and re-eased to maximise VE minus the VE of the pure FPM, and the
path was then bent into what a zoom of at most {s["params"].get("max_zoom") or 1:g}x covers.
<b>Planned</b> scores are those of the rendered path; <b>measured</b> ones come from decoding
the input and the output and estimating their motion again.</p>{measured_note}
<table><tr><th>measure</th><th>planned: recorded motion</th><th>planned: rendered path</th>
<th>measured: input</th><th>measured: output</th></tr>{table}
<tr><td>First-person motion information kept</td><td></td><td>{100 * s["fpmi_retention_planned"]:.1f} %</td>
<td></td><td>{"" if kept_meas is None else f"{100 * kept_meas:.1f} %"}</td></tr>
<tr><td>Zoom (mean / largest)</td><td></td><td>{s["zoom"]["mean"]:.3f} / {s["zoom"]["max"]:.3f}</td>
<td></td><td></td></tr>
<tr><td>Share of black (uncovered) pixels</td><td></td><td>{100 * s["black_share"]:.2f} %</td><td></td><td></td></tr>
</table>
<img src="{_angles_figure(res)}" alt="angles and zoom">
<img src="{_ve_figure(res, intr, fps)}" alt="VE per window">
<h2>Input and output</h2>{thumbs}
<h2>Kept from the input</h2><ul>{kept}</ul>{"<h3>Not kept</h3><ul>" + dropped + "</ul>" if dropped else ""}
{"<h2>Notes</h2><ul>" + notes + "</ul>" if notes else ""}
<h2>Run</h2><p>motion {secs["motion"]:.1f} s, plan and path {secs["plan"]:.1f} s, rendering
{secs["render"]:.1f} s, measuring {secs["measure"]:.1f} s.</p><ul>{params}</ul>
</body></html>
"""
    return atomic_write_text(path, doc)
