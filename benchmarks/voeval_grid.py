"""A full default `egovid voeval run` on this machine: 4 odometers (egovid, ECC, Mono-VO,
COLMAP) x 6 scenes (5 factors: feature, data, sensor, motion; compression across) x 7
compression levels, 48-frame 320x240 clips. Target: <= 30 minutes on 2 cores.

Prints the total time, the time per cell by odometer, the cell statuses, and writes the report
(bench-output/voeval/report.html / report.md / matrices.json).
"""

from __future__ import annotations

import os
import shutil
import time
from collections import defaultdict

import numpy as np

from egovid.voeval.report import write_report
from egovid.voeval.runner import GridConfig, load_results, run_grid

from _common import cache_dir, report


def main() -> None:
    out = cache_dir("voeval")
    if not os.environ.get("EGOVID_RESUME"):
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir(parents=True)
    t = time.perf_counter()
    summary = run_grid(out, GridConfig(workers=os.cpu_count() or 2))
    total = time.perf_counter() - t
    write_report(out)
    results, _, _, _ = load_results(out)
    per_vo = defaultdict(list)
    status = defaultdict(lambda: defaultdict(int))
    for (vo, _s, _l), c in results.items():
        per_vo[vo].append(c["seconds"])
        status[vo][c["status"]] += 1
    report(
        "voeval_grid",
        {
            "cells": summary["cells"],
            "computed": summary["computed"],
            "total_minutes": total / 60,
            "target_minutes": 30,
            "meets_target": total <= 30 * 60,
            "cores": os.cpu_count(),
            "seconds_per_cell": {vo: {"mean": float(np.mean(v)), "max": float(np.max(v))} for vo, v in per_vo.items()},
            "status": {vo: dict(s) for vo, s in status.items()},
            "report": str(out / "report.html"),
        },
    )


if __name__ == "__main__":
    main()
