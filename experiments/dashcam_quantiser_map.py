"""Which VP9 quantisers match the thesis' HEVC QPs 30/35/40/45 (§16)?

The thesis coded with the HEVC reference software at QP 30, 35, 40 and 45. egovid codes VP9, whose
quantiser (0-63) is on another scale. This experiment codes the same synthetic drive with x265
(constant QP, GOP 8, a keyframe every 24 frames — the 3D-HEVC test configuration) and with egovid's
VP9 coder (`--gop 8`, random access every 24 frames) over its quantiser range, and maps each QP to
the VP9 quantiser of equal PSNR-Y (interpolated). Also printed: the mapping by quantiser step size
alone (HEVC Qstep = 2^((QP-4)/6); VP9 step = ac_q/8), for comparison.

Writes docs/figures/dashcam_quantiser_map.json.
"""

from __future__ import annotations

import json
import math
import sys
import tempfile
from pathlib import Path

import av
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from dashcam_bdrate import frames_of, specs  # noqa: E402
from egovid.dashcam.codec import segment as codec  # noqa: E402
from egovid.dashcam.codec.settings import EncoderSettings  # noqa: E402
from egovid.synth.drive import render_drive  # noqa: E402

from _common import cache_dir  # noqa: E402

QPS = (30, 35, 40, 45)
N = 96


def psnr_y(a: np.ndarray, b: np.ndarray) -> float:
    d = a.astype(np.float64) - b.astype(np.float64)
    return 10 * math.log10(255.0**2 / max(float(np.mean(d * d)), 1e-9))


def x265_psnr(frames: list[np.ndarray], w: int, h: int, qp: int) -> tuple[float, int]:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "x.mkv"
        with av.open(str(path), "w") as out:
            s = out.add_stream("libx265", rate=30)
            s.width, s.height, s.pix_fmt = w, h, "yuv420p"
            s.options = {
                "preset": "medium",
                "x265-params": f"qp={qp}:keyint=24:min-keyint=24:scenecut=0:bframes=7:b-adapt=0:log-level=error",
            }
            for f in frames:
                vf = av.VideoFrame.from_ndarray(f, format="yuv420p")
                for p in s.encode(vf):
                    out.mux(p)
            for p in s.encode():
                out.mux(p)
        size = path.stat().st_size
        with av.open(str(path)) as inp:
            dec = [fr.to_ndarray(format="yuv420p") for fr in inp.decode(video=0)]
    vals = [psnr_y(a[:h], b[:h]) for a, b in zip(frames, dec, strict=True)]
    return float(np.mean(vals)), size


def main() -> None:
    w, h = 640, 360
    folder = cache_dir(f"dashcam{w}")
    name, _ref, spec = specs()["day"][1]
    path = folder / f"{name}.mp4"
    if not path.exists():
        render_drive(spec, path, width=w, height=h)
    frames = frames_of(path)[:N]
    hevc = {qp: x265_psnr(frames, w, h, qp) for qp in QPS}
    vp9 = {}
    for q in range(24, 64, 4):
        st = EncoderSettings(q=q, speed=5, gop=8, refresh=24)
        recon: list = []
        e = codec.encode_segment(iter(frames), w, h, st, keep_recon=recon)
        vp9[q] = (float(np.mean([psnr_y(a[:h], b[:h]) for a, b in zip(frames, recon, strict=True)])), len(e.blob))
    qs = np.array(sorted(vp9))
    ps = np.array([vp9[q][0] for q in qs])
    by_psnr = {qp: float(np.interp(-hevc[qp][0], -ps, qs)) for qp in QPS}
    by_step = {}
    for qp in QPS:
        step = 2 ** ((qp - 4) / 6)
        by_step[qp] = min(range(64), key=lambda q: abs(math.log(_ac(q) / 8 / step)))
    res = {
        "clip": f"{name}, {N} frames, {w}x{h}",
        "x265 psnr_y/bytes by QP": hevc,
        "vp9 psnr_y/bytes by q": vp9,
        "vp9 q of equal PSNR-Y": by_psnr,
        "vp9 q of equal quantiser step": by_step,
    }
    print(json.dumps(res, indent=1))
    out = ROOT / "docs" / "figures" / "dashcam_quantiser_map.json"
    out.write_text(json.dumps(res, indent=1))


def _ac(q: int) -> int:
    """libvpx 8-bit AC quantiser of the 0-63 quantiser q (vp9_quant_common.c tables)."""
    return _AC[_Q2I[q]]


_Q2I = [4 * q for q in range(62)] + [249, 255]
# libvpx vp9_quant_common.c, ac_qlookup (8-bit)
# fmt: off
_AC = (
    4, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22,
    23, 24, 25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 37, 38,
    39, 40, 41, 42, 43, 44, 45, 46, 47, 48, 49, 50, 51, 52, 53, 54,
    55, 56, 57, 58, 59, 60, 61, 62, 63, 64, 65, 66, 67, 68, 69, 70,
    71, 72, 73, 74, 75, 76, 77, 78, 79, 80, 81, 82, 83, 84, 85, 86,
    87, 88, 89, 90, 91, 92, 93, 94, 95, 96, 97, 98, 99, 100, 101, 102,
    104, 106, 108, 110, 112, 114, 116, 118, 120, 122, 124, 126, 128, 130, 132, 134,
    136, 138, 140, 142, 144, 146, 148, 150, 152, 155, 158, 161, 164, 167, 170, 173,
    176, 179, 182, 185, 188, 191, 194, 197, 200, 203, 207, 211, 215, 219, 223, 227,
    231, 235, 239, 243, 247, 251, 255, 260, 265, 270, 275, 280, 285, 290, 295, 300,
    305, 311, 317, 323, 329, 335, 341, 347, 353, 359, 366, 373, 380, 387, 394, 401,
    408, 416, 424, 432, 440, 448, 456, 465, 474, 483, 492, 501, 510, 520, 530, 540,
    550, 560, 571, 582, 593, 604, 615, 627, 639, 651, 663, 676, 689, 702, 715, 729,
    743, 757, 771, 786, 801, 816, 832, 848, 864, 881, 898, 915, 933, 951, 969, 988,
    1007, 1026, 1046, 1066, 1087, 1108, 1129, 1151, 1173, 1196, 1219, 1243, 1267, 1292, 1317, 1343,
    1369, 1396, 1423, 1451, 1479, 1508, 1537, 1567, 1597, 1628, 1660, 1692, 1725, 1759, 1793, 1828,
)
# fmt: on


if __name__ == "__main__":
    main()
