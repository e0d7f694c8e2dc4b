"""libaom encoder controls screened for the default preset's joint candidate (issue 26, speed):
the libaom segment encoder alone (``codec/aom_segment.py``, the realtime preset's structure: flat,
every refresh kept, runs of 24 from the baseline) on the first frames of the 720p drive of
``benchmarks/dashcam_ingest_speed.py`` (rendered there first), the root drive's frame at the same
index as each frame's baseline (unaligned: a rough stand-in for the alignment), at one quantiser.

Per configuration: wall and CPU seconds of the process (libaom's worker threads included: on this
shared machine read the CPU seconds, and compare configurations of one run), bytes, PSNR-Y and the
digest of the pictures (equal digests: the control changed nothing). Extra controls are applied
after the encoder's own (``AV1Encoder``), so they override them.

Usage: python experiments/dashcam_aom_controls.py CONFIGS, CONFIGS a JSON list of
``[label, [[control id, value], ...], {speed, threads, tiles, row_mt, q}]``, e.g.
``'[["base", [], {}], ["costs", [[126, 3], [127, 3], [128, 3]], {"tiles": 0}]]'`` (control ids:
``codec/aom.py``; libaom 3.6's ``aom/aomcx.h``). Env: EGOVID_AOM_FRAMES (default 96),
EGOVID_AOM_REPEATS (default 1), EGOVID_BENCH_DIR (the benchmarks' cache).
"""

from __future__ import annotations

import ctypes
import json
import os
import resource
import sys
import time
from pathlib import Path

import av
import numpy as np

from egovid.dashcam.codec import aom, aom_segment, vpx
from egovid.dashcam.codec.settings import EncoderSettings

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
os.environ.setdefault("EGOVID_BENCH_SIZES", "1280x720")

import dashcam_ingest_speed as speed  # noqa: E402 - after the path to benchmarks/

N = int(os.environ.get("EGOVID_AOM_FRAMES", "96"))
REPEATS = int(os.environ.get("EGOVID_AOM_REPEATS", "1"))
EXTRA: list[tuple[int, int]] = []


def frames(path: Path, n: int) -> list[np.ndarray]:
    """The first ``n`` frames of ``path`` as I420 arrays."""
    out = []
    with av.open(str(path)) as c:
        for f in c.decode(video=0):
            out.append(f.to_ndarray(format="yuv420p"))
            if len(out) >= n:
                break
    return out


def _with_extra(init):
    def patched(self, *args, **kwargs) -> None:
        init(self, *args, **kwargs)
        for ctrl, value in EXTRA:
            self._control(ctrl, ctypes.c_int(value))

    return patched


def run(new, bases, label: str, extra, speed_=7, threads=2, tiles=1, row_mt=True, q=42) -> dict:
    """One configuration: seconds, bytes, PSNR-Y and digest of the segment."""
    EXTRA[:] = [tuple(x) for x in extra]
    h, w = new[0].shape[0] * 2 // 3, new[0].shape[1]
    st = EncoderSettings(
        q=q,
        speed=speed_,
        codec="aom",
        realtime=True,
        fps=30,
        gop=1,
        refresh=24,
        threads=threads,
        tile_columns=tiles,
        row_mt=row_mt,
        keep_refresh=True,
    )
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    seg = aom_segment.encode_segment(iter(new), w, h, st, baselines=lambda k: bases[k])
    t1, r1 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
    cpu = r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime
    return {
        "label": label,
        "wall_s": round(t1 - t0, 3),
        "cpu_s": round(cpu, 3),
        "bytes": seg.nbytes,
        "psnr_y": round(seg.psnr_y, 3),
        "digest": seg.recon_digest[:10],
    }


def main() -> None:
    configs = json.loads(sys.argv[1])
    root, joint = speed.drives(1280, 720)
    new, old = frames(joint, N), frames(root, N)
    h, w = new[0].shape[0] * 2 // 3, new[0].shape[1]
    pw, ph = vpx.padded_size(w, h)
    bases = [vpx.pad_i420(o, pw, ph) for o in old]
    aom.AV1Encoder.__init__ = _with_extra(aom.AV1Encoder.__init__)
    aom.self_test()
    for _ in range(REPEATS):
        for label, extra, kw in configs:
            kw = {("speed_" if k == "speed" else k): v for k, v in kw.items()}
            print(json.dumps(run(new, bases, label, extra, **kw)), flush=True)


if __name__ == "__main__":
    main()
