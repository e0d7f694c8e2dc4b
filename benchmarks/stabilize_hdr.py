"""`egovid fpv stabilize` on 10-bit HLG HEVC (a phone's HDR video): speed, size and fidelity of
the 10-bit output (HEVC Main10) against the 8-bit one (H.264, ``--bit-depth 8``) from the same input.

Inputs (made once with the ffmpeg command): the issue's 3-s 640x360 ``testsrc2`` clip and
``handheld-1080p-pan.mp4`` (real, 8-bit H.264) converted to 10-bit HLG HEVC (x265 CRF 12). Each
input's motion is estimated once; every run then plans and renders in a fresh process (given the
motion, ``--no-measure``, global shutter), which reports its plan + render time, render fps, peak
RSS and output size; then a render alone (fixed homographies: a small wobble, zoom 1.05) reports
its wall fps and CPU milliseconds per frame (all threads; the figure that holds on a loaded
machine). Fidelity: the luma PSNR (10-bit peak, 1023) of each decoded output against a reference
render, the input decoded at 10 bits and warped by the same homographies with no
encoding (an 8-bit output counts as its samples times 4). Run under
``flock /tmp/egovid-timing.lock`` and report ``uptime``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from _common import ROOT, cache_dir, report

REAL = ROOT.parent / "shared" / "data" / "real" / "handheld-1080p-pan.mp4"
HLG = ["-color_primaries", "bt2020", "-color_trc", "arib-std-b67", "-colorspace", "bt2020nc"]


def ffmpeg(*args: str) -> None:
    subprocess.run(["ffmpeg", "-v", "error", "-y", *args], check=True, timeout=900, start_new_session=True)


def inputs(d: Path) -> dict[str, Path]:
    synth, real = d / "hlg-synth-360p.mp4", d / "hlg-handheld-1080p.mp4"
    if not synth.exists():
        src = ["-f", "lavfi", "-i", "testsrc2=size=640x360:rate=30:duration=3", "-vf", "format=yuv420p10le"]
        ffmpeg(*src, "-c:v", "libx265", "-pix_fmt", "yuv420p10le", *HLG, "-x265-params", "log-level=error", str(synth))
    if not real.exists():
        x265 = ["-c:v", "libx265", "-crf", "12", "-preset", "fast", "-pix_fmt", "yuv420p10le"]
        ffmpeg("-i", str(REAL), "-vf", "format=yuv420p10le", *x265, *HLG, "-x265-params", "log-level=error",
               "-c:a", "copy", str(real))  # fmt: skip
    return {"synth-360p": synth, "handheld-1080p": real}


CHILD = r"""
import json, resource, sys, time
import numpy as np
from egovid.core.rotations import matrix_from_euler
from egovid.core.video import iter_frames, probe
from egovid.fpv.stabilize.render import OutputFormat, _warp_i420, homographies, zoom_about_centre
from egovid.fpv.stabilize.run import stabilize_video
src, dst, motion, depth = sys.argv[1:5]
t = time.perf_counter()
res = stabilize_video(src, dst, motion=motion, measure=False, bit_depth=depth, readout_ms=0.0)
wall = time.perf_counter() - t
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
info = probe(src)
w, h = info.width, info.height
from egovid.core.camera.resolve import resolve_camera
intr = resolve_camera(src, None, None).intrinsics
eul = lambda a: matrix_from_euler(a[:, 0], a[:, 1], a[:, 2])
H = zoom_about_centre(res.keep, w, h) @ homographies(eul(res.original), eul(res.path), intr)
black = OutputFormat.of(info, 10).black
se, n = 0.0, 0
for fin, fout in zip(iter_frames(src, i420=True, bits=10), iter_frames(dst, i420=True, bits=10), strict=True):
    ref = _warp_i420(fin.image, H[fin.index], w, h, black, 0)[:h].astype(np.float64)
    se += float(np.mean((fout.image[:h].astype(np.float64) - ref) ** 2)); n += 1
psnr = 10 * np.log10(1023.0 ** 2 / (se / n))
print("RESULT", json.dumps({"bits": res.render.bits, "codec": probe(dst).codec, "pix_fmt": probe(dst).pix_fmt,
    "frames": n, "plan_render_s": wall, "render_s": res.seconds["render"], "render_fps": n / res.seconds["render"],
    "peak_rss_mb": rss, "bytes": __import__("os").path.getsize(dst), "psnr_y_db": psnr}))
"""


RENDER_ONLY = r"""
import json, sys, time
import numpy as np
from egovid.core.video import probe
from egovid.fpv.stabilize.render import render_stabilized
src, dst, depth = sys.argv[1:4]
n = probe(src).frame_count
H = np.repeat(np.eye(3)[None], n, 0)
H[:, 0, 2], H[:, 1, 2] = 4 * np.sin(np.arange(n) / 3), 3 * np.cos(np.arange(n) / 4)
c0, w0 = time.process_time(), time.perf_counter()
render_stabilized(src, dst, H, keep=np.full(n, 0.95), bit_depth=depth)
c, w = time.process_time() - c0, time.perf_counter() - w0
print("RESULT", json.dumps({"render_only_fps": n / w, "render_only_cpu_ms_per_frame": 1000 * c / n}))
"""


def child(code: str, *args: str) -> dict:
    r = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=1800, start_new_session=True
    )
    line = next((ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if r.returncode != 0 or line is None:
        raise SystemExit(f"run failed ({r.returncode}): {r.stderr[-2000:]}")
    return json.loads(line[7:])


def run(src: Path, dst: Path, motion: Path, depth: str) -> dict:
    out = child(CHILD, str(src), str(dst), str(motion), depth)
    return {**out, **child(RENDER_ONLY, str(src), str(dst.with_suffix(".render.mp4")), depth)}


def main() -> None:
    d = cache_dir("stabilize_hdr")
    figures = {"uptime": Path("/proc/loadavg").read_text().split()[:3]}
    for name, src in inputs(d).items():
        motion = d / f"{name}.motion.csv"
        if not motion.exists():
            subprocess.run(
                [sys.executable, "-m", "egovid", "fpv", "motion", str(src), "-o", str(motion)],
                check=True, timeout=1800, capture_output=True, start_new_session=True,
            )  # fmt: skip
        for depth in ("8", "auto"):
            figures[f"{name} bit-depth {depth}"] = run(src, d / f"{name}.{depth}.mp4", motion, depth)
            print(name, depth, figures[f"{name} bit-depth {depth}"], flush=True)
    figures["uptime after"] = Path("/proc/loadavg").read_text().split()[:3]
    report("stabilize_hdr", figures)


if __name__ == "__main__":
    main()
