"""ffmpeg's vid.stab (two passes) as the stabilisation peer.

Two settings:

* ``defaults=True``: vid.stab as a user runs it (detect defaults, ``vidstabtransform`` smoothing
  15 frames, optimal static zoom, borders kept from earlier frames); its zoom is read from its
  own log ("Final zoom", percent);
* ``defaults=False``: without zoom (``optzoom=0:crop=black``), so that frames keep the original
  geometry like ``egovid fpv stabilize --borders black``; its content mask is not guessed from
  pixel colour: the same transforms are applied to an all-white clip of the same size and
  length, and the white pixels of that clip are the covered ones.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from egovid.core.errors import EgovidError
from egovid.core.video import count_frames, iter_frames, probe


def _run(cmd: list[str]) -> str:
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise EgovidError(f"ffmpeg failed: {r.stderr.strip()[-200:]}", "install Debian's ffmpeg (with libvidstab)")
    return r.stderr


@dataclass
class VidstabRun:
    """``seconds`` of both passes, ``zoom`` factor applied (1 = none), and with ``defaults=False``
    the content ``masks`` of the output frames."""

    seconds: float
    zoom: float
    masks: list[np.ndarray] | None


def run_vidstab(
    src: Path, dst: Path, workdir: Path, *, crf: int = 18, preset: str = "veryfast", defaults: bool = False
) -> VidstabRun:
    """Stabilise ``src`` into ``dst`` with vid.stab (see the module docstring)."""
    if shutil.which("ffmpeg") is None:
        raise EgovidError("ffmpeg is not installed", "run `make install` (it installs Debian's ffmpeg)")
    workdir.mkdir(parents=True, exist_ok=True)
    trf = workdir / (src.stem + ".trf")
    transform = f"vidstabtransform=input={trf}" + ("" if defaults else ":optzoom=0:crop=black")
    t = time.perf_counter()
    _run(["ffmpeg", "-v", "error", "-y", "-i", str(src), "-vf", f"vidstabdetect=result={trf}", "-f", "null", "-"])
    log = _run(
        [
            "ffmpeg",
            "-v",
            "verbose",
            "-y",
            "-i",
            str(src),
            "-vf",
            transform,
            "-c:v",
            "libx264",
            "-preset",
            preset,
            "-crf",
            str(crf),
            str(dst),
        ]
    )
    seconds = time.perf_counter() - t
    found = re.findall(r"Final zoom: (-?[0-9.]+)", log)
    zoom = 1.0 + float(found[-1]) / 100.0 if found else 1.0
    if defaults:
        return VidstabRun(seconds, zoom, None)
    info = probe(src)
    white = workdir / (src.stem + ".white.mkv")
    _run(
        [
            "ffmpeg",
            "-v",
            "error",
            "-y",
            "-f",
            "lavfi",
            "-i",
            f"color=white:s={info.width}x{info.height}:r=30",
            "-frames:v",
            str(count_frames(src)),
            "-vf",
            transform,
            "-c:v",
            "ffv1",
            str(white),
        ]
    )
    return VidstabRun(seconds, zoom, [f.image > 128 for f in iter_frames(white, gray=True)])
