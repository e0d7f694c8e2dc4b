"""The default `egovid voeval run` grid at its realistic scale, and the same cells on a Dask cluster.

Default grid: every available odometer (egovid, ECC, Mono-VO, COLMAP, ORB-SLAM3 where it installs)
x 6 synthetic scenes (factors feature, data, sensor, motion; compression across) x 7 compression
levels, 300-frame 640x480 clips, one seed. Target: <= 30 minutes on this 2-core machine.

Modes (``--mode``):

* ``local`` — the grid as `egovid voeval run` runs it without a scheduler: a local pool of two
  worker processes (Dask LocalCluster), scenes and ladder included in the time;
* ``cluster`` — a separate `dask scheduler` and `dask worker --nworkers 2 --nthreads 1` on
  127.0.0.1 (what `--scheduler tcp://HOST:PORT` talks to), same grid;
* ``both`` — local, then the cluster on a copy of the prepared scenes (cells only), to compare
  per-cell times of the same cells.

``--vos``, ``--levels`` and ``--seeds`` run a part of the grid (e.g. to check before a full run).
Prints the total time, seconds per cell by odometer (mean, max) and by stage, the cell statuses,
and writes the report (bench-output/voeval[-cluster]/report.html, report.md, matrices.json).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from egovid.engine import EngineConfig
from egovid.voeval.layout import LEVELS
from egovid.voeval.report import write_report
from egovid.voeval.runner import GridConfig, load_results, run_grid

from _common import cache_dir, report


@contextlib.contextmanager
def local_cluster(base: Path):
    """`dask scheduler` + `dask worker --nworkers 2 --nthreads 1` on 127.0.0.1; yields the address."""
    dask = str(Path(sys.executable).parent / "dask")
    sched = base / "scheduler.json"
    sched.unlink(missing_ok=True)
    local = ["--host", "127.0.0.1", "--no-dashboard"]
    procs = [
        subprocess.Popen(
            [dask, "scheduler", *local, "--port", "0", "--scheduler-file", str(sched)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
    ]
    try:
        deadline = time.monotonic() + 120
        while not (sched.exists() and sched.stat().st_size):
            if time.monotonic() > deadline:
                raise TimeoutError("the Dask scheduler did not start within 120 s")
            time.sleep(0.2)
        address = json.loads(sched.read_text())["address"]
        procs.append(
            subprocess.Popen(
                [
                    dask,
                    "worker",
                    address,
                    *local,
                    "--nworkers",
                    "2",
                    "--nthreads",
                    "1",
                    "--local-directory",
                    str(base / "workers"),
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
            )
        )
        from distributed import Client

        with Client(address, timeout=60) as c:
            c.wait_for_workers(2, timeout=180)
        yield address
    finally:
        for p in reversed(procs):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)


def summary(out: Path, seconds: float, r: dict, mode: str) -> dict:
    run = load_results(out)
    per_vo, status = defaultdict(list), defaultdict(lambda: defaultdict(int))
    per_scene = defaultdict(list)
    for (vo, scene, _lv, _s), c in run.cells.items():
        per_vo[vo].append(c["seconds"])
        per_scene[scene].append(c["seconds"])
        status[vo][c["status"]] += 1
    return {
        "mode": mode,
        "cells": len(run.cells),
        "computed": r["computed"],
        "stage_minutes": {k: v / 60 for k, v in r["stages"].items()},
        "total_minutes": seconds / 60,
        "target_minutes": 30,
        "meets_target": seconds <= 30 * 60,
        "cores": os.cpu_count(),
        "vo_seconds_per_cell": {
            v: {"mean": float(np.mean(t)), "max": float(np.max(t)), "n": len(t)} for v, t in per_vo.items()
        },
        "vo_seconds_per_scene": {s: float(np.mean(t)) for s, t in per_scene.items()},
        "status": {v: dict(s) for v, s in status.items()},
        "report": str(out / "report.html"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mode", choices=("local", "cluster", "both"), default="local")
    ap.add_argument("--vos", help="odometers (default: every available one)")
    ap.add_argument("--levels", default=",".join(LEVELS))
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--quick", action="store_true", help="the --quick grid (48 frames, 320x240)")
    ap.add_argument("--resume", action="store_true", help="keep finished cells of an earlier run")
    a = ap.parse_args()
    cfg = GridConfig(levels=a.levels.split(","), seeds=[int(s) for s in a.seeds.split(",")])
    if a.vos:
        cfg.vos = a.vos.split(",")
    if a.quick:
        cfg.frames, cfg.width, cfg.height = 48, 320, 240
    out = cache_dir("voeval")
    if a.mode in ("local", "both"):
        if not a.resume:
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir(parents=True)
        t = time.perf_counter()
        r = run_grid(out, cfg, EngineConfig(workers=2))
        total = time.perf_counter() - t
        write_report(out)
        report("voeval_grid", summary(out, total, r, "local: LocalCluster, 2 worker processes"))
    if a.mode in ("cluster", "both"):
        cl = cache_dir("voeval-cluster")
        if not a.resume:
            shutil.rmtree(cl, ignore_errors=True)
            cl.mkdir(parents=True)
        if a.mode == "both":  # same prepared scenes and ladder: the cluster run times the cells only
            for sub in ("scenes", "videos"):
                shutil.copytree(out / sub, cl / sub, dirs_exist_ok=True)
        with local_cluster(cl) as address:
            t = time.perf_counter()
            r = run_grid(cl, cfg, EngineConfig(scheduler=address))
            total = time.perf_counter() - t
        write_report(cl)
        report("voeval_grid", summary(cl, total, r, f"cluster: dask scheduler + 2 workers at {address}"))


if __name__ == "__main__":
    main()
