"""Why the joint codec saves less than the thesis: the distance to the temporal reference.

The thesis coded with HEVC hierarchical B pictures (GOP 8) and reports the saving per picture type
(Fig. 16.2): P 48.1 %, B8 41.5 %, B4 32.9 %, B2 18.6 %, B1 6.0 % — the farther a picture is from
its temporal reference, the more the aligned older drive helps. egovid's VP9 codec is low-delay:
every frame predicts from the frame before it, which is the thesis' B1 case.

This script measures that on the benchmark's route pairs (``benchmarks/dashcam_bdrate.py``,
640x360, ground-truth alignment so that the aligner does not blur the picture): BD-rate of joint vs
standalone VP9 when only every ``stride``-th frame of the new drive is coded (stride 1 = the real
30 fps drive; stride 8 = a temporal reference 8 frames back, like the thesis' P pictures).
Writes docs/figures/dashcam_temporal_distance.json.
"""

from __future__ import annotations

import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import dashcam_bdrate as bench  # noqa: E402
from egovid.dashcam.codec import segment as codec  # noqa: E402
from egovid.dashcam.codec import vpx  # noqa: E402
from egovid.dashcam.codec.settings import EncoderSettings  # noqa: E402
from egovid.synth.drive import render_drive, simulate  # noqa: E402

W, H = 640, 360
STRIDES = (1, 4, 8)


def _pairs() -> dict:
    return {name: (ref, new) for pairs in bench.specs().values() for name, ref, new in pairs}


def _job(args: tuple[str, int, int]) -> tuple[tuple[int, float], tuple[int, float]]:
    """(bits, PSNR-Y) of the standalone and the joint encode at quantiser ``q``."""
    name, q, stride = args
    ref_spec, new_spec = _pairs()[name]
    folder = bench.cache_dir(f"dashcam{W}")
    ta, tb = simulate(ref_spec, 30.0), simulate(new_spec, 30.0)
    oracle = np.array([int(np.argmin(np.abs(ta.s - s))) for s in tb.s])[::stride]
    A, B = bench.frames_of(folder / "ref.mp4"), bench.frames_of(folder / f"{name}.mp4")[::stride]
    pw, ph = vpx.padded_size(W, H)
    st = EncoderSettings(q=q, gop=1)
    recs: list = []
    codec.encode_segment(iter(A), W, H, st, keep_recon=recs)
    alone = codec.encode_segment(iter(B), W, H, st)
    joint = codec.encode_segment(iter(B), W, H, st, lambda i: vpx.pad_i420(recs[oracle[i]], pw, ph))
    return (len(alone.blob) * 8, alone.psnr_y), (len(joint.blob) * 8, joint.psnr_y)


def main() -> dict:
    folder = bench.cache_dir(f"dashcam{W}")
    results: dict = {"size": f"{W}x{H}", "quantisers": list(bench.QS), "alignment": "ground truth", "pairs": {}}
    for name, (ref_spec, new_spec) in _pairs().items():
        for label, spec in (("ref", ref_spec), (name, new_spec)):
            if not (folder / f"{label}.mp4").exists():
                render_drive(spec, folder / f"{label}.mp4", width=W, height=H)
        row = {}
        for stride in STRIDES:
            with ProcessPoolExecutor(2) as pool:
                res = list(pool.map(_job, [(name, q, stride) for q in bench.QS]))
            row[str(stride)] = bench.bd(
                [a[0] for a, _ in res], [a[1] for a, _ in res], [j[0] for _, j in res], [j[1] for _, j in res]
            )
        results["pairs"][name] = row
        print(name, {k: round(v, 1) for k, v in row.items()}, flush=True)
    for set_name, pairs in bench.specs().items():
        results[f"average_{set_name}"] = {
            str(s): float(np.mean([results["pairs"][n][str(s)] for n, _, _ in pairs])) for s in STRIDES
        }
        print(set_name, {k: round(v, 1) for k, v in results[f"average_{set_name}"].items()})
    out = ROOT / "docs" / "figures" / "dashcam_temporal_distance.json"
    out.write_text(json.dumps(results, indent=1))
    print("wrote", out)
    return results


if __name__ == "__main__":
    main()
