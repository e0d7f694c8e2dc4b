"""Helpers shared by the benchmark scripts: a cache folder and synthetic clips."""

from __future__ import annotations

import functools
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


@functools.cache
def vmaf_ffmpeg() -> str | None:
    """An ``ffmpeg`` with libvmaf, or None: the one imageio-ffmpeg ships (``pip install
    '.[bench]'``; its build has libvmaf and the built-in vmaf_v0.6.1 model), else one on PATH
    that has the filter. Neither PyAV's FFmpeg nor Debian's has libvmaf."""
    import shutil
    import subprocess

    candidates = []
    try:
        import imageio_ffmpeg

        candidates.append(imageio_ffmpeg.get_ffmpeg_exe())
    except (ImportError, RuntimeError):
        pass
    if shutil.which("ffmpeg"):
        candidates.append(shutil.which("ffmpeg"))
    for exe in candidates:
        out = subprocess.run([exe, "-hide_banner", "-filters"], capture_output=True, text=True, timeout=60)
        if " libvmaf " in out.stdout:
            return exe
    return None


def vmaf(reference: Path, distorted, size: tuple[int, int] | None = None, fps: float = 30.0) -> float:
    """Mean VMAF (vmaf_v0.6.1, 0-100) of ``distorted`` against the video file ``reference``, frame
    for frame. ``distorted`` is a video file, or a list of I420 frames (uint8, shape (h*3/2, w))
    with ``size`` = (w, h) in pixels, piped raw. Runs libvmaf on 2 threads, every frame."""
    import subprocess
    import tempfile

    exe = vmaf_ffmpeg()
    if exe is None:
        raise RuntimeError("no ffmpeg with libvmaf: pip install '.[bench]' (imageio-ffmpeg)")
    with tempfile.TemporaryDirectory(prefix="egovid-vmaf-") as tmp:
        log = Path(tmp) / "vmaf.json"
        if isinstance(distorted, (str, Path)):
            dist_in, data = ["-i", str(distorted)], None
        else:
            w, h = size
            dist_in = ["-f", "rawvideo", "-pix_fmt", "yuv420p", "-s", f"{w}x{h}", "-r", f"{fps:g}", "-i", "-"]
            data = b"".join(np.ascontiguousarray(f[: h * 3 // 2]).tobytes() for f in distorted)
        cmd = [
            exe,
            "-hide_banner",
            "-loglevel",
            "error",
            *dist_in,
            "-i",
            str(reference),
            "-lavfi",
            f"[0:v]settb=1/30,setpts=N[d];[1:v]settb=1/30,setpts=N[r];[d][r]libvmaf=log_fmt=json:log_path={log}:n_threads=2",
            "-f",
            "null",
            "-",
        ]
        subprocess.run(cmd, input=data, check=True, capture_output=True, timeout=3600)
        result = json.loads(log.read_text())
    counts = {_frame_count(reference), len(distorted) if data is not None else _frame_count(distorted)}
    if counts != {len(result["frames"])}:
        raise RuntimeError(f"VMAF scored {len(result['frames'])} frames of videos of {sorted(counts)} frames")
    return float(result["pooled_metrics"]["vmaf"]["mean"])


def _frame_count(path) -> int:
    """Video frames in a file (its packets, demuxed without decoding)."""
    import av

    with av.open(str(path)) as c:
        return sum(1 for p in c.demux(c.streams.video[0]) if p.size)
