"""Joint vs standalone VP9 on synthetic route pairs: BD-rate, alignment error, ingest speed.

Sets (thesis §16): *near-identical* pairs — the same road minutes apart: same light and parked
cars, different speed and stops (thesis upper bound 53–65 %); *different days* — the same time
of day on another day: sun and exposure a little different, other clouds and vehicles, lane offset
±0.2 m, other speed and stops (thesis 23.5–39.7 %). Each new drive is coded against the older one
with its frames aligned by the ORB aligner (thesis search + egovid's refinement), the thesis' ORB
search alone, SeqSLAM (thesis: 16.7–35.1 %), and the ground truth (oracle). Both aligners start
from the same noisy 1 Hz GPS prior. The reference drive is itself VP9-coded at the same
quantiser, and the baseline is built from its decoded frames, as in the archive.

BD-rate: bjontegaard (pchip), PSNR-Y, VP9 quantisers 28/38/48/58 (libvpx 0–63 scale; equal PSNR-Y
to the thesis' HEVC QPs 30/35/40/45, experiments/dashcam_quantiser_map.py), with the archive's
coding structure (anchors every 8 frames, frames between at q + 12, random access every 24 frames:
a keyframe in the standalone encode, a frame predicted from the baseline alone in the joint one,
as the thesis' 3D-HEVC configuration codes its dependent view) and, for comparison, low delay
(every frame from the one before) and the standalone encode with a single keyframe. Also the global
alignment of the baseline (gain, similarity) on the different-day set, alignment error in frames
against the synthetic ground truth, and `egovid dashcam ingest` frames per second at 1280x720.
Env: EGOVID_BENCH_SIZE (default 640x360); EGOVID_BENCH_SETS (e.g. ``day``; default all);
EGOVID_BENCH_QS (e.g. ``20,28,36,44``); EGOVID_BENCH_REFRESH (random-access period, 0 = none);
EGOVID_BENCH_SETS=none measures only the ingest speed;
EGOVID_BENCH_QUICK=1 measures only ORB, SeqSLAM and the ground truth at the default structure and
skips the ingest-speed part (for a run at 1280x720 on two cores).
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from egovid.dashcam import codec, vpx
from egovid.dashcam.align import OrbScorer, ScaleRefiner, align_orb, small_gray, smooth_monotone
from egovid.dashcam.geometry import project_on_polyline
from egovid.dashcam.gps import project
from egovid.dashcam.ingest import IngestOptions, ingest
from egovid.dashcam.seqslam import align_seqslam, descriptor
from egovid.dashcam.store import Archive
from egovid.io.video import iter_frames
from egovid.synth.drive import ORIGIN, DriveSpec, Light, gps_samples, render_drive, route_map, simulate

from _common import cache_dir, report

# VP9 quantisers of equal PSNR-Y to the thesis' HEVC QPs 30/35/40/45 on this content
# (experiments/dashcam_quantiser_map.py: 27.7/38.5/48.2/57.9).
QS = tuple(int(v) for v in os.environ.get("EGOVID_BENCH_QS", "28,38,48,58").split(","))
GOP = 8  # the archive's default coding structure (anchors every 8 frames); 1 = low delay
# Random-access period (frames), the archive's default: the thesis' 3D-HEVC configuration (GOP 8,
# intra period 24). 0 = one keyframe per drive.
REFRESH = int(os.environ.get("EGOVID_BENCH_REFRESH", "24"))
LEG = [("main", 20.0, 75.0)]


def specs() -> dict[str, list[tuple[str, DriveSpec, DriveSpec]]]:
    noon = Light.preset("noon")
    ref = DriveSpec(legs=LEG, cruise=10.0, seed=1, light=noon, vehicles=4)

    def day(g, daz, de, cc, seed):
        return dataclasses.replace(
            noon,
            gain=tuple(x * g for x in noon.gain),
            sun_az=noon.sun_az + daz,
            sun_el=noon.sun_el + de,
            cloud_cover=cc,
        )

    return {
        "near": [
            ("near-slower", ref, dataclasses.replace(ref, cruise=8.0, lane_offset=0.05, seed=101)),
            ("near-stop", ref, dataclasses.replace(ref, cruise=11.0, stops=[(25.0, 1.5)], lane_offset=-0.05, seed=102)),
        ],
        "day": [
            ("day-a", ref, DriveSpec(legs=LEG, cruise=8.5, seed=201, light=day(1.03, 5, 2, 0.45, 1), lane_offset=0.2)),
            (
                "day-b",
                ref,
                DriveSpec(
                    legs=LEG,
                    cruise=11.5,
                    seed=202,
                    light=day(0.97, -4, -3, 0.2, 2),
                    lane_offset=-0.15,
                    stops=[(60.0, 1.0)],
                ),
            ),
            ("day-c", ref, DriveSpec(legs=LEG, cruise=9.5, seed=203, light=day(1.0, 3, 4, 0.6, 3), lane_offset=0.1)),
        ],
    }


def frames_of(path) -> list[np.ndarray]:
    return [f.image for f in iter_frames(path, i420=True)]


def gps_positions(spec: DriveSpec, truth, fps: float) -> np.ndarray:
    """Per-frame position along the street from the noisy GPS, as the archive computes it."""
    g = gps_samples(spec, truth)
    xy = project(g["lat"], g["lon"], ORIGIN)
    street = route_map()["main"]
    s_fix = np.maximum.accumulate(project_on_polyline(street.points, xy))
    t_fix = np.array([(t - spec.start_time).total_seconds() for t in g["time"]])
    return np.interp(truth.times, t_fix, s_fix)


def similarity_params(B, dec, refmap, w, h, sc) -> list[list[int]]:
    """Similarity warps reference -> new frame from ORB matches (fixed point), per frame."""
    import cv2

    out = []
    for i in range(len(B)):
        a_, b_ = sc.features(small_gray(B[i], w, h)), sc.features(small_gray(dec[refmap[i]], w, h))
        p_ = None
        if a_.desc is not None and b_.desc is not None:
            mm = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(a_.desc, b_.desc)
            if len(mm) >= 12:
                p_ = codec.estimate_similarity(
                    a_.pts[[x.queryIdx for x in mm]], b_.pts[[x.trainIdx for x in mm]], 320 / w
                )
        out.append(p_ or [4096, 0, 0, 0, 4096, 0])
    return out


def encode_all(job) -> dict:
    """One quantiser and coding structure: the reference drive, the new drive alone, and jointly
    for every alignment."""
    ref_path, new_path, q, gop, w, h, maps, refined, kinds, sim_params = job
    pw, ph = vpx.padded_size(w, h)
    A, B = frames_of(ref_path), frames_of(new_path)
    st = vpx.EncoderSettings(q=q, speed=5, gop=gop, refresh=REFRESH)
    recs: list = []
    codec.encode_segment(iter(A), w, h, st, keep_recon=recs)
    s = codec.encode_segment(iter(B), w, h, st)
    out = {"alone": (len(s.blob) * 8, s.psnr_y)}
    if st.refresh:  # the same drive alone without random access: what seeking costs a plain encode
        s0 = codec.encode_segment(iter(B), w, h, dataclasses.replace(st, refresh=0))
        out["alone-one-keyframe"] = (len(s0.blob) * 8, s0.psnr_y)
    for k, rm in maps.items():
        j = codec.encode_segment(iter(B), w, h, st, lambda i, rm=rm: vpx.pad_i420(recs[rm[i]], pw, ph))
        out[k] = (len(j.blob) * 8, j.psnr_y)
    for kind in kinds:
        params = (
            [codec.estimate_gain(B[i][:h], recs[refined[i]][:h]) for i in range(len(B))]
            if kind == "gain"
            else sim_params
        )

        def base(i, kind=kind, params=params):
            return codec.apply_alignment(vpx.pad_i420(recs[refined[i]], pw, ph), pw, ph, kind, params[i])

        j = codec.encode_segment(iter(B), w, h, st, base)
        out[kind] = (len(j.blob) * 8, j.psnr_y)
    return out


def bd(r1, p1, r2, p2) -> float:
    import bjontegaard

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return float(bjontegaard.bd_rate(r1, p1, r2, p2, method="pchip"))


def main() -> None:
    w, h = (int(v) for v in os.environ.get("EGOVID_BENCH_SIZE", "640x360").split("x"))
    folder = cache_dir(f"dashcam{w}")
    results = {"size": f"{w}x{h}", "quantisers": QS, "random_access": REFRESH, "sets": {}}
    ref_cache: dict = {}
    quick = os.environ.get("EGOVID_BENCH_QUICK") == "1"
    wanted = os.environ.get("EGOVID_BENCH_SETS")
    for set_name, pairs in specs().items():
        if wanted and set_name not in wanted.split(","):
            continue
        rows = []
        for name, ref_spec, new_spec in pairs:
            paths = {}
            for label, spec in (("ref", ref_spec), (name, new_spec)):
                p = folder / f"{label}.mp4"
                if not p.exists():
                    render_drive(spec, p, width=w, height=h)
                paths[label] = p
            A, B = frames_of(paths["ref"]), frames_of(paths[name])
            ta, tb = simulate(ref_spec, 30.0), simulate(new_spec, 30.0)
            oracle = np.array([int(np.argmin(np.abs(ta.s - s))) for s in tb.s])
            if not ref_cache:
                rec: list = []
                codec.encode_segment(
                    iter(A), w, h, vpx.EncoderSettings(q=28, speed=5, gop=GOP, refresh=REFRESH), keep_recon=rec
                )
                ref_cache[28] = rec
            # Aligners, all from the same GPS prior, on the decoded reference at q = 28.
            pa, pb = gps_positions(ref_spec, ta, 30.0), gps_positions(new_spec, tb, 30.0)
            order = np.argsort(pa, kind="stable")
            prior = np.interp(pb, pa[order], order.astype(float))
            dec = ref_cache[28]
            sc = OrbScorer()
            fa = [sc.features(small_gray(f, w, h)) for f in dec]
            fb = [sc.features(small_gray(f, w, h)) for f in B]
            stopped = tb.speed < 0.3
            t0 = time.perf_counter()
            plain = align_orb(fb, fa, prior, tb.speed, np.abs(np.gradient(pa)) * 30.0, stopped, 30.0, sc).refmap
            t_orb = time.perf_counter() - t0
            t0 = time.perf_counter()
            rf = ScaleRefiner()
            refined = rf.refine(
                smooth_monotone(plain),
                [rf.features(small_gray(f, w, h)) for f in B],
                [rf.features(small_gray(f, w, h)) for f in dec],
                stopped,
            )
            t_refine = time.perf_counter() - t0
            t0 = time.perf_counter()
            seq = align_seqslam(
                np.stack([descriptor(small_gray(f, w, h)) for f in B]),
                np.stack([descriptor(small_gray(f, w, h)) for f in dec]),
                prior,
            ).refmap
            t_seq = time.perf_counter() - t0
            maps = {"oracle": oracle, "orb": refined, "orb-plain": plain, "seqslam": seq}
            row = {
                "pair": name,
                "frames": len(B),
                "align_error_frames": {k: float(np.mean(np.abs(v - oracle))) for k, v in maps.items() if k != "oracle"},
                "align_seconds": {"orb-plain": t_orb, "orb refinement": t_refine, "seqslam": t_seq},
            }
            kinds = ("gain", "similarity") if set_name == "day" and not quick else ()
            sim_params = similarity_params(B, dec, refined, w, h, sc) if kinds else None
            args = (str(paths["ref"]), str(paths[name]))
            ld_maps = {} if quick else {k: maps[k] for k in ("oracle", "orb")}
            if quick:
                maps = {k: maps[k] for k in ("oracle", "orb", "seqslam")}
            jobs = [(*args, q, GOP, w, h, maps, refined, kinds, sim_params) for q in QS]
            jobs += [(*args, q, 1, w, h, ld_maps, refined, (), None) for q in QS] if ld_maps else []
            with ProcessPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
                per_q = list(pool.map(encode_all, jobs))
            per_q, per_q_ld = per_q[: len(QS)], per_q[len(QS) :]

            def curve(rows_, k):
                return [x[k][0] for x in rows_], [x[k][1] for x in rows_]

            row["bd_rate_percent"] = {k: bd(*curve(per_q, "alone"), *curve(per_q, k)) for k in maps}
            if "alone-one-keyframe" in per_q[0]:  # against a plain encode with no random access at all
                one = curve(per_q, "alone-one-keyframe")
                row["bd_rate_percent"]["orb vs standalone with one keyframe"] = bd(*one, *curve(per_q, "orb"))
                row["bd_rate_percent"]["standalone random access vs one keyframe"] = bd(*one, *curve(per_q, "alone"))
            for kind in kinds:
                row["bd_rate_percent"][f"orb+{kind}"] = bd(*curve(per_q, "alone"), *curve(per_q, kind))
            for k in ld_maps:
                # Low delay (every frame from the one before), against the low-delay standalone.
                row["bd_rate_percent"][f"lowdelay:{k}"] = bd(*curve(per_q_ld, "alone"), *curve(per_q_ld, k))
            if per_q_ld:  # the two standalone structures against each other (negative = GOP 8 smaller)
                row["bd_rate_percent"]["standalone gop8 vs lowdelay"] = bd(
                    *curve(per_q_ld, "alone"), *curve(per_q, "alone")
                )
            rows.append(row)
            print(name, row["bd_rate_percent"], row["align_error_frames"], flush=True)
        avg = {k: float(np.mean([r["bd_rate_percent"][k] for r in rows])) for k in rows[0]["bd_rate_percent"]}
        results["sets"][set_name] = {"pairs": rows, "average_bd_rate_percent": avg}
    if quick:
        report("dashcam_bdrate", results)
        return
    # Ingest speed at 1280x720 (good-quality VP9, speed 5), with and without the standalone encode.
    big = cache_dir("dashcam1280")
    s1 = DriveSpec(legs=[("main", 20.0, 70.0)], cruise=10.0, seed=1, light=Light.preset("noon"))
    s2 = DriveSpec(legs=[("main", 20.0, 70.0)], cruise=9.0, seed=2, light=Light.preset("noon"))
    vids = []
    for k, s in enumerate((s1, s2)):
        p = big / f"drive{k}.mp4"
        if not p.exists():
            render_drive(s, p, width=1280, height=720)
        vids.append(p)
    import shutil

    speeds = {}
    for savings in (False, True):
        root = big / "archive"
        shutil.rmtree(root, ignore_errors=True)
        ar = Archive.create(root)
        r0 = ingest(ar, vids[0], vids[0].with_suffix(".gpx"), IngestOptions(measure_savings=savings))
        r1 = ingest(ar, vids[1], vids[1].with_suffix(".gpx"), IngestOptions(measure_savings=savings))
        speeds[f"savings_{savings}"] = {
            "root_fps": r0.fps,
            "joint_fps": r1.fps,
            "joint_saving_at_q32": r1.pieces[0].saving,
        }
    results["ingest_720p"] = speeds
    if "day" in results["sets"]:  # (EGOVID_BENCH_SETS=none measures only the ingest speed)
        day = results["sets"]["day"]["average_bd_rate_percent"]
        results["targets"] = {
            "day_set_joint_saving_ge_30pct": -day["orb"] >= 30.0,
            "orb_ahead_of_seqslam": day["orb"] < day["seqslam"],
        }
    report("dashcam_bdrate", results)


if __name__ == "__main__":
    main()
