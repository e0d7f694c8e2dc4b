"""Which older frame goes with each new one (thesis §15.2–15.3): ORB timeline alignment, the
SeqSLAM baseline, illumination matching and stop detection.

:data:`ALIGNERS` is the registry of the streamed timeline aligners (``--aligner``), by name: each
is a class built from a piece's baseline and GPS prior (streaming.py) that the ingest feeds one
new frame at a time (:class:`StreamAligner`). A new aligner is one class and one entry here.
"""

from __future__ import annotations

from typing import ClassVar, Protocol

import numpy as np

from egovid.dashcam.align.streaming import GpsAligner, OrbAligner, OrbPlainAligner, Reference, SeqslamAligner


class StreamAligner(Protocol):
    """A timeline aligner, streamed (see streaming.py for the arguments it is built from)."""

    name: ClassVar[str]  # its --aligner name
    summary: ClassVar[str]  # one line for the help
    orb_search: ClassVar[bool]  # searches with ORB: the ingest warms OpenCV's ORB up and prefetches

    fallbacks: int  # frames matched to the GPS prior for want of a confident match

    def __init__(
        self,
        ref: Reference,
        prior: np.ndarray,
        speed_new: np.ndarray,
        speed_ref: np.ndarray,
        stopped: np.ndarray,
        fps: float,
        every: int = 1,
    ) -> None: ...

    def push(self, gray: np.ndarray) -> list[int]:
        """Add the next new frame (its small grey copy); the matches that became final, in order."""
        ...

    def lowest_needed(self) -> int:
        """No frame of the baseline's sequence below this will be looked at again."""
        ...


#: The timeline aligners by ``--aligner`` name, the default first.
ALIGNERS: dict[str, type[StreamAligner]] = {
    cls.name: cls for cls in (OrbAligner, OrbPlainAligner, SeqslamAligner, GpsAligner)
}
DEFAULT_ALIGNER = next(iter(ALIGNERS))

__all__ = ["ALIGNERS", "DEFAULT_ALIGNER", "Reference", "StreamAligner"]
