"""Helpers shared by the benchmark scripts: a cache folder and synthetic clips."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CACHE = Path(os.environ.get("EGOVID_BENCH_DIR", ROOT / "bench-output"))


def cache_dir(name: str) -> Path:
    d = CACHE / name
    d.mkdir(parents=True, exist_ok=True)
    return d


def running_clip(path: Path, n: int = 300, size=(1280, 720), seed: int = 2, **kw) -> Path:
    """The issue's test clip: running sine yaw 10°/pitch 2.5° + roll 1.5° + shake + sensor noise."""
    from egovid.synth import motions
    from egovid.synth.fpv import render_fpv

    if not path.exists():
        angles = motions.running(
            n, kw.get("yaw", 10.0), kw.get("pitch", 2.5), kw.get("period", 24.0), kw.get("roll", 1.5)
        )
        angles = angles + motions.jitter(n, kw.get("jitter", (0.1, 0.1, 0.1)), seed=seed)
        render_fpv(path, angles, width=size[0], height=size[1], noise_std=2.0, seed=seed)
    return path


def timed(fn, *args, **kwargs):
    t = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t


def stolen_seconds() -> float | None:
    """CPU seconds the hypervisor has taken from this virtual machine since boot, all CPUs
    (/proc/stat's steal column; None where there is none). The difference over a run says how much
    of its wall time other guests of the same host had: speed figures from runs with a few seconds
    stolen are not this machine's."""
    try:
        with open("/proc/stat", encoding="ascii") as fh:
            fields = fh.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def report(name: str, figures: dict) -> None:
    """Print figures and append them to bench-output/results.jsonl."""
    print(json.dumps({"benchmark": name, **figures}, indent=2, default=float))
    with open(CACHE / "results.jsonl", "a", encoding="utf-8") as fh:
        stamp = time.strftime("%Y-%m-%dT%H:%M:%S")
        fh.write(json.dumps({"benchmark": name, "time": stamp, **figures}, default=float) + "\n")


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))
