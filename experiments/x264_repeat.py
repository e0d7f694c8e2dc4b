"""Does the stabiliser's render pattern give the same bytes for the same frames?

Re-encodes a clip ``--runs`` times in this process the way ``render_views`` does (decode with
``iter_frames`` on one worker thread, encode with :class:`egovid.core.video.VideoWriter` on
another, CRF 18, veryfast; ``--threads`` x264 threads, 0 = as many as it picks) and checks that
the encoder received the same frames and time stamps each time (a hash of every frame it was
given). Identical encoder input with different output files means the encoder's result depends on
something other than its input (measured 2026-12-05, hero6 clip, 6 runs: 2-4 distinct files with
the default threads and 2-3 with ``--threads 1``, the encoder's input identical every time; the
same with the chroma planes' stride padding filled). Not a test: it needs the shared clips and is
timing dependent.
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from egovid.core.video import VideoWriter, iter_frames, probe

ROOT = Path(__file__).resolve().parent.parent
CLIP = ROOT.parent / "shared" / "data" / "real" / "gopro-hero6-2s.mp4"


def reencode(src: str, dst: Path, threads: int) -> str:
    """Re-encode ``src`` into ``dst`` with decode and encode overlapped; a hash of the encoder's input."""
    info = probe(src)
    seen = hashlib.md5()
    frames = iter_frames(src, i420=True)
    stages = ThreadPoolExecutor(max_workers=2)
    decoding = stages.submit(next, frames, None)
    encoding = None
    opts = {"threads": str(threads)} if threads else None
    with VideoWriter(dst, info.width, info.height, info.fps, thread_type="AUTO", options=opts) as writer:
        while (frame := decoding.result()) is not None:
            decoding = stages.submit(next, frames, None)
            image = np.ascontiguousarray(frame.image)
            seen.update(image.tobytes())
            seen.update(np.float64(frame.time).tobytes())
            if encoding is not None:
                encoding.result()
            encoding = stages.submit(writer.write_i420, image, frame.time)
        if encoding is not None:
            encoding.result()
    stages.shutdown()
    frames.close()
    return seen.hexdigest()[:8]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip", nargs="?", default=str(CLIP))
    ap.add_argument("--runs", type=int, default=6)
    ap.add_argument("--threads", type=int, default=0, help="x264 threads (0: as many as it picks)")
    args = ap.parse_args()
    inputs, outputs = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.runs):
            dst = Path(tmp) / f"run{i}.mp4"
            inputs.append(reencode(args.clip, dst, args.threads))
            outputs.append(hashlib.md5(dst.read_bytes()).hexdigest()[:8])
    print(f"encoder input: {len(set(inputs))} distinct of {args.runs}; output files: {len(set(outputs))} distinct")
    print("outputs:", " ".join(outputs))


if __name__ == "__main__":
    main()
