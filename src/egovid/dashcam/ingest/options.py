"""How drives are ingested: encoder and alignment settings."""

from __future__ import annotations

from dataclasses import dataclass

from egovid.dashcam import vpx
from egovid.errors import EgovidError

ALIGNERS = ("orb", "orb-plain", "seqslam", "gps")
BASELINE_ALIGN = ("none", "gain", "similarity")


@dataclass(frozen=True)
class IngestOptions:
    """How a drive is ingested.

    ``q``: VP9 quantiser 0-63 (lower = better quality; frames between anchors use ``q + 12``);
    ``speed``: libvpx cpu-used; ``realtime``: realtime instead of good-quality deadline; ``gop``:
    anchor spacing in frames (8, the default; 1 = low delay, every frame from the one before);
    ``refresh``: random-access period in frames (a drive can be decoded from every ``refresh``-th
    frame on: a keyframe for a root drive, a frame predicted from the older drive alone for a joint
    one; 0 = from the start only);
    ``aligner``: orb (thesis' ORB search, smoothed and refined by vertical image scale; the default) |
    orb-plain (the thesis' search alone) | seqslam | gps;
    ``baseline_align``: none | gain | similarity (global alignment of the baseline);
    ``measure_savings``: also encode each joint piece standalone to report the saving;
    ``verify``: decode each new bitstream as extract will and compare with the encoder.
    """

    q: int = 32
    speed: int = 5
    realtime: bool = False
    gop: int = 8
    refresh: int = 24
    aligner: str = "orb"
    baseline_align: str = "none"
    measure_savings: bool = True
    verify: bool = True
    preset: str | None = None

    def check(self) -> IngestOptions:
        """Raise :class:`EgovidError` for settings that cannot work (before any work starts)."""
        if not 0 <= self.q <= 63:
            raise EgovidError(f"quantiser {self.q} is outside 0-63", "use e.g. --q 32")
        if not 0 <= self.speed <= 9:
            raise EgovidError(f"--speed {self.speed} is outside 0-9", "use e.g. 5")
        self.encoder_settings(30.0)  # checks gop and the random-access period
        if self.aligner not in ALIGNERS:
            raise EgovidError(f"unknown aligner {self.aligner!r}", f"choose one of {', '.join(ALIGNERS)}")
        if self.baseline_align not in BASELINE_ALIGN:
            raise EgovidError(
                f"unknown baseline alignment {self.baseline_align!r}", f"choose one of {', '.join(BASELINE_ALIGN)}"
            )
        return self

    def encoder_settings(self, fps: float) -> vpx.EncoderSettings:
        return vpx.EncoderSettings(
            q=self.q, speed=self.speed, realtime=self.realtime, fps=round(fps) or 30, gop=self.gop, refresh=self.refresh
        )
