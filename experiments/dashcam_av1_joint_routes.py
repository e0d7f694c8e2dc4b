"""Routes to joint coding on top of SVT-AV1, measured before choosing (issue 26).

SVT-AV1 takes no external reference picture (PyAV/FFmpeg expose none, nor does its own API), so
two codec-independent routes are measured here on one benchmark pair (``benchmarks/dashcam_bdrate.py``,
640x360, ground-truth alignment: an upper bound for each route), both at SVT-AV1 preset 10 with
a keyframe every 24 frames, against the plain SVT-AV1 encode of the new drive:

* **library picture**: every 24-frame run of the new drive is coded after the older drive's aligned
  decoded frame, forced to a keyframe (so SVT-AV1's own structure predicts the run from it);
  counted with and without the library pictures' bytes (free = shared by many later drives);
* **residual**: SVT-AV1 codes new − baseline + 128, the decoder adds the baseline back.

(The third route, libaom's AV1_SET_REFERENCE, was bounded by its plain encoder instead: libaom
3.6 realtime at cpu-used 8 through Debian's ffmpeg codes the same drive at −0.03 % BD-rate against
libvpx VP9 realtime cpu-used 8 — the codec today's joint VP9 sits on — at half its speed, and the
good-quality mode ran at 1.4 fps; docs/dashcam.md, "Codecs".)

Usage: python experiments/dashcam_av1_joint_routes.py [pair] (default day-a). Prints the BD-rates.
"""

from __future__ import annotations

import sys
import time
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import dashcam_bdrate as bench  # noqa: E402
from egovid.dashcam.codec.av1 import keep_thread_scheduling  # noqa: E402
from egovid.synth.drive import render_drive, simulate  # noqa: E402

CRFS = (30, 38, 46, 54)


def encode(frames: list[np.ndarray], crf: int, gop: int, keys=frozenset()) -> list[bytes]:
    h, w = frames[0].shape[0] * 2 // 3, frames[0].shape[1]
    cc = av.CodecContext.create("libsvtav1", "w")
    cc.width, cc.height, cc.pix_fmt = w, h, "yuv420p"
    cc.time_base, cc.framerate, cc.gop_size = Fraction(1, 30), Fraction(30), gop
    cc.options = {"preset": "10", "crf": str(crf), "svtav1-params": "irefresh-type=2"}
    with keep_thread_scheduling():  # as root SVT-AV1 would make this thread real-time
        cc.open()
    out = []
    for k, f in enumerate(frames):
        vf = av.VideoFrame.from_ndarray(f, format="yuv420p")
        vf.pts = k
        if k in keys:
            vf.pict_type = av.video.frame.PictureType.I
        out += [bytes(p) for p in cc.encode(vf)]
    return out + [bytes(p) for p in cc.encode(None)]


def decode(packets: list[bytes]) -> list[np.ndarray]:
    cc = av.CodecContext.create("libdav1d", "r")
    out = [f.to_ndarray(format="yuv420p") for p in packets for f in cc.decode(av.Packet(p))]
    return out + [f.to_ndarray(format="yuv420p") for f in cc.decode(None)]


def psnr(a: list[np.ndarray], b: list[np.ndarray]) -> float:
    h = a[0].shape[0] * 2 // 3
    se = sum(float(np.sum((x[:h].astype(np.int32) - y[:h]) ** 2)) for x, y in zip(a, b, strict=True))
    return float(10 * np.log10(255.0**2 * h * a[0].shape[1] * len(a) / se))


def main() -> None:
    name = sys.argv[1] if len(sys.argv) > 1 else "day-a"
    pairs = {n: (r, s) for plist in bench.specs().values() for n, r, s in plist}
    ref_spec, new_spec = pairs[name]
    folder = bench.cache_dir("dashcam640")
    for label, spec in (("ref", ref_spec), (name, new_spec)):
        if not (folder / f"{label}.mp4").exists():
            render_drive(spec, folder / f"{label}.mp4", width=640, height=360)
    A, B = bench.frames_of(folder / "ref.mp4"), bench.frames_of(folder / f"{name}.mp4")
    ta, tb = simulate(ref_spec, 30.0), simulate(new_spec, 30.0)
    oracle = [int(np.argmin(np.abs(ta.s - s))) for s in tb.s]
    rows: dict[str, list[tuple[float, float]]] = {"plain": [], "library (free)": [], "library": [], "residual": []}
    for crf in CRFS:
        RA = decode(encode(A, crf, 24))
        t0 = time.perf_counter()
        pb = encode(B, crf, 24)
        rows["plain"].append((8 * sum(map(len, pb)), psnr(decode(pb), B)))
        seq, keep, keys = [], [], set()
        for k0 in range(0, len(B), 24):
            keys.add(len(seq))
            seq.append(RA[oracle[k0]])
            keep.append(False)
            seq += B[k0 : k0 + 24]
            keep += [True] * len(B[k0 : k0 + 24])
        pl = encode(seq, crf, 25, frozenset(keys))
        rec = [r for r, kp in zip(decode(pl), keep, strict=True) if kp]
        run_bits = 8 * sum(len(p) for p, kp in zip(pl, keep, strict=True) if kp)
        rows["library (free)"].append((run_bits, psnr(rec, B)))
        rows["library"].append((8 * sum(map(len, pl)), psnr(rec, B)))
        res = [np.clip(b.astype(np.int16) - RA[oracle[k]] + 128, 0, 255).astype(np.uint8) for k, b in enumerate(B)]
        pr = encode(res, crf, 24)
        back = [
            np.clip(r.astype(np.int16) + RA[oracle[k]] - 128, 0, 255).astype(np.uint8) for k, r in enumerate(decode(pr))
        ]
        rows["residual"].append((8 * sum(map(len, pr)), psnr(back, B)))
        print(crf, {k: v[-1] for k, v in rows.items()}, f"{time.perf_counter() - t0:.1f} s", flush=True)
    base = rows.pop("plain")
    for label, pts in rows.items():
        r = bench.bd([p[0] for p in base], [p[1] for p in base], [p[0] for p in pts], [p[1] for p in pts])
        print(f"{name}: {label} vs plain SVT-AV1: {r:+.1f} % BD-rate (PSNR-Y)")


if __name__ == "__main__":
    main()
