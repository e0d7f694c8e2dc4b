"""libvpx encoder settings against the different-day saving, with ground-truth alignment.

The fast loop behind the realtime preset (docs/dashcam.md, "Why the realtime deadline saved
less"): BD-rate of joint vs standalone VP9 on the benchmark's different-day pairs
(``benchmarks/dashcam_bdrate.py``, 640x360, q 28/38/48/58, random access every 24), with the older
drive aligned by the simulator's ground truth so that only the encoder differs, and the joint
encode's frames per second (noisy on a shared machine).

Usage: ``python experiments/dashcam_realtime_encoder.py '[CONFIG, ...]'`` where each CONFIG is a
JSON object of :class:`egovid.dashcam.codec.vpx.EncoderSettings` fields plus, for trials the encoder does
not offer, ``"ctl": [[control id, value], ...]`` (libvpx controls applied after start-up; the
self-test runs before them) and ``"role_speed": {"anchor": 7, ...}`` (cpu-used for the frames of
one role, switched around them). Env: PAIRS (default day-a), QS, VERIFY=1 (a decoder follows the
encoder and must reproduce its pictures).
Example: ``'[{"realtime": true, "speed": 9, "gop": 8, "threads": 2, "row_mt": true}]'``.
"""

from __future__ import annotations

import ctypes
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import dashcam_bdrate as bench  # noqa: E402
from egovid.dashcam.codec import segment as codec  # noqa: E402
from egovid.dashcam.codec import vpx  # noqa: E402
from egovid.dashcam.codec.settings import EncoderSettings  # noqa: E402
from egovid.synth.drive import render_drive, simulate  # noqa: E402

from _common import cache_dir  # noqa: E402

CONTROLS: list[tuple[int, int]] = []
ROLE_SPEED: dict[str, int] = {}


def _patch() -> None:
    vpx.self_test()  # cached: it runs with the library's plain settings
    init, structured = vpx.VP9Encoder.__init__, vpx.VP9Encoder.encode_structured

    def start(self, *a, **k):
        init(self, *a, **k)
        for ctrl, value in CONTROLS:
            self._control(ctrl, ctypes.c_int(value))

    def encode(self, frame, role, *a, **k):
        speed = ROLE_SPEED.get(role)
        if speed is None:
            return structured(self, frame, role, *a, **k)
        self._control(vpx.VP8E_SET_CPUUSED, ctypes.c_int(speed))
        try:
            return structured(self, frame, role, *a, **k)
        finally:
            self._control(vpx.VP8E_SET_CPUUSED, ctypes.c_int(self.settings.speed))

    vpx.VP9Encoder.__init__, vpx.VP9Encoder.encode_structured = start, encode


def main() -> None:
    _patch()
    configs = json.loads(sys.argv[1])
    qs = tuple(int(v) for v in os.environ.get("QS", ",".join(map(str, bench.QS))).split(","))
    verify = os.environ.get("VERIFY") == "1"
    folder = cache_dir("dashcam640")
    pairs = {name: (ref, new) for name, ref, new in bench.specs()["day"]}
    for name in os.environ.get("PAIRS", "day-a").split(","):
        ref_spec, new_spec = pairs[name]
        for label, spec in (("ref", ref_spec), (name, new_spec)):
            if not (folder / f"{label}.mp4").exists():
                render_drive(spec, folder / f"{label}.mp4", width=640, height=360)
        ta, tb = simulate(ref_spec, 30.0), simulate(new_spec, 30.0)
        oracle = np.array([int(np.argmin(np.abs(ta.s - s))) for s in tb.s])
        A, B = bench.frames_of(folder / "ref.mp4"), bench.frames_of(folder / f"{name}.mp4")
        h, w = B[0].shape[0] * 2 // 3, B[0].shape[1]
        pw, ph = vpx.padded_size(w, h)
        for cfg in configs:
            cfg = dict(cfg)
            CONTROLS[:] = [tuple(c) for c in cfg.pop("ctl", [])]
            ROLE_SPEED.clear()
            ROLE_SPEED.update(cfg.pop("role_speed", {}))
            pts, seconds = [], 0.0
            for q in qs:
                st = EncoderSettings(q=q, fps=30, refresh=bench.REFRESH, **cfg)
                recs: list = []
                codec.encode_segment(iter(A), w, h, st, keep_recon=recs)
                alone = codec.encode_segment(iter(B), w, h, st)
                t0 = time.perf_counter()
                joint = codec.encode_segment(
                    iter(B),
                    w,
                    h,
                    st,
                    lambda i, r=recs, o=oracle, size=(pw, ph): vpx.pad_i420(r[o[i]], *size),
                    verify=verify,
                )
                seconds += time.perf_counter() - t0
                pts.append((8 * len(alone.blob), alone.psnr_y, 8 * len(joint.blob), joint.psnr_y))
            r1, p1, r2, p2 = zip(*pts, strict=True)
            rate = bench.bd(r1, p1, r2, p2) if len(qs) >= 4 else float("nan")
            print(
                name,
                json.dumps(cfg),
                CONTROLS,
                ROLE_SPEED,
                f"BD {rate:.1f} %, joint encode {len(B) * len(qs) / seconds:.0f} fps,",
                "standalone kbit",
                [round(x / 1000) for x in r1],
                "joint",
                [round(x / 1000) for x in r2],
                flush=True,
            )


if __name__ == "__main__":
    main()
