"""Peak memory of `egovid fpv stabilize` on a long 720p input (default 10 minutes).

A 30-second synthetic running clip (1280x720) is concatenated (stream copy) into a 1-minute and a
10-minute video; each is stabilised in a fresh process and its peak resident set size (RSS) is
read from the kernel. Memory must stay bounded: the 10-minute run may not need much more than the
1-minute one. Set EGOVID_MEMORY_MINUTES to change the long duration. Takes ~20 minutes at 10.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
from pathlib import Path

from _common import cache_dir, report, running_clip


def concat(base: Path, times: int, out: Path) -> Path:
    if out.exists():
        return out
    lst = out.with_suffix(".txt")
    lst.write_text("".join(f"file '{base.resolve()}'\n" for _ in range(times)))
    subprocess.run(
        ["ffmpeg", "-v", "error", "-y", "-f", "concat", "-safe", "0", "-i", str(lst), "-c", "copy", str(out)],
        check=True,
    )
    return out


def peak_rss_mb(video: Path, out: Path) -> tuple[float, float]:
    """(peak RSS in MB, seconds) of a child `egovid fpv stabilize` process."""
    code = (
        "import resource, sys, runpy; sys.argv = ['egovid', 'fpv', 'stabilize', sys.argv[1], '-o', sys.argv[2]];"
        "import egovid.cli as c\n"
        "try:\n    c.main()\nexcept SystemExit as e:\n    pass\n"
        "print('PEAK', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)"
    )
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", code, str(video), str(out)], capture_output=True, text=True)
    seconds = time.perf_counter() - t
    peak = [ln for ln in r.stdout.splitlines() if ln.startswith("PEAK")]
    if r.returncode != 0 or not peak:
        raise SystemExit(f"stabilize failed: {r.stderr[-2000:]}")
    return int(peak[0].split()[1]) / 1024.0, seconds


def main() -> None:
    minutes = float(os.environ.get("EGOVID_MEMORY_MINUTES", "10"))
    folder = cache_dir("memory")
    base = running_clip(folder / "base30s.mp4", n=900)
    one = concat(base, 2, folder / "long1min.mp4")
    long = concat(base, round(minutes * 2), folder / f"long{minutes:g}min.mp4")
    rss1, s1 = peak_rss_mb(one, folder / "out1.mp4")
    rssn, sn = peak_rss_mb(long, folder / "outN.mp4")
    report(
        "stabilize_memory",
        {
            "input_1min": {"frames": 1800, "peak_rss_mb": rss1, "seconds": s1, "fps": 1800 / s1},
            f"input_{minutes:g}min": {
                "frames": int(1800 * minutes),
                "peak_rss_mb": rssn,
                "seconds": sn,
                "fps": 1800 * minutes / sn,
            },
            "rss_growth_factor": rssn / rss1,
            "bounded": rssn < 1.5 * rss1,
            "self_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        },
    )


if __name__ == "__main__":
    main()
