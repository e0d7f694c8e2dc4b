"""Where everything of an evaluation run lives (``--out DIR``), and the factor pairs of a run.

::

    DIR/config.json                         what was asked
    DIR/scenes.json                         the scenes and factor pairs of the run
    DIR/scenes/real/NAME.mkv                a real sequence, lossless (+ NAME.gt.tum, NAME.json)
    DIR/scenes/sS/SCENE.mkv                 synthetic and degraded scenes of seed S
    DIR/videos/{real,sS}/SCENE__crfNN.mp4   the H.264 compression ladder
    DIR/results/VO/sS/SCENE__LEVEL.json     one cell: status, times, pose error, OITF, RITF (+ .tum)

A real sequence is the same for every seed (only its degraded copies depend on the seed), so it
and its ladder are stored once; its cells still run once per seed (the spread then measures the
odometer's own non-determinism).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

CRFS = (18, 24, 30, 36, 42, 48)
LEVELS = ("lossless", *(f"crf{c}" for c in CRFS))


@dataclass(frozen=True)
class Factor:
    """One factor pair: ``ideal`` and ``hard`` scene names, from a ``source`` ("synthetic" or a
    real sequence's name). ``name`` is the thesis factor (feature, data, sensor, motion) or the
    real-frame factor (noise, blur, illumination)."""

    source: str
    name: str
    ideal: str
    hard: str

    @property
    def label(self) -> str:
        return self.name if self.source == "synthetic" else f"{self.source}: {self.name}"


def scene_dir(out: Path, seed: int, seeded: bool = True) -> Path:
    """Folder of a scene's lossless video and truth."""
    return out / "scenes" / (f"s{seed}" if seeded else "real")


def video_path(out: Path, scene: str, level: str, seed: int, seeded: bool = True) -> Path:
    """The video a cell runs on."""
    if level == "lossless":
        return scene_dir(out, seed, seeded) / f"{scene}.mkv"
    return out / "videos" / (f"s{seed}" if seeded else "real") / f"{scene}__{level}.mp4"


def cell_path(out: Path, vo: str, scene: str, level: str, seed: int) -> Path:
    """The JSON of one cell (its trajectory is the same path with ``.tum``)."""
    return out / "results" / vo / f"s{seed}" / f"{scene}__{level}.json"
