"""egovid's stabiliser against ffmpeg's vid.stab (two passes) on the same synthetic 720p clips.

Clips (1280x720, 300 frames, with ground truth): running (yaw 10°/pitch 2.5° sines, roll 1.5°,
shake, noise) and a 40° intentional pan with a running bob on top. Both stabilisers write H.264
(libx264 veryfast, CRF 18) without zoom (vid.stab optzoom=0, crop=black; egovid --borders black),
so that frames keep the same geometry; ITF is masked in both, from geometry: egovid's mask is the
warp of its homography, vid.stab's is obtained by running vidstabtransform with the same
transforms on an all-white clip. For each, measured on the decoded outputs: masked ITF before/after
and gain (dB), share of black pixels, VE of the output's motion (re-estimated from the output
video, same estimator for both), FPMI retention (1 - VE of the pure FPM, output over input), and
end-to-end frames per second: egovid's stabilisation (motion, plan, render; its own measuring
off) against vid.stab's two passes, in the same run, with the share of each egovid stage.
Targets: ITF gain >= vid.stab's, FPMI retention better, speed >= 1.0x vid.stab.

``--speed`` (issue 31's speed targets: >= 1.5x vid.stab's two passes end to end at 720p, real time
at 1080p30): the default command itself, ``egovid fpv stabilize IN -o OUT --no-measure`` in its own
process (motion from ``--source auto``, the plan, the visible-shake layer, crop with a dynamic zoom;
only the output's re-measuring off), against vid.stab's two passes with their defaults, on the
running clip at 1280x720 and 1920x1080, 30 fps (``--frames``, default 150), one after the other in
the same run; with the load average and the CPU time the hypervisor stole during each.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.rotations import matrix_from_euler
from egovid.core.video import count_frames, probe
from egovid.fpv.stabilize.measure import measure_video
from egovid.fpv.stabilize.pipeline import stabilize
from egovid.fpv.stabilize.render import content_masks, homographies
from egovid.fpv.stabilize.vidstab import run_vidstab
from egovid.synth import motions
from egovid.synth.fpv import render_fpv

from _common import ROOT, cache_dir, report, running_clip, stolen_seconds


def make_clips(folder: Path) -> dict[str, Path]:
    n = 300
    clips = {
        "running": motions.running(n, 10.0, 2.5, 24.0, 1.5) + motions.jitter(n, (0.1, 0.1, 0.1), seed=2),
        "pan40": motions.pan(n, 40.0, 0.2, 0.8) + motions.running(n, 3.0, 1.0, 20.0, 1.0) + motions.jitter(n, seed=4),
    }
    out = {}
    for name, angles in clips.items():
        p = folder / f"{name}.mp4"
        if not p.exists():
            render_fpv(p, angles, width=1280, height=720, noise_std=2.0, seed=7)
        out[name] = p
    return out


def main() -> None:
    folder = cache_dir("stabilize")
    for name, clip in make_clips(folder).items():
        info = probe(clip)
        intr = Intrinsics.default(info.width, info.height)
        n = count_frames(clip)
        vs_out = folder / f"{name}.vidstab.mp4"
        vs = run_vidstab(clip, vs_out, folder)
        eg_out = folder / f"{name}.egovid.mp4"
        t = time.perf_counter()
        res = stabilize(clip, eg_out, intrinsics=intr, borders="black", measure=False)
        eg_seconds = time.perf_counter() - t
        before = measure_video(clip, intr, motion=res.original)
        vs_m = measure_video(vs_out, intr, masks=lambda k, m=vs.masks: m[k])
        R = matrix_from_euler(*res.original.T)
        H = homographies(R, matrix_from_euler(*res.path.T), intr)
        eg_m = measure_video(eg_out, intr, masks=content_masks(H, res.keep, info.width, info.height))
        vs_black = float(np.mean([1 - m.mean() for m in vs.masks]))

        def retention(m, b=before) -> float:
            return (1 - m.pure_fpm_ve) / (1 - b.pure_fpm_ve) if b.pure_fpm_ve < 1 else 1.0

        pan = {}
        if name == "pan40":
            span = lambda a: float(a[-30:].mean() - a[:30].mean())  # noqa: E731
            pan = {"pan_span_in_deg": span(res.original[:, 0]), "pan_span_egovid_deg": span(res.path[:, 0])}
        stages = {k: v for k, v in res.seconds.items() if k != "measure"}
        report(
            f"stabilize_vs_vidstab/{name}",
            {
                "frames": n,
                "input": {"itf_db": before.itf_db, "ve": before.ve, "pure_fpm_ve": before.pure_fpm_ve},
                "vidstab": {
                    "itf_db": vs_m.itf_db,
                    "itf_gain_db": vs_m.itf_db - before.itf_db,
                    "black_share": vs_black,
                    "ve": vs_m.ve,
                    "pure_fpm_ve": vs_m.pure_fpm_ve,
                    "fpmi_retention": retention(vs_m),
                    "fps": n / vs.seconds,
                },
                "egovid": {
                    "itf_db": eg_m.itf_db,
                    "itf_gain_db": eg_m.itf_db - before.itf_db,
                    "black_share": res.render.black_share,
                    "ve": eg_m.ve,
                    "pure_fpm_ve": eg_m.pure_fpm_ve,
                    "fpmi_retention": retention(eg_m),
                    "fps": n / eg_seconds,
                    "stages_s": stages,
                    "stage_share": {k: v / stages["total"] for k, v in stages.items() if k != "total"},
                },
                "speed_ratio_egovid_over_vidstab": vs.seconds / eg_seconds,
                "targets_met": {
                    "itf_gain": eg_m.itf_db >= vs_m.itf_db,
                    "fpmi_retention": retention(eg_m) >= retention(vs_m),
                    "speed_ratio_1.0": eg_seconds <= vs.seconds,
                },
                **pan,
            },
        )


def speed(frames: int) -> None:
    """The default command against vid.stab's two passes at 720p and 1080p30 (module docstring)."""
    folder = cache_dir("stabilize-speed")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
    for w, h in ((1280, 720), (1920, 1080)):
        clip = running_clip(folder / f"running-{h}p-{frames}.mp4", n=frames, size=(w, h))
        n = count_frames(clip)
        load, steal0 = os.getloadavg()[0], stolen_seconds()
        vs = run_vidstab(clip, folder / f"{clip.stem}.vidstab.mp4", folder, defaults=True)
        steal1 = stolen_seconds()
        out = folder / f"{clip.stem}.egovid.mp4"
        cmd = [sys.executable, "-m", "egovid", "fpv", "stabilize", str(clip), "-o", str(out), "--no-measure"]
        t = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True, env=env)
        eg_seconds = time.perf_counter() - t
        steal2 = stolen_seconds()
        if r.returncode != 0:
            raise SystemExit(f"error: egovid fpv stabilize failed: {r.stderr.strip()[-300:]}")
        stolen = None if steal0 is None else {"vidstab": steal1 - steal0, "egovid": steal2 - steal1}
        report(
            f"stabilize_vs_vidstab/speed-{h}p",
            {
                "size": f"{w}x{h}",
                "frames": n,
                "fps_video": probe(clip).fps,
                "vidstab_s": vs.seconds,
                "vidstab_fps": n / vs.seconds,
                "egovid_s": eg_seconds,
                "egovid_fps": n / eg_seconds,
                "speed_ratio_egovid_over_vidstab": vs.seconds / eg_seconds,
                "load_1min_before": load,
                "load_1min_after": os.getloadavg()[0],
                "stolen_cpu_s": stolen,
                "egovid_console": r.stdout.strip().splitlines()[-4:],
            },
        )


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speed", action="store_true", help="the speed rows only (720p and 1080p30)")
    ap.add_argument("--frames", type=int, default=150, help="frames of the speed clips")
    args = ap.parse_args()
    if args.speed:
        speed(args.frames)
    else:
        main()
