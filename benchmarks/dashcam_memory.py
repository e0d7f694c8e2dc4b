"""Peak memory of a dashcam ingest against drive length: the video is decoded once and streamed,
so a 60 s drive should need no more memory than a 10 s one (issue 14: within 10 %).

For each length (EGOVID_BENCH_LENGTHS, default 10,60 seconds) a pair of drives at 640x360 along the
main road (the later one slower, another lane and light), each ingest in a fresh process (the
default preset, through ingest_videos, the route of ``egovid dashcam ingest``): the root drive,
then the joint one; peak resident memory from
getrusage(RUSAGE_SELF).ru_maxrss of that process. Also the most frames the joint ingest held at
once (frames of the new drive waiting for their match, and of the older drive kept for baselines).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

from egovid.synth.drive import DriveSpec, Light, render_drive

from _common import cache_dir, report

W, H = 640, 360
LENGTHS = [float(v) for v in os.environ.get("EGOVID_BENCH_LENGTHS", "10,60").split(",")]

CHILD = r"""
import json, resource, sys
from egovid.dashcam.ingest import ingest_videos
from egovid.dashcam.archive.store import open_archive
ar = open_archive(sys.argv[1])
(rep,) = ingest_videos(ar, [sys.argv[2]], name=sys.argv[3]).reports
print(json.dumps({"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "frames": rep.frames,
                  "fps": rep.fps, "modes": [p.mode for p in rep.pieces]}))
"""


def _ingest(archive, video, name) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(archive), str(video), name], check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    from egovid.dashcam.archive.store import Archive

    noon = Light.preset("noon")
    rows = {}
    for seconds in LENGTHS:
        folder = cache_dir(f"dashcam-memory-{seconds:g}s")
        length = 10.0 * seconds
        specs = {
            "ref": DriveSpec(legs=[("main", 20.0, 20.0 + length)], cruise=10.0, seed=1, light=noon),
            "new": DriveSpec(
                legs=[("main", 20.0, 20.0 + length)],
                cruise=9.0,
                seed=2,
                light=noon,
                lane_offset=0.2,
                stops=[(length / 2, 2.0)],
            ),
        }
        for name, spec in specs.items():
            if not (folder / f"{name}.mp4").exists():
                render_drive(spec, folder / f"{name}.mp4", width=W, height=H)
        arch = folder / "archive"
        shutil.rmtree(arch, ignore_errors=True)
        Archive.create(arch).close()
        root = _ingest(arch, folder / "ref.mp4", "ref")
        joint = _ingest(arch, folder / "new.mp4", "new")
        rows[f"{seconds:g}s"] = {"root": root, "joint": joint}
        print(
            f"{seconds:g} s: root {root['peak_rss_mb']:.0f} MB, joint {joint['peak_rss_mb']:.0f} MB "
            f"({joint['modes']}, {joint['frames']} frames)",
            flush=True,
        )
    short, long_ = rows[f"{LENGTHS[0]:g}s"], rows[f"{LENGTHS[-1]:g}s"]
    ratio = long_["joint"]["peak_rss_mb"] / short["joint"]["peak_rss_mb"]
    report(
        "dashcam_memory",
        {
            "size": f"{W}x{H}",
            "lengths_s": LENGTHS,
            "runs": rows,
            "joint_peak_ratio_long_over_short": ratio,
            "target_within_10_percent": ratio <= 1.10,
        },
    )


if __name__ == "__main__":
    main()
