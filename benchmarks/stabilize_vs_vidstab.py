"""egovid's stabiliser against ffmpeg's vid.stab (two passes) on the same synthetic clips.

Clips (1280x720, 300 frames, with ground truth): running (yaw 10°/pitch 2.5° sines, roll 1.5°,
shake, noise) and a 40° intentional pan with a running bob on top. Both stabilisers write H.264
(libx264 veryfast, CRF 18) without zoom (vid.stab optzoom=0, crop=black; egovid --borders black),
so that frames keep the same geometry; ITF is masked in both: egovid's mask is the warp of its
homography, vid.stab's is obtained by running vidstabtransform with the same transforms on an
all-white clip. For each, printed: masked ITF before/after and gain (dB), share of black pixels,
VE of the output's motion (re-estimated from the output video, same estimator for both), FPMI
retention (1 - VE of the pure FPM, output over input), and end-to-end frames per second of the two
passes. Targets: ITF gain >= vid.stab's, FPMI retention better, fps >= 0.5x vid.stab.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from egovid.io.camera import Intrinsics
from egovid.io.video import count_frames, iter_frames, probe
from egovid.metrics.itf import ITFAccumulator
from egovid.motion.estimate import estimate_motion
from egovid.perception.score import score_angles
from egovid.stabilize.pipeline import pure_motion, stabilize
from egovid.stabilize.vidstab import run_vidstab
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


def itf_of(video: Path, masks=None) -> float:
    acc = ITFAccumulator()
    for k, f in enumerate(iter_frames(video)):
        acc.add(f.image, None if masks is None else masks[k])
    return acc.value


def motion_scores(video: Path, intr: Intrinsics) -> tuple[float, float]:
    """(VE of the video's motion, VE of its pure FPM), motion re-estimated from the video."""
    e = estimate_motion(video, intr).trajectory.euler()
    return (
        score_angles(e, 30.0, intr.hfov_deg, intr.vfov_deg).score,
        score_angles(pure_motion(e), 30.0, intr.hfov_deg, intr.vfov_deg).score,
    )


def main() -> None:
    folder = cache_dir("stabilize")
    for name, clip in make_clips(folder).items():
        info = probe(clip)
        intr = Intrinsics.default(info.width, info.height)
        n = count_frames(clip)
        ve_in, pure_in = motion_scores(clip, intr)
        itf_in = itf_of(clip)
        vs_out = folder / f"{name}.vidstab.mp4"
        vs_seconds, vs_masks = run_vidstab(clip, vs_out, folder)
        vs_itf = itf_of(vs_out, vs_masks)
        vs_black = float(np.mean([1 - m.mean() for m in vs_masks]))
        vs_ve, vs_pure = motion_scores(vs_out, intr)
        eg_out = folder / f"{name}.egovid.mp4"
        t = time.perf_counter()
        res = stabilize(clip, eg_out, intrinsics=intr, borders="black")
        eg_seconds = time.perf_counter() - t
        eg_ve, eg_pure = motion_scores(eg_out, intr)

        def retention(pure_out: float, pure_in: float = pure_in) -> float:
            return (1 - pure_out) / (1 - pure_in) if pure_in < 1 else 1.0

        pan = {}
        if name == "pan40":
            a_in = res.original[:, 0]
            a_out = res.edited[:, 0]
            span = lambda a: float(a[-30:].mean() - a[:30].mean())  # noqa: E731
            pan = {"pan_span_in_deg": span(a_in), "pan_span_egovid_deg": span(a_out)}
        report(
            f"stabilize_vs_vidstab/{name}",
            {
                "frames": n,
                "input": {"itf_db": itf_in, "ve": ve_in, "pure_fpm_ve": pure_in},
                "vidstab": {
                    "itf_db": vs_itf,
                    "itf_gain_db": vs_itf - itf_in,
                    "black_share": vs_black,
                    "ve": vs_ve,
                    "pure_fpm_ve": vs_pure,
                    "fpmi_retention": retention(vs_pure),
                    "fps": n / vs_seconds,
                },
                "egovid": {
                    "itf_db": res.render.itf_after,
                    "itf_gain_db": res.render.itf_after - itf_in,
                    "black_share": res.render.black_share,
                    "ve": eg_ve,
                    "pure_fpm_ve": eg_pure,
                    "fpmi_retention": retention(eg_pure),
                    "fps": n / eg_seconds,
                    "stages_s": res.seconds,
                },
                "fps_ratio_egovid_over_vidstab": (n / eg_seconds) / (n / vs_seconds),
                "targets_met": {
                    "itf_gain": res.render.itf_after >= vs_itf,
                    "fpmi_retention": retention(eg_pure) >= retention(vs_pure),
                    "fps_ratio_0.5": (n / eg_seconds) >= 0.5 * (n / vs_seconds),
                },
                **pan,
            },
        )


if __name__ == "__main__":
    main()
