"""libaom with the older drive injected as a reference (``AV1_SET_REFERENCE``), measured before
building it into the archive (issue 26): the joint gain itself (libaom joint against libaom
standalone at the same settings) and both against plain SVT-AV1 at presets of equal measured speed.

One benchmark pair of ``benchmarks/dashcam_bdrate.py`` (640x360 synthetic drives, default day-a).
The older drive is coded as the archive stores a first drive (SVT-AV1, its preset 10, a keyframe
every 24 frames, CRF = libaom q + 2, close in PSNR-Y), decoded, and its frame at the new frame's
position (ground truth: the alignment's upper bound) is the baseline. Every 24 frames a
random-access run: standalone = keyframe + 23 inter frames; joint = an undisplayed grey keyframe
and a grey frame that refreshes one slot (libaom's good-quality mode does not use the references
on the first frame after a keyframe; the same trick as VP9's START_BASELINE_HELD), then the run's
first frame from the baseline alone, the others from the baseline and the three previous frames.
Standalone uses the same explicit low-delay structure (LAST, LAST2, LAST3), and also libaom's own
(``own``: its default reference management at lag 0).

Timing: encoder seconds (the injection copies included) over the new drive's frames, each
configuration and each SVT-AV1 preset interleaved in one run; the machine is shared, so read the
speed as ratios. BD-rate: bjontegaard pchip, PSNR-Y, 4 points.

Usage: python experiments/dashcam_aom_joint.py [pair] [configs] (configs: comma-separated
``rt7``..``rt10``, ``good4``..``good6``; default ``rt8,rt10,good6``). EGOVID_AOM_FRAMES limits the
frames (default all). Prints one line per point and the BD-rates; writes
bench-output/dashcam_aom_joint_<pair>.json.
"""

from __future__ import annotations

import json
import os
import sys
import time
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import dashcam_bdrate as bench  # noqa: E402
from egovid.dashcam.codec import aom  # noqa: E402
from egovid.dashcam.codec.av1 import keep_thread_scheduling  # noqa: E402
from egovid.synth.drive import render_drive, simulate  # noqa: E402

QS = (28, 36, 44, 52)  # libaom's quantiser (0-63)
REF_DQ = 2  # the older drive's SVT-AV1 CRF = q + REF_DQ
SVT_CRFS = (26, 34, 42, 50, 58)
SVT_PRESETS = tuple(int(p) for p in os.environ.get("EGOVID_AOM_SVT", "3,4,5,6,8,10").split(","))
RUN = 24


def vp9(frames, baselines, q: int, good: bool) -> tuple[int, list[np.ndarray], float]:
    """Today's VP9 joint candidate (the archive's own code: GOP 8, runs of 24): ``good`` the
    archive preset's (good quality, cpu-used 5, one thread), else the realtime preset's."""
    from egovid.dashcam.codec import segment
    from egovid.dashcam.codec.settings import EncoderSettings

    h, w = frames[0].shape[0] * 2 // 3, frames[0].shape[1]
    if good:
        st = EncoderSettings(q=q, speed=5, gop=8, refresh=RUN)
    else:
        st = EncoderSettings(
            q=q, speed=9, realtime=True, gop=8, refresh=RUN, threads=2, row_mt=True, tile_columns=1, start_speed=5
        )
    rec: list[np.ndarray] = []
    clock: dict = {}
    seg = segment.encode_segment(iter(frames), w, h, st, baselines.__getitem__, keep_recon=rec, clock=clock)
    return seg.nbytes, rec, clock["encode"]


def svt(frames: list[np.ndarray], crf: int, preset: int, threads: int = 2) -> tuple[list[bytes], float]:
    h, w = frames[0].shape[0] * 2 // 3, frames[0].shape[1]
    cc = av.CodecContext.create("libsvtav1", "w")
    cc.width, cc.height, cc.pix_fmt = w, h, "yuv420p"
    cc.time_base, cc.framerate, cc.gop_size = Fraction(1, 30), Fraction(30), RUN
    cc.options = {"preset": str(preset), "crf": str(crf), "svtav1-params": f"irefresh-type=2:lp={threads}"}
    with keep_thread_scheduling():  # as root SVT-AV1 would make this thread real-time
        cc.open()
    t0 = time.perf_counter()
    out = []
    for k, f in enumerate(frames):
        vf = av.VideoFrame.from_ndarray(f, format="yuv420p")
        vf.pts = k
        if k % RUN == 0:
            vf.pict_type = av.video.frame.PictureType.I
        out += [bytes(p) for p in cc.encode(vf)]
    out += [bytes(p) for p in cc.encode(None)]
    return out, time.perf_counter() - t0


def dav1d(packets: list[bytes]) -> list[np.ndarray]:
    cc = av.CodecContext.create("libdav1d", "r")
    out = [f.to_ndarray(format="yuv420p") for p in packets for f in cc.decode(av.Packet(p))]
    return out + [f.to_ndarray(format="yuv420p") for f in cc.decode(None)]


def psnr(a: list[np.ndarray], b: list[np.ndarray]) -> float:
    h = a[0].shape[0] * 2 // 3
    se = sum(float(np.sum((x[:h].astype(np.int32) - y[:h]) ** 2)) for x, y in zip(a, b, strict=True))
    return float(10 * np.log10(255.0**2 * h * a[0].shape[1] * len(a) / se))


def low_delay(recent: list[int]) -> tuple[dict[int, int], int]:
    """References LAST, LAST2, LAST3 -> the run's newest slots among 0-2; the slot to refresh."""
    refs = {t: s for t, s in zip((aom.LAST, aom.LAST2, aom.LAST3), recent, strict=False)}
    free = [s for s in (0, 1, 2) if s not in recent]
    return refs, (free[0] if free else recent[-1])


def libaom(frames, baselines, settings: aom.AomSettings, mode: str) -> tuple[int, list[np.ndarray], float]:
    """Code ``frames`` in runs of RUN: ``mode`` joint | explicit (same structure, no baseline) |
    own (libaom's own references). Returns bytes, the encoder's pictures, encoder seconds; checks
    that a decoder with the same injections reproduces them (bit-exact)."""
    h, w = frames[0].shape[0] * 2 // 3, frames[0].shape[1]
    grey = np.full_like(frames[0], 128)
    enc = aom.AV1Encoder(w, h, settings)
    packets: list[tuple[bytes, np.ndarray | None, bool]] = []  # packet, injected baseline, shown
    recon = []
    seconds = 0.0
    for k0 in range(0, len(frames), RUN):
        recent: list[int] = []
        t0 = time.perf_counter()
        if mode == "joint":
            packets.append((enc.encode(grey, None), None, False))
            packets.append((enc.encode(grey, {aom.LAST: 0}, (0,)), None, False))
        for k in range(k0, min(k0 + RUN, len(frames))):
            if mode == "own":
                pkt = enc.encode(frames[k], None) if k == k0 else enc._encode(frames[k], 0)
                base = None
            elif k == k0 and mode != "joint":
                pkt, base = enc.encode(frames[k], None), None
                recent = [0]  # after a keyframe every slot holds it
            else:
                refs, slot = low_delay(recent)
                base = baselines[k] if mode == "joint" else None
                if base is not None:
                    refs = {**refs, aom.GOLDEN: aom.BASELINE_SLOT} if refs else {aom.LAST: aom.BASELINE_SLOT}
                pkt = enc.encode(frames[k], refs, (slot,), base)
                recent = [slot] + [s for s in recent if s != slot]
            seconds += time.perf_counter() - t0
            packets.append((pkt, base, True))
            recon.append(enc.reconstruction())
            t0 = time.perf_counter()
    enc.close()
    dec = aom.AV1Decoder(w, h)
    shown = [dec.decode(p, b) for p, b, s in packets]
    shown = [pic for pic, (_, _, s) in zip(shown, packets, strict=True) if s]
    dec.close()
    if not all(np.array_equal(a, b) for a, b in zip(shown, recon, strict=True)):
        raise SystemExit(f"{mode} {settings}: the decoder does not reproduce the encoder's pictures")
    return sum(len(p) for p, _, _ in packets), recon, seconds


CONFIGS = {
    **{f"rt{s}": aom.AomSettings(q=0, speed=s, realtime=True, threads=2) for s in (7, 8, 9, 10)},
    **{f"rt{s}": aom.AomSettings(q=0, speed=s, realtime=True, threads=2) for s in (5, 6)},
    **{f"good{s}": aom.AomSettings(q=0, speed=s, realtime=False, threads=2) for s in (3, 4, 5, 6)},
}
OWN = ("rt10", "good6")  # libaom's own reference structure measured for these


def main() -> None:
    import dataclasses

    os.environ.setdefault("SVT_LOG", "1")
    name = sys.argv[1] if len(sys.argv) > 1 else "day-a"
    configs = (sys.argv[2] if len(sys.argv) > 2 else "rt8,rt10,good6").split(",")
    pairs = {n: (r, s) for plist in bench.specs().values() for n, r, s in plist}
    ref_spec, new_spec = pairs[name]
    folder = bench.cache_dir("dashcam640")
    for label, spec in (("ref", ref_spec), (name, new_spec)):
        if not (folder / f"{label}.mp4").exists():
            render_drive(spec, folder / f"{label}.mp4", width=640, height=360)
    limit = int(os.environ.get("EGOVID_AOM_FRAMES", "0")) or None
    A, B = bench.frames_of(folder / "ref.mp4"), bench.frames_of(folder / f"{name}.mp4")[:limit]
    ta, tb = simulate(ref_spec, 30.0), simulate(new_spec, 30.0)
    oracle = [int(np.argmin(np.abs(ta.s - s))) for s in tb.s][: len(B)]
    rows: dict[str, list[dict]] = {}
    for i, q in enumerate(QS):
        ra = dav1d(svt(A, q + REF_DQ, 10)[0])
        baselines = [ra[j] for j in oracle]
        for c in configs:
            if c.startswith("vp9"):
                n, rec, sec = vp9(B, baselines, q, c == "vp9good")
                pt = {"q": q, "bits": 8 * n, "psnr": psnr(rec, B), "fps": len(B) / sec}
                rows.setdefault(f"{c} joint", []).append(pt)
                print(f"{c} joint", pt, flush=True)
                continue
            st = dataclasses.replace(CONFIGS[c], q=q)
            for mode in ("joint", "explicit", "own") if c in OWN else ("joint", "explicit"):
                n, rec, sec = libaom(B, baselines, st, mode)
                pt = {"q": q, "bits": 8 * n, "psnr": psnr(rec, B), "fps": len(B) / sec}
                rows.setdefault(f"{c} {mode}", []).append(pt)
                print(f"{c} {mode}", pt, flush=True)
        for p in SVT_PRESETS:
            for crf in SVT_CRFS[i : i + 1] + (SVT_CRFS[-1:] if i == len(QS) - 1 else ()):
                pk, sec = svt(B, crf, p)
                pt = {"crf": crf, "bits": 8 * sum(map(len, pk)), "psnr": psnr(dav1d(pk), B), "fps": len(B) / sec}
                rows.setdefault(f"svt p{p}", []).append(pt)
                print(f"svt p{p}", pt, flush=True)

    def bd(a: str, b: str) -> float:
        ra, rb = rows[a], rows[b]
        return bench.bd(
            [p["bits"] for p in ra], [p["psnr"] for p in ra], [p["bits"] for p in rb], [p["psnr"] for p in rb]
        )

    def fps(k: str) -> float:
        return float(np.mean([p["fps"] for p in rows[k]]))

    summary = {}
    for c in configs:
        s = {"joint fps": fps(f"{c} joint")}
        if f"{c} explicit" in rows:
            s["joint vs explicit standalone %"] = bd(f"{c} explicit", f"{c} joint")
            s["explicit standalone fps"] = fps(f"{c} explicit")
        if f"{c} own" in rows:
            s["joint vs libaom's own standalone %"] = bd(f"{c} own", f"{c} joint")
        for p in SVT_PRESETS:
            s[f"joint vs svt p{p} %"] = bd(f"svt p{p}", f"{c} joint")
            s[f"joint fps / svt p{p} fps"] = fps(f"{c} joint") / fps(f"svt p{p}")
        summary[c] = s
        print(c, {k: round(v, 2) for k, v in s.items()}, flush=True)
    print({f"svt p{p} fps": round(fps(f"svt p{p}"), 1) for p in SVT_PRESETS})
    out = ROOT / "bench-output" / f"dashcam_aom_joint_{name}.json"
    out.write_text(json.dumps({"pair": name, "frames": len(B), "rows": rows, "summary": summary}, indent=1))


if __name__ == "__main__":
    main()
