"""egovid's stabiliser against vid.stab and Gyroflow's method on the test bed (egovid.synth.testbed).

For every case (intended motion + known shake, rendered with its truth; see the module), in the
same run and on the same rendered input:

* **egovid**: ``stabilize_video()`` with its defaults (what ``fpv stabilize`` runs: the thesis'
  plan and the visible-shake layer below it); motion from vision, or ``--gyro`` from the case's
  gyro (the true orientation sampled at 200 Hz, which is what a synced camera gyro gives) where
  the case has one; **egovid-plan**: the same with ``visible=False`` (the thesis' plan alone);
* **vid.stab**: ffmpeg's two passes as a user runs them (detect defaults, smoothing 15, optimal
  static zoom, borders kept);
* **Gyroflow's method** (cases with a gyro): its Default smoothing (smoothness 0.5) of the gyro
  orientation, envelope-follower adaptive zoom (4 s, limit 130 %), per-row rolling-shutter
  correction (:mod:`egovid.fpv.stabilize.gyroflow_peer`).

Measured on each decoded output the same way:

* **jitter**: ``../shared/tools/shake.py INPUT OUTPUT`` itself (the acceptance measure), x + y, and
  its zoom;
* **VE** and **FPMI kept**: motion re-estimated from the decoded output
  (``estimate_motion``, scored by ``motion_scores``; 2D-VE and ITF are not needed here);
  FPMI kept = (1 - pure-FPM VE after) / (1 - pure-FPM VE before) against the input as measured,
  and against the truth's intended motion
  (``fpmi_vs_truth``; n/a where the intended motion carries almost none: 1 - VE < ``FPMI_NONE``, 0.05);
* **truth ceiling**: the jitter shake.py's formula gives the intended motion itself (from the
  truth angles, small-angle image path): what "keep the intended motion exactly" costs.

Targets (issue 31, per case): egovid's jitter <= 0.9 x vid.stab's at zoom <= 1.10, FPMI kept >= 90 %.
Run: ``python benchmarks/stabilize_testbed.py [--case NAME ...] [--seconds S] [--gyro]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from egovid.core.motion.estimate import estimate_motion
from egovid.core.motion.source import camera_motion
from egovid.fpv.stabilize.gyroflow_peer import plan_gyroflow, run_gyroflow
from egovid.fpv.stabilize.measure import FPMI_NONE, motion_scores
from egovid.fpv.stabilize.run import stabilize_video
from egovid.fpv.stabilize.vidstab import run_vidstab
from egovid.synth.testbed import CaseTruth, default_cases, render_case

from _common import ROOT, cache_dir, report

SHAKE = ROOT.parent / "shared" / "tools" / "shake.py"


def shake(original: Path, output: Path) -> dict:
    """shake.py's JSON line for ``output`` against ``original``."""
    r = subprocess.run([sys.executable, str(SHAKE), str(original), str(output)], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"shake.py failed: {r.stderr[-300:]}")
    d = json.loads(r.stdout.strip().splitlines()[-1])
    d["jitter"] = round(d["jitter_x"] + d["jitter_y"], 3)
    return d


def truth_ceiling(truth: CaseTruth) -> float:
    """shake.py's jitter formula (x + y) on the intended motion's small-angle image path."""
    c = truth.case
    f = c.intrinsics().focal * 480.0 / c.width
    a = np.radians(truth.intended)
    p = np.stack([f * a[:, 0], -f * a[:, 1]], axis=1)
    k = 15
    pad = np.pad(p, ((k // 2, k // 2), (0, 0)), mode="edge")
    ma = np.array([pad[i : i + k].mean(0) for i in range(len(p))])
    return float(np.sqrt(np.mean((p - ma) ** 2, axis=0)).sum())


def scores_of(video: Path, intr, fps: float):
    """VE, SVE and pure-FPM VE of ``video``'s motion re-estimated from its decoded pixels."""
    traj = estimate_motion(video, intr).trajectory
    return motion_scores(traj.euler(), fps, intr, times=traj.times)


def _fpmi(before: float, after: float) -> float:
    lost = 1.0 - before
    return (1.0 - after) / lost if lost > 1e-9 else float("nan")


def bench_case(case, folder: Path, use_gyro: bool) -> dict:
    src = folder / f"{case.name}.mp4"
    truth = render_case(case, src)
    intr = case.intrinsics()
    row: dict = {"case": case.name, "fps": case.fps, "size": f"{case.width}x{case.height}", "rotation": case.rotation}
    row["input"] = shake(src, src)
    row["truth_ceiling_jitter"] = round(truth_ceiling(truth), 3)
    before = scores_of(src, intr, case.fps)
    intended = motion_scores(truth.intended, case.fps, intr)
    row["ve_input"] = round(before.ve, 4)
    outs: dict[str, Path] = {}
    seconds: dict[str, float] = {}

    # The gyro path: the true orientation at the frame centres (a synced gyro, no vision).
    motion = truth.trajectory() if use_gyro and truth.gyro is not None else None
    t = time.perf_counter()
    if motion is None:  # what `fpv stabilize` estimates, once for both egovid variants
        motion = camera_motion(src, "auto", focal=intr.focal).trajectory
    t_motion = time.perf_counter() - t
    for name, visible in (("egovid", True), ("egovid-plan", False)):
        outs[name] = folder / f"{case.name}.{name}.mp4"
        t = time.perf_counter()
        res = stabilize_video(
            src, outs[name], motion=motion, focal=intr.focal, max_zoom=1.10, visible=visible, measure=False
        )
        seconds[name] = time.perf_counter() - t + t_motion
        if visible:
            row["visible_cutoff_hz"] = res.visible.cutoff_hz if res.visible else None
            row["egovid_zoom_max_planned"] = round(float(np.max(1 / res.keep)), 3)
    outs["vidstab"] = folder / f"{case.name}.vidstab.mp4"
    seconds["vidstab"] = run_vidstab(src, outs["vidstab"], folder / "work", defaults=True).seconds
    if truth.gyro is not None:
        outs["gyroflow"] = folder / f"{case.name}.gyroflow.mp4"
        t = time.perf_counter()
        g = truth.gyro
        plan = plan_gyroflow(
            g.times, g.R, truth.times, intr, case.fps, readout_s=case.readout_s, rotation=case.rotation
        )
        run_gyroflow(src, outs["gyroflow"], plan, intr, rotation=case.rotation)
        seconds["gyroflow"] = time.perf_counter() - t
    for name, out in outs.items():
        m = scores_of(out, intr, case.fps)
        d = shake(src, out)
        fv = _fpmi(intended.pure_fpm_ve, m.pure_fpm_ve) if 1 - intended.pure_fpm_ve >= FPMI_NONE else None
        row[name] = {
            **d,
            "ve": round(m.ve, 4),
            "fpmi_kept": round(_fpmi(before.pure_fpm_ve, m.pure_fpm_ve), 3),
            "fpmi_vs_truth": None if fv is None else round(fv, 3),
            "seconds": round(seconds[name], 2),
        }
    if "egovid" in row and "vidstab" in row:
        row["egovid_plan_jitter_over_vidstab"] = round(
            row["egovid-plan"]["jitter"] / max(row["vidstab"]["jitter"], 1e-9), 3
        )
        e, v = row["egovid"], row["vidstab"]
        fp = e["fpmi_vs_truth"] if e["fpmi_vs_truth"] is not None else e["fpmi_kept"]
        row["egovid_jitter_over_vidstab"] = round(e["jitter"] / max(v["jitter"], 1e-9), 3)
        row["targets_met"] = {
            "jitter_le_0.9_vidstab": e["jitter"] <= 0.9 * v["jitter"],
            "zoom_le_1.10": e["zoom"] <= 1.10 + 1e-3,
            "fpmi_ge_90": fp >= 0.9,
        }
    return row


def table(rows: list[dict]) -> str:
    head = "| case | input jitter | truth ceiling | egovid jitter / zoom / FPMI (truth) / VE | egovid-plan |"
    head += " vid.stab | Gyroflow | egovid ÷ vid.stab |"
    lines = [head, "|" + " --- |" * 8]
    for r in rows:

        def cell(k: str, r: dict = r) -> str:
            if k not in r:
                return "–"
            d = r[k]
            ft = "n/a" if d["fpmi_vs_truth"] is None else f"{100 * d['fpmi_vs_truth']:.0f} %"
            return f"{d['jitter']:.3f} / {d['zoom']:.3f} / {100 * d['fpmi_kept']:.0f} % ({ft}) / {d['ve']:.3f}"

        lines.append(
            f"| {r['case']} | {r['input']['jitter']:.3f} | {r['truth_ceiling_jitter']:.3f} | {cell('egovid')} | "
            f"{cell('egovid-plan')} | "
            f"{cell('vidstab')} | {cell('gyroflow')} | {r.get('egovid_jitter_over_vidstab', float('nan')):.2f} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", action="append", help="only these cases (names from egovid.synth.testbed)")
    ap.add_argument("--seconds", type=float, default=None, help="shorten every case to this many seconds")
    ap.add_argument("--gyro", action="store_true", help="egovid takes the case's gyro as its motion where it has one")
    ap.add_argument("--table", action="store_true", help="print the table of the latest stored result of every case")
    ap.add_argument("--since", default="", help="with --table: only results stored at or after this time (ISO)")
    args = ap.parse_args()
    if args.table:
        from _common import CACHE

        latest: dict[str, dict] = {}
        for line in (CACHE / "results.jsonl").read_text().splitlines():
            r = json.loads(line)
            if r["benchmark"].startswith("stabilize_testbed/") and "egovid-plan" in r and r["time"] >= args.since:
                latest[r["case"]] = r
        order = [c.name for c in default_cases()]
        print(table([latest[n] for n in order if n in latest]))
        return
    folder = cache_dir("stabilize_testbed")
    rows = []
    for case in default_cases():
        if args.case and case.name not in args.case:
            continue
        if args.seconds:
            case = replace(case, seconds=args.seconds)
        row = bench_case(case, folder, args.gyro)
        report(f"stabilize_testbed/{case.name}", row)
        rows.append(row)
    print(table(rows))


if __name__ == "__main__":
    main()
