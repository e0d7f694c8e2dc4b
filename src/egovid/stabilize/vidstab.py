"""ffmpeg's vid.stab (two passes) as the stabilisation peer, with content masks for masked ITF.

vid.stab is run without zoom (``optzoom=0:crop=black``) so that its frames keep the original
geometry, like ``egovid fpv stabilize --borders black``. Its content mask is not guessed from pixel
colour: the same transforms are applied to an all-white clip of the same size and length, and the
white pixels of that clip are the covered ones.
"""

from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

from egovid.errors import EgovidError
from egovid.io.video import count_frames, iter_frames, probe


def _run(cmd: list[str]) -> None:
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise EgovidError(f"ffmpeg failed: {r.stderr.strip()[-200:]}", "install Debian's ffmpeg (with libvidstab)")


def run_vidstab(
    src: Path, dst: Path, workdir: Path, *, crf: int = 18, preset: str = "veryfast"
) -> tuple[float, list[np.ndarray]]:
    """Stabilise ``src`` into ``dst`` with vid.stab; returns (seconds for both passes, masks)."""
    if shutil.which("ffmpeg") is None:
        raise EgovidError("ffmpeg is not installed", "run `make install` (it installs Debian's ffmpeg)")
    workdir.mkdir(parents=True, exist_ok=True)
    trf = workdir / (src.stem + ".trf")
    t = time.perf_counter()
    _run(["ffmpeg", "-v", "error", "-y", "-i", str(src), "-vf", f"vidstabdetect=result={trf}", "-f", "null", "-"])
    _run(
        [
            "ffmpeg",
            "-v",
            "error",
            "-y",
            "-i",
            str(src),
            "-vf",
            f"vidstabtransform=input={trf}:optzoom=0:crop=black",
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
            f"vidstabtransform=input={trf}:optzoom=0:crop=black",
            "-c:v",
            "ffv1",
            str(white),
        ]
    )
    return seconds, [f.image > 128 for f in iter_frames(white, gray=True)]
