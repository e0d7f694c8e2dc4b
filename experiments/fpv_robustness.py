"""Thesis §10.1.2 / Fig. 10.4: robustness of VE and SVE to imperceptible changes of a motion.

Base motion: a sine of amplitude A (1–20°), period 20 frames, 12 periods, scored as a yaw motion
of a 1080p video (f = 830 px, viewing distance d = 3240 px, so d/f = 3.9), MAR 0.02°. Three
operators make motions a viewer cannot tell apart from the base: flipping (left-right and
upside-down), adding Gaussian noise of standard deviation MAR·d/(12 f) (eq. 10.4), and adding a
slope (the same noise accumulated, a drift). For each amplitude, r = 100 trials; the error is
e = mean |M(θ_syn) - M(θ)| / M(θ) · 100 % (eq. 10.2).

Writes docs/figures/fpv_robustness.png and .json.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from egovid.fpv.perception.intervals import yaw_pitch_intervals
from egovid.fpv.perception.model import ViewingModel
from egovid.fpv.perception.score import rms
from egovid.fpv.perception.ve import sve_windows, ve_windows

OUT = Path(__file__).resolve().parent.parent / "docs" / "figures"
F, D, MAR = 830.0, 3240.0, 0.02
HFOV = 2 * math.degrees(math.atan(960 / F))
PERIOD, PERIODS, TRIALS = 20, 12, 100


def score(theta: np.ndarray, model: ViewingModel, method: str) -> float:
    iv = yaw_pitch_intervals(theta, HFOV, model.d_over_f, model.pe_threshold(30.0))
    iv += theta[: len(iv), None]
    if method == "ve":
        return rms(ve_windows(iv[:, 0], iv[:, 1], HFOV, model.window_frames, model.saccade_frames))
    return rms(sve_windows(iv[:, 0], iv[:, 1], HFOV, model.window_frames))


def main() -> dict:
    model = ViewingModel(d_over_f=D / F, mar_deg=MAR)
    sigma = MAR * D / (12 * F)  # eq. 10.4
    n = np.arange(PERIOD * PERIODS)
    amps = np.arange(1, 21)
    rng = np.random.default_rng(0)
    result = {"amplitudes": amps.tolist(), "sigma_deg": sigma, "trials": TRIALS}
    for method in ("ve", "sve"):
        errs = {"flip_lr": [], "flip_ud": [], "noise": [], "slope": [], "base": []}
        for A in amps:
            base = A * np.sin(2 * np.pi * n / PERIOD)
            m0 = score(base, model, method)
            errs["base"].append(m0)

            def e(m: float, m0: float = m0) -> float:
                return abs(m - m0) / m0 * 100.0

            errs["flip_lr"].append(e(score(base[::-1].copy(), model, method)))
            errs["flip_ud"].append(e(score(-base, model, method)))
            noise, slope = [], []
            for _ in range(TRIALS):
                noise.append(e(score(base + rng.normal(0, sigma, len(base)), model, method)))
                slope.append(e(score(base + np.cumsum(rng.normal(0, sigma, len(base))), model, method)))
            errs["noise"].append(float(np.mean(noise)))
            errs["slope"].append(float(np.mean(slope)))
        result[method] = errs
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4), sharey=False)
    for ax, op in zip(axes, ("flip_lr", "noise", "slope"), strict=True):
        for method, style in (("ve", "-o"), ("sve", "--s")):
            ax.plot(amps, result[method][op], style, ms=3, label=method.upper())
        if op == "flip_lr":
            ax.plot(amps, result["ve"]["flip_ud"], ":", label="VE upside-down")
        ax.set_title({"flip_lr": "flipping", "noise": "adding noise (eq. 10.4)", "slope": "adding slope"}[op])
        ax.set_xlabel("sine amplitude (°)")
        ax.set_ylabel("error e (%)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Robustness of VE and SVE (thesis Fig. 10.4 set-up)")
    fig.tight_layout()
    OUT.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT / "fpv_robustness.png", dpi=110)
    (OUT / "fpv_robustness.json").write_text(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    r = main()
    for method in ("ve", "sve"):
        print(method, "base M:", np.round(r[method]["base"], 3).tolist())
        for op in ("flip_lr", "flip_ud", "noise", "slope"):
            print(f"  {op:8s}", np.round(r[method][op], 2).tolist())
