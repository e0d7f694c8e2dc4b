"""How drives are ingested: encoder and alignment settings."""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass

from egovid.core.errors import EgovidError
from egovid.dashcam.align import ALIGNERS
from egovid.dashcam.codec import vpx

BASELINE_ALIGN = ("none", "gain", "similarity")

#: Named settings (``--preset``); explicit options override them. Measured in
#: benchmarks/dashcam_ingest_speed.py (speed) and benchmarks/dashcam_bdrate.py (savings).
PRESETS: dict[str, dict] = {
    # libvpx's realtime deadline at its fastest speed, two threads sharing rows and two tile
    # columns (one column saves 0.6 points more but root drives ingest slower), the first frame of
    # each joint random-access run at cpu-used 5 (0.6 points, no measurable time); one set of ORB
    # key points per frame shared by the search and the refinement, which measure every 2nd frame
    # (the others interpolated). docs/dashcam.md, "Why the realtime deadline saved less".
    "realtime": {
        "realtime": True,
        "speed": 9,
        "start_speed": 5,
        "threads": 2,
        "row_mt": True,
        "tile_columns": 1,
        "refine_radius": 2,
        "refine_features": 0,
        "align_every": 2,
        "verify_share": 0.25,
    },
    # libvpx's good-quality deadline at its fastest speed, two threads sharing rows and two tile
    # columns: the different-day saving of the archive preset's deadline (libvpx's realtime mode
    # never searches ALTREF and skips GOLDEN, the older drive, in much of the frame; see
    # docs/dashcam.md) at about twice its speed.
    "balanced": {
        "realtime": False,
        "speed": 5,
        "start_speed": 0,
        "threads": 2,
        "row_mt": True,
        "tile_columns": 1,
        "refine_radius": 3,
        "refine_features": 1000,
        "align_every": 1,
        "verify_share": 1.0,
    },
    # libvpx's good-quality deadline, one thread: the smallest files, the thesis-matched figures.
    "archive": {
        "realtime": False,
        "speed": 5,
        "start_speed": 0,
        "threads": 1,
        "row_mt": False,
        "tile_columns": 0,
        "refine_radius": 3,
        "refine_features": 1000,
        "align_every": 1,
        "verify_share": 1.0,
    },
}
DEFAULT_PRESET = "realtime"


@dataclass(frozen=True)
class IngestOptions:
    """How a drive is ingested (the defaults are those of :data:`DEFAULT_PRESET`).

    ``q``: VP9 quantiser 0-63 (lower = better quality; frames between anchors use ``q + 12``);
    ``speed``: libvpx cpu-used; ``realtime``: realtime instead of good-quality deadline; ``gop``:
    anchor spacing in frames (8, the default; 1 = low delay, every frame from the one before);
    ``refresh``: random-access period in frames (a drive can be decoded from every ``refresh``-th
    frame on: a keyframe for a root drive, a frame predicted from the older drive alone for a joint
    one; 0 = from the start only);
    ``aligner``: orb (thesis' ORB search, smoothed and refined by vertical image scale; the default) |
    orb-plain (the thesis' search alone) | seqslam | gps;
    ``baseline_align``: none | gain | similarity (global alignment of the baseline);
    ``measure_savings``: also encode each joint piece standalone to report the saving (off by
    default: it doubles the encoding);
    ``verify``: a decoder follows the encoder packet by packet and must reproduce its pictures;
    ``verify_share``: the share of a segment's random-access runs it follows besides the first and
    the last (a seeded sample, :func:`verified_runs`; 1: all). Every run's digest is taken from the
    encoder's pictures either way and checked by every extract;
    ``threads``, ``row_mt``, ``tile_columns``: libvpx's threading (``tile_columns`` is log2);
    ``start_speed``: cpu-used of the first frame of a joint random-access run (0 = ``speed``);
    ``refine_radius``: reference frames either side of a match measured by the vertical-scale
    refinement; ``refine_features``: its ORB key points per frame (0: the search's own, 500);
    ``align_every``: the ORB aligners search and refine every n-th frame, the matches of the
    frames between interpolated (1: every frame);
    ``preset``: the name of the preset these came from (recorded with each segment).
    """

    q: int = 32
    speed: int = 9
    realtime: bool = True
    gop: int = 8
    refresh: int = 24
    aligner: str = "orb"
    baseline_align: str = "none"
    measure_savings: bool = False
    verify: bool = True
    verify_share: float = 0.25
    threads: int = 2
    row_mt: bool = True
    tile_columns: int = 1
    start_speed: int = 5
    refine_radius: int = 2
    refine_features: int = 0
    align_every: int = 2
    preset: str | None = "realtime"

    @classmethod
    def from_preset(cls, preset: str | None = None, **overrides) -> IngestOptions:
        """The options of a named preset (:data:`PRESETS`; default :data:`DEFAULT_PRESET`), with
        ``overrides`` (those that are not None) on top."""
        name = preset or DEFAULT_PRESET
        if name not in PRESETS:
            raise EgovidError(f"unknown preset {name!r}", f"choose one of {', '.join(PRESETS)}")
        given = {k: v for k, v in overrides.items() if v is not None}
        return cls(**{**PRESETS[name], **given, "preset": name})

    def check(self) -> IngestOptions:
        """Raise :class:`EgovidError` for settings that cannot work (before any work starts)."""
        if not 0 <= self.q <= 63:
            raise EgovidError(f"quantiser {self.q} is outside 0-63", "use e.g. --q 32")
        if not 0 <= self.speed <= 9:
            raise EgovidError(f"--speed {self.speed} is outside 0-9", "use e.g. 5")
        self.encoder_settings(30.0)  # checks gop and the random-access period
        if self.aligner not in ALIGNERS:
            raise EgovidError(f"unknown aligner {self.aligner!r}", f"choose one of {', '.join(ALIGNERS)}")
        if self.refine_features != 0 and not 100 <= self.refine_features <= 5000:
            raise EgovidError(f"{self.refine_features} refinement features is outside 100-5000", "use 0 or 1000")
        if not 1 <= self.align_every <= 4:
            raise EgovidError(f"aligning every {self.align_every}th frame is outside 1-4", "use 1 or 2")
        if not 0.0 < self.verify_share <= 1.0:
            raise EgovidError(f"verifying a share of {self.verify_share} of the runs is outside (0, 1]", "use 1")
        if not 1 <= self.refine_radius <= 10:
            raise EgovidError(f"refinement radius {self.refine_radius} is outside 1-10", "use 2 or 3")
        if self.baseline_align not in BASELINE_ALIGN:
            raise EgovidError(
                f"unknown baseline alignment {self.baseline_align!r}", f"choose one of {', '.join(BASELINE_ALIGN)}"
            )
        return self

    def verified_runs(self, n_runs: int, seed: int = 0) -> Callable[[int], bool]:
        """Which of a segment's ``n_runs`` random-access runs the verifying decoder follows: the
        first, the last and a random ``verify_share`` of the others (seeded by ``seed``, e.g. the
        segment's first frame, so an ingest repeated verifies the same runs); ask in run order."""
        rng = random.Random(f"egovid-verify-{seed}")
        share = self.verify_share
        return lambda i: share >= 1.0 or i in (0, n_runs - 1) or rng.random() < share

    def encoder_settings(self, fps: float) -> vpx.EncoderSettings:
        return vpx.EncoderSettings(
            q=self.q,
            speed=self.speed,
            realtime=self.realtime,
            fps=round(fps) or 30,
            gop=self.gop,
            refresh=self.refresh,
            threads=self.threads,
            tile_columns=self.tile_columns,
            row_mt=self.row_mt,
            start_speed=self.start_speed,
        )
