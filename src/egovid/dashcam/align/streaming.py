"""The timeline aligners, streamed: a piece's frames matched to its baseline's sequence one new
frame at a time, each frame's final match given as soon as it can no longer change.

The aligners of orb.py and seqslam.py, composed exactly as on whole sequences (a test checks that
both give the same matches), one class per ``--aligner`` (the registry is
:data:`egovid.dashcam.align.ALIGNERS`):

* :class:`OrbAligner` (``orb``) = the thesis' search (orb.OrbSearch), smoothing
  (orb.StreamSmoother), the vertical-scale refinement (orb.ScaleRefiner.crossing) and a second
  smoothing per stretch between stops; a match is final about 14 frames after its frame arrived
  (the two smoothing windows), so only that many frames are in flight;
* :class:`OrbPlainAligner` (``orb-plain``) the search alone;
* :class:`SeqslamAligner` (``seqslam``: seqslam.SeqslamSearch, stopped frames holding the previous
  match);
* :class:`GpsAligner` (``gps``) the GPS prior.

``every`` = e > 1 (the realtime preset's 2): the ORB aligners search and refine only every e-th
moving frame (and the last one, and the last before a stop); the search's matches and the
refinement's crossings of the frames in between are interpolated on a line between their measured
neighbours, before each smoothing; the wide searches around the GPS prior (the first frame, and
after a match far from it) score every 3rd reference frame, then the neighbours of the best
(orb.OrbSearch ``coarse``). The smoothing already fits a line over 9 frames, so on the synthetic
different-day drives the matches stay as close to the ground truth
(``benchmarks/dashcam_bdrate.py``) for half the alignment work.

Every aligner is built from the same arguments: ``ref`` (:class:`Reference`, the baseline's
sequence of m frames), ``prior`` (n,) the reference frame at each new frame's GPS position
(float), ``speed_new`` (n,) and ``speed_ref`` (m,) speeds in m/s, ``stopped`` (n,) the stop mask,
``fps`` the new drive's frame rate and ``every``; matches are indices 0 … m − 1.
"""

from __future__ import annotations

from typing import ClassVar, Protocol

import numpy as np

from egovid.core.motion.features import FrameFeatures
from egovid.dashcam.align.orb import OrbScorer, OrbSearch, ScaleRefiner, StreamSmoother
from egovid.dashcam.align.seqslam import SeqslamSearch, descriptor


class Reference(Protocol):
    """The baseline's sequence as the aligners read it (ingest.frames.RefFrames): ``m`` frames,
    the ORB scorer and refiner shared with it, and per frame j what they compute."""

    m: int
    scorer: OrbScorer
    refiner: ScaleRefiner

    def feats(self, j: int) -> FrameFeatures: ...

    def fine(self, j: int) -> FrameFeatures: ...

    def desc(self, j: int) -> np.ndarray: ...


class _Streamed:
    """What every streamed aligner keeps: the piece's GPS prior, stops and frame counts."""

    name: ClassVar[str]
    summary: ClassVar[str]
    orb_search: ClassVar[bool] = False  # searches with ORB (warm OpenCV's ORB up, prefetch the first search)

    def __init__(
        self,
        ref: Reference,
        prior: np.ndarray,
        speed_new: np.ndarray,
        speed_ref: np.ndarray,
        stopped: np.ndarray,
        fps: float,
        every: int = 1,
    ) -> None:
        self.ref, self.prior, self.stopped = ref, prior, np.asarray(stopped, bool)
        self.n, self.m = len(prior), ref.m
        self.k_in = 0  # new frames pushed so far
        self.fallbacks = 0  # frames matched to the prior for want of a confident match

    def _next(self) -> int:
        k = self.k_in
        self.k_in += 1
        return k


class GpsAligner(_Streamed):
    name = "gps"
    summary = "the reference frame at the same GPS position"

    def push(self, gray: np.ndarray) -> list[int]:
        """Add the next new frame (its small grey copy); returns its match, final at once."""
        return [int(np.clip(round(self.prior[self._next()]), 0, self.m - 1))]

    def lowest_needed(self) -> int:
        """No frame of the baseline's sequence below this will be looked at again (none is)."""
        return 0


class SeqslamAligner(_Streamed):
    name = "seqslam"
    summary = "SeqSLAM sequence matching of small normalised frames"

    def __init__(self, ref: Reference, prior: np.ndarray, *args, **kwargs) -> None:
        super().__init__(ref, prior, *args, **kwargs)
        self.seq = SeqslamSearch(ref.desc, self.m, prior)
        # Lowest band start of the frames still to come (the band moves with the prior).
        lo = np.round(np.asarray(prior, float)).astype(np.int64) - self.seq.band
        self.band_low = np.minimum.accumulate(lo[::-1])[::-1]
        self.last: int | None = None

    def push(self, gray: np.ndarray) -> list[int]:
        """Add the next new frame; returns its match (a stopped frame keeps the previous one)."""
        k = self._next()
        j = self.seq.step(k, descriptor(gray))
        self.fallbacks = self.seq.fallbacks
        if k > 0 and self.stopped[k]:
            j = self.last
        self.last = j
        return [j]

    def lowest_needed(self) -> int:
        """No frame of the baseline's sequence below this will be looked at again."""
        return int(max(0, self.band_low[min(self.k_in, self.n - 1)]))


class OrbPlainAligner(_Streamed):
    name = "orb-plain"
    summary = "the thesis' ORB search alone"
    orb_search = True

    def __init__(self, ref: Reference, prior, speed_new, speed_ref, stopped, fps: float, every: int = 1) -> None:
        super().__init__(ref, prior, speed_new, speed_ref, stopped, fps, every)
        self.every = max(1, int(every))
        coarse = 3 if self.every > 1 else 1
        self.search = OrbSearch(ref.feats, self.m, prior, speed_new, speed_ref, self.stopped, fps, ref.scorer, coarse)
        self.searched: list[int] = []  # frames waiting for the next searched frame (every > 1)
        self.j_prev: tuple[int, float] | None = None  # the last searched frame and its match

    def push(self, gray: np.ndarray) -> list[int]:
        """Add the next new frame (its small grey copy); returns the matches that became final,
        for the frames after the last one returned, in order."""
        k = self._next()
        if not self._measured(k):
            self.search.skip(k)
            self.searched.append(k)
            return []
        feat = self.ref.scorer.features(gray)
        return self._matched(k, gray, feat, self._step(k, feat))

    def _step(self, k: int, feat: FrameFeatures) -> list[tuple[int, float]]:
        """Search frame k; (frame, match) of it and of the frames skipped since the last search
        (interpolated)."""
        j, _ = self.search.step(k, feat)
        self.fallbacks = self.search.fallbacks
        matches = [*_between(self.j_prev, self.searched, k, j), (k, float(j))]
        self.j_prev, self.searched = (k, float(j)), []
        return matches

    def _matched(self, k: int, gray: np.ndarray, feat: FrameFeatures, matches: list[tuple[int, float]]) -> list[int]:
        """The final matches given the search's (the plain search's are final at once)."""
        return [round(v) for _, v in matches]

    def _measured(self, k: int) -> bool:
        """Whether frame ``k`` is searched (and refined)."""
        return (
            self.every == 1
            or k % self.every == 0
            or k == self.n - 1
            or bool(self.stopped[k])
            or bool(self.stopped[min(k + 1, self.n - 1)])
        )

    def lowest_needed(self) -> int:
        """No frame of the baseline's sequence below this will be looked at again."""
        return max(0, self.search.lowest_needed())


class OrbAligner(OrbPlainAligner):
    name = "orb"
    summary = "the ORB search, smoothed and refined by vertical image scale (the default)"

    def __init__(self, ref: Reference, prior, *args, **kwargs) -> None:
        super().__init__(ref, prior, *args, **kwargs)
        self.sm1 = StreamSmoother(self.n)
        self.sm2 = StreamSmoother(self.n, ref.refiner.window, median=5, stopped=self.stopped)
        self.fine: dict[int, FrameFeatures] = {}
        self.k_sm1 = 0  # frames out of the first smoothing
        self.last_sm = 0
        self.refined: list[int] = []  # frames waiting for the next refined frame (every > 1)
        self.x_prev: tuple[int, float] | None = None  # the last refined frame and its crossing

    def _matched(self, k: int, gray: np.ndarray, feat: FrameFeatures, matches: list[tuple[int, float]]) -> list[int]:
        """Smooth the search's matches, refine each smoothed one by vertical scale, smooth again."""
        self.fine[k] = self.ref.refiner.features(gray) if self.ref.refiner.n_features else feat
        out: list[int] = []
        for _, jk in matches:
            for s in self.sm1.push(jk):
                out += self._refine(s)
        return out

    def _refine(self, s: float) -> list[int]:
        """The next smoothed match ``s``: its vertical-scale crossing (interpolated for a frame not
        searched: it waits for the next crossing), through the second smoothing."""
        k1 = self.k_sm1
        self.k_sm1 += 1
        self.last_sm = s
        fine = self.fine.pop(k1, None)
        if fine is None and not self.stopped[k1]:
            self.refined.append(k1)
            return []
        x = float(s) if self.stopped[k1] else self.ref.refiner.crossing(s, fine, self.ref.fine, self.m)
        xs = [*_between(self.x_prev, self.refined, k1, x), (k1, x)]
        self.x_prev, self.refined = (k1, x), []
        return [int(np.clip(v, 0, self.m - 1)) for _, xk in xs for v in self.sm2.push(xk)]

    def lowest_needed(self) -> int:
        """No frame of the baseline's sequence below this will be looked at again."""
        return max(0, min(self.search.lowest_needed(), self.last_sm - self.ref.refiner.radius))


def _between(prev: tuple[int, float] | None, frames: list[int], k: int, v: float) -> list[tuple[int, float]]:
    """Values of ``frames`` (between the measured frame ``prev[0]`` and frame ``k``) on the line
    from ``prev[1]`` to ``v``."""
    if not frames:
        return []
    k0, v0 = prev if prev is not None else (frames[0] - 1, v)
    return [(f, v0 + (v - v0) * (f - k0) / (k - k0)) for f in frames]
