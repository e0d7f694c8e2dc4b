"""Every camera's own metadata (issue 27): GPS of the real GoPro clips and of every generation's
layout, lens-profile intrinsics against the camera's gyro, and the rolling-shutter correction.

Figures printed:

* GPS: fixes read per file by egovid's GPMF reader, and whether telemetry-parser (independent)
  reads the same fixes; ExifTool's fixes paired in file order on the same files (the old pairing
  by ExifTool's copy numbers, now gone, found 0 of the HERO6 clip's 36: docs/dashcam.md);
* vision against the camera's gyro on the real GoPro clips (slope, r): with the lens profile the
  file's facts select (and its fisheye distortion), against the gyro-fitted pinhole (the peer,
  main's default when a gyro is recorded). Each row is judged against the gyro synced to that
  row's own vision (offset, axes and bias, as ``camera_motion`` does), and against the raw gyro
  (same offset and axes, the gyro's own bias from its samples alone: its parts at rest, none on
  either clip, so zero): on a short clip the synced bias also absorbed a constant rate error of
  vision (10 °/s of yaw on the HERO6 clip with the pinhole model of its fisheye lens; the sync
  now caps it at ``gyro.MAX_BIAS_DEG_S``), and reusing one row's bias for another made that row
  look worse than it is. The first row is the default route (``camera_motion(clip, "vision")``,
  camera resolved as ``egovid motion`` does with no flags);
* a synthetic rolling-shutter clip (30 ms readout at 30 fps, running shake): per-frame error of
  vision against the known truth, plain, and with the points moved to their frame's time with
  vision's own rates (two passes), against the global-shutter render of the same motion.

Run: ``python benchmarks/camera_metadata.py`` (a few minutes on 2 cores); ``--vision`` for the
real clips' vision rows only (about 3 minutes on 2 shared cores).
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from egovid.core.camera.gpmf import read_gpmf_gps
from egovid.core.camera.gps_check import compare, read_telemetry_parser_gps
from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.lens_profiles import find_profile
from egovid.core.motion import gyro
from egovid.core.motion.estimate import CONF_MEASURED, MotionOptions, collect_pairs, solve_motion
from egovid.core.motion.rolling_shutter import frame_rates, refit_pairs
from egovid.core.motion.source import camera_motion
from egovid.core.video import probe

from _common import cache_dir, report

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
GENERATIONS = ("hero5", "hero6", "hero7", "hero8", "hero9", "hero10", "hero11", "hero13", "max", "fusion")


def gps_figures() -> dict:
    import exiftool

    from egovid.core.camera.exif import RECORD_ARGS
    from egovid.dashcam.route.camera_gps import exiftool_records, exiftool_rows
    from egovid.dashcam.route.embedded import parse_gps_time
    from egovid.synth.gopro import write_gopro_clip

    files = [REAL / n for n in ("gopro-hero5-karma.mp4", "gopro-hero6-2s.mp4")]
    d = cache_dir("camera_metadata")
    for g in GENERATIONS:
        p = d / f"{g}.mp4"
        if not p.exists():
            write_gopro_clip(p, g, seconds=4, no_fix=(3,), no_precision=(1,))
        files.append(p)
    out = {}
    with exiftool.ExifToolHelper(common_args=["-n"]) as et:
        for f in files:
            gps = read_gpmf_gps(f)
            check = compare(gps, read_telemetry_parser_gps(f)) if gps is not None else None
            ordered = exiftool_rows(exiftool_records(et.execute(*RECORD_ARGS, str(f))), parse_gps_time)
            out[f.name] = {
                "gpmf_fixes": len(gps) if gps is not None else 0,
                "gpmf_layout": gps.layout if gps is not None else None,
                "telemetry_parser": check.to_dict() if check is not None else None,
                "exiftool_in_file_order_fixes": len(ordered.rows),
            }
    return out


def vision_figures() -> dict:
    out = {}
    clips = (("gopro-hero5-karma.mp4", "HERO5 Black", "M"), ("gopro-hero6-2s.mp4", "HERO6 Black", None))
    for name, model, lens in clips:
        clip = REAL / name
        t0 = time.perf_counter()
        vis = camera_motion(clip, "vision")
        seconds = time.perf_counter() - t0
        imu = vis.telemetry.imu
        info = probe(clip)
        found = find_profile(
            "GoPro", model, info.width, info.height, lens=lens, stabilized=False, fps=info.fps,
            focal_px=vis.camera.intrinsics.focal,
        )  # fmt: skip
        row = {"default_route": _cmp(vis.trajectory, vis.confidence, imu, vis.camera.intrinsics.focal)}
        row["default_route"].update(
            camera=vis.camera.source, lens=vis.camera.lens.describe(), seconds=round(seconds, 1),
            sync_bias_deg_s=np.degrees(vis.sync.bias).round(2).tolist() if vis.sync is not None else None,
        )  # fmt: skip
        row["profile"] = found.reason
        if found.match is not None:
            intr = Intrinsics.from_focal(info.width, info.height, found.match.fx)
            pairs = collect_pairs(clip, intr, MotionOptions(keep_matches=10**6))
            plain = solve_motion(pairs, intr)
            row["profile_pinhole"] = _cmp(plain.trajectory, plain.confidence, imu, intr.focal)
            fixed = solve_motion(refit_pairs(pairs, None, 0.0, distortion=found.match.distortion), intr)
            row["profile_fisheye"] = _cmp(fixed.trajectory, fixed.confidence, imu, intr.focal)
        out[name] = row
    return out


def _cmp(traj, confidence, imu, focal) -> dict:
    """Vision ``traj`` against the gyro synced to it, and against the raw gyro: the same offset
    and axes, with the gyro's own bias from its samples alone (its parts at rest,
    :func:`~egovid.voeval.gyro_reference.still_bias`; none on either clip, so zero), which vision's
    error cannot move."""
    from egovid.voeval.gyro_reference import still_bias

    weights = (confidence[1:] >= CONF_MEASURED).astype(float)
    sync = gyro.sync_gyro(gyro.integrate(imu), traj.times, gyro.frame_rates(traj.times, traj.R), weights)
    own, still_s = still_bias(imu.times, imu.gyro)
    out = {
        "focal_px": round(float(focal), 1),
        "gyro_bias_deg_s": np.degrees(sync.bias).round(2).tolist(),
        "gyro_own_bias_deg_s": np.degrees(own).round(2).tolist(),
        "gyro_still_s": round(still_s, 2),
    }
    for label, bias in (("synced", sync.bias), ("raw_gyro", own)):
        R_ref = gyro.frame_rotations(gyro.integrate(imu, bias=bias), replace(sync, bias=bias), traj.times)
        c = gyro.compare_rotations(traj.R, R_ref)
        out[label] = {"slope": round(c.ratio, 4), "r": round(c.r, 4), "rms_deg": round(c.rms_deg, 4)}
    return out


def rolling_figures(readout_s: float = 0.03) -> dict:
    from egovid.core.trajectory import read_motion_csv
    from egovid.synth.fpv import ground_truth_paths
    from egovid.synth.motions import jitter, running
    from egovid.synth.rolling import render_rolling_fpv

    n = 60
    angles = running(n, yaw_amp=6, pitch_amp=2, period=10) + jitter(n, (0.6, 0.6, 0.3), seed=3)
    intr = Intrinsics.default(640, 360)
    d = cache_dir("camera_metadata")
    out = {}
    for label, ro in (("global_shutter", 0.0), (f"rolling_{readout_s * 1000:g}ms", readout_s)):
        video = d / f"rs_{ro:g}.mp4"
        if not video.exists():
            render_rolling_fpv(video, angles, ro, intrinsics=intr)
        truth = read_motion_csv(ground_truth_paths(video)[0])
        pairs = collect_pairs(video, intr, MotionOptions(keep_matches=10**6, threshold_px=3.0))
        est = solve_motion(pairs, intr)
        out[label] = {"vision": _truth(est.trajectory.R, truth.R)}
        if ro:
            for k in (1, 2):
                est = solve_motion(refit_pairs(pairs, frame_rates(est.trajectory.R, pairs.times), ro), intr)
                out[label][f"corrected_pass_{k}"] = _truth(est.trajectory.R, truth.R)
    return out


def _truth(R, R_true) -> dict:
    c = gyro.compare_rotations(R, R_true)
    return {"r": round(c.r, 4), "r_axes": [round(x, 3) for x in c.r_axes], "rms_deg_per_frame": round(c.rms_deg, 4)}


def main(argv: list[str]) -> None:
    if argv == ["--vision"]:  # only the real clips' vision against their gyros
        report("camera_metadata_vision", {"cores": os.cpu_count(), "vision_vs_gyro": vision_figures()})
        return
    report(
        "camera_metadata",
        {
            "cores": os.cpu_count(),
            "gps": gps_figures(),
            "rolling_shutter": rolling_figures(),
            "vision_vs_gyro": vision_figures(),
        },
    )


if __name__ == "__main__":
    main(sys.argv[1:])
