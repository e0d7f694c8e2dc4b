"""Thesis Fig. 9.3(b): VE of a pure zigzag motion and of its best eased version, amplitude 1–20°.

The pure motion is a zigzag of amplitude A (anchors at ±A), period 20 frames; its best eased
version uses the (k, s) of eq. 9.2 that maximise VE (eq. 9.8). Viewing distance over focal length
d/f = 6 as in the thesis' example; we also show d/f = 4. Writes docs/figures/fpv_zigzag.png/.json.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from egovid.fpv.perception.model import ViewingModel
from egovid.fpv.stabilize.lut import best_easing

OUT = Path(__file__).resolve().parent.parent / "docs" / "figures"


def main() -> dict:
    amps = np.arange(1, 21, dtype=float)
    res = {"amplitudes": amps.tolist(), "half_period": 10}
    for ratio in (6.0, 4.0):
        model = ViewingModel(d_over_f=ratio)
        rows = [best_easing(2 * a, 10, "yaw", model) for a in amps]
        res[f"d/f={ratio:g}"] = {
            "ve_pure": [r.ve_pure for r in rows],
            "ve_eased": [r.ve_eased for r in rows],
            "k": [r.k for r in rows],
            "s": [r.s for r in rows],
        }
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for ratio, style in (("6", "-"), ("4", "--")):
        r = res[f"d/f={ratio}"]
        ax.plot(amps, r["ve_eased"], style + "o", ms=3, label=f"optimal (eased) motion, d/f = {ratio}")
        ax.plot(amps, r["ve_pure"], style + "s", ms=3, label=f"pure motion (zigzag), d/f = {ratio}")
    ax.set_xlabel("motion amplitude (°)")
    ax.set_ylabel("VE")
    ax.set_ylim(0, 1.02)
    ax.set_title("VE of pure motions and their best eased versions (thesis Fig. 9.3b)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    OUT.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT / "fpv_zigzag.png", dpi=110)
    (OUT / "fpv_zigzag.json").write_text(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    r = main()
    for key in ("d/f=6", "d/f=4"):
        print(key, "pure ", np.round(r[key]["ve_pure"], 3).tolist())
        print(key, "eased", np.round(r[key]["ve_eased"], 3).tolist())
