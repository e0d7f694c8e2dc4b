"""Dashcam ingest scaling out: one batch of drives ingested by 1 and by 2 local worker processes
(``egovid dashcam ingest ARCHIVE FOLDER --workers N``), wall-clock seconds and frames per second
of the whole batch (the files' examination included, as the command does it: ingest_videos), in
the same run.

The batch: four drives at 640x360 (EGOVID_BENCH_SIZE), two along the main road and two along the
side street, 400 m apart, so the two roads ingest side by side and each later drive waits for the
earlier one of its road (its baseline). Default preset. Run under /work/coord/bin/timed.
"""

from __future__ import annotations

import os
import shutil
import time

from egovid.core.engine import EngineConfig
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.ingest import IngestOptions, ingest_videos
from egovid.synth.drive import DriveSpec, Light, render_drive

from _common import cache_dir, report

W, H = (int(v) for v in os.environ.get("EGOVID_BENCH_SIZE", "640x360").split("x"))


def batch_folder():
    folder = cache_dir(f"dashcam-scaling-{W}x{H}")
    videos = folder / "videos"
    videos.mkdir(exist_ok=True)
    noon = Light.preset("noon")
    specs = {
        "1-main": DriveSpec(legs=[("main", 30.0, 100.0)], cruise=10.0, seed=11, light=noon),
        "2-side": DriveSpec(legs=[("side", 10.0, 80.0)], cruise=10.0, seed=12, light=noon),
        "3-main": DriveSpec(legs=[("main", 30.0, 100.0)], cruise=9.0, lane_offset=0.2, seed=13, light=noon),
        "4-side": DriveSpec(legs=[("side", 10.0, 80.0)], cruise=9.0, lane_offset=0.2, seed=14, light=noon),
    }
    for name, spec in specs.items():
        if not (videos / f"{name}.mp4").exists():
            render_drive(spec, videos / f"{name}.mp4", width=W, height=H)
    return folder, videos


def main() -> None:
    folder, videos = batch_folder()
    rows = {}
    for workers in (1, 2):
        root = folder / f"archive-{workers}"
        shutil.rmtree(root, ignore_errors=True)
        ar = Archive.create(root)
        t0 = time.perf_counter()
        results = ingest_videos(ar, [videos], engine=EngineConfig(workers=workers)).check().added
        seconds = time.perf_counter() - t0
        frames = sum(r.report.frames for r in results)
        rows[str(workers)] = {
            "seconds": seconds,
            "frames": frames,
            "fps": frames / seconds,
            "modes": {r.name: [p.mode for p in r.report.pieces] for r in results},
        }
        print(f"{workers} worker(s): {seconds:.1f} s, {frames / seconds:.1f} fps", flush=True)
    report(
        "dashcam_scaling",
        {
            "size": f"{W}x{H}",
            "preset": IngestOptions().preset,
            "cpus": os.cpu_count(),
            "workers": rows,
            "speedup_2_over_1": rows["1"]["seconds"] / rows["2"]["seconds"],
        },
    )


if __name__ == "__main__":
    main()
