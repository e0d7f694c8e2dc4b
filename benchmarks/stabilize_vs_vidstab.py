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
"""

from __future__ import annotations

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

from _common import cache_dir, report


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


if __name__ == "__main__":
    main()
