"""Stage *align*, streamed: the timeline alignment of a piece to its baseline's sequence, one new
frame at a time, giving each frame's final match as soon as it can no longer change.

The aligners of align.py and seqslam.py, composed exactly as on whole sequences (a test checks
that both give the same matches): ``orb`` = the thesis' search (align.OrbSearch), smoothing
(align.StreamSmoother), the vertical-scale refinement (align.ScaleRefiner.crossing) and a second
smoothing per stretch between stops; ``orb-plain`` the search alone; ``seqslam``
(seqslam.SeqslamSearch, stopped frames holding the previous match); ``gps`` the GPS prior. A
match is final about 14 frames after its frame arrived (the two smoothing windows), so only that
many frames are in flight.

``every`` = e > 1 (the realtime preset's 2): the ORB aligners search and refine only every e-th
moving frame (and the last one, and the last before a stop); the search's matches and the
refinement's crossings of the frames in between are interpolated on a line between their measured
neighbours, before each smoothing; the wide searches around the GPS prior (the first frame, and
after a match far from it) score every 3rd reference frame, then the neighbours of the best
(align.OrbSearch ``coarse``). The smoothing already fits a line over 9 frames, so on the
synthetic different-day drives the matches stay as close to the ground truth
(``benchmarks/dashcam_bdrate.py``) for half the alignment work.
"""

from __future__ import annotations

import numpy as np

from egovid.dashcam.align.orb import OrbSearch, StreamSmoother
from egovid.dashcam.ingest.frames import RefFrames


class StreamingAlignment:
    """Matches (indices into the baseline's sequence, 0 … m − 1) of the ``n`` frames of a piece.

    ``prior`` (n,): the reference frame at each frame's GPS position (float); ``speed_new`` (n,),
    ``speed_ref`` (m,) speeds in m/s; ``stopped`` (n,) the stop mask; ``fps`` the new drive's
    frame rate."""

    def __init__(
        self,
        kind: str,
        ref: RefFrames,
        prior: np.ndarray,
        speed_new: np.ndarray,
        speed_ref: np.ndarray,
        stopped: np.ndarray,
        fps: float,
        every: int = 1,
    ) -> None:
        self.kind, self.ref, self.prior, self.stopped = kind, ref, prior, np.asarray(stopped, bool)
        self.n, self.m = len(prior), ref.m
        self.every = max(1, int(every))
        self.k_in = 0
        self.searched: list[int] = []  # frames waiting for the next searched frame (every > 1)
        self.j_prev: tuple[int, float] | None = None  # the last searched frame and its match
        self.refined: list[int] = []  # frames waiting for the next refined frame (every > 1)
        self.x_prev: tuple[int, float] | None = None  # the last refined frame and its crossing
        self.last: int | None = None
        self.fallbacks = 0
        if kind in ("orb", "orb-plain"):
            coarse = 3 if self.every > 1 else 1
            self.search = OrbSearch(
                ref.feats, self.m, prior, speed_new, speed_ref, self.stopped, fps, ref.scorer, coarse
            )
        if kind == "orb":
            self.sm1 = StreamSmoother(self.n)
            self.sm2 = StreamSmoother(self.n, ref.refiner.window, median=5, stopped=self.stopped)
            self.fine: dict = {}
            self.k_sm1 = 0
            self.last_sm = 0
        if kind == "seqslam":
            from egovid.dashcam.align.seqslam import SeqslamSearch

            self.seq = SeqslamSearch(ref.desc, self.m, prior)
            # Lowest band start of the frames still to come (the band moves with the prior).
            lo = np.round(np.asarray(prior, float)).astype(np.int64) - self.seq.band
            self.band_low = np.minimum.accumulate(lo[::-1])[::-1]

    def push(self, gray: np.ndarray) -> list[int]:
        """Add the next new frame (its small grey copy); returns the matches that became final,
        for the frames after the last one returned, in order."""
        k = self.k_in
        self.k_in += 1
        if self.kind == "gps":
            return [int(np.clip(round(self.prior[k]), 0, self.m - 1))]
        if self.kind == "seqslam":
            from egovid.dashcam.align.seqslam import descriptor

            j = self.seq.step(k, descriptor(gray))
            self.fallbacks = self.seq.fallbacks
            if k > 0 and self.stopped[k]:
                j = self.last
            self.last = j
            return [j]
        if not self._measured(k):
            self.search.skip(k)
            self.searched.append(k)
            return []
        feat = self.ref.scorer.features(gray)
        j, _ = self.search.step(k, feat)
        self.fallbacks = self.search.fallbacks
        matches = [*_between(self.j_prev, self.searched, k, j), (k, float(j))]
        self.j_prev, self.searched = (k, float(j)), []
        if self.kind == "orb-plain":
            return [round(v) for _, v in matches]
        self.fine[k] = self.ref.refiner.features(gray) if self.ref.refiner.n_features else feat
        out = []
        for _, jk in matches:
            for s in self.sm1.push(jk):
                k1 = self.k_sm1
                self.k_sm1 += 1
                self.last_sm = s
                fine = self.fine.pop(k1, None)
                if fine is None and not self.stopped[k1]:  # not searched: wait for the next crossing
                    self.refined.append(k1)
                    continue
                x = float(s) if self.stopped[k1] else self.ref.refiner.crossing(s, fine, self.ref.fine, self.m)
                xs = [*_between(self.x_prev, self.refined, k1, x), (k1, x)]
                self.x_prev, self.refined = (k1, x), []
                for _, xk in xs:
                    out += [int(np.clip(v, 0, self.m - 1)) for v in self.sm2.push(xk)]
        return out

    def _measured(self, k: int) -> bool:
        """Whether the ORB aligners search (and refine) frame ``k``."""
        return (
            self.every == 1
            or k % self.every == 0
            or k == self.n - 1
            or bool(self.stopped[k])
            or bool(self.stopped[min(k + 1, self.n - 1)])
        )

    def lowest_needed(self) -> int:
        """No frame of the baseline's sequence below this will be looked at again by the
        alignment."""
        if self.kind == "gps":
            return 0
        if self.kind == "seqslam":
            return int(max(0, self.band_low[min(self.k_in, self.n - 1)]))
        low = self.search.lowest_needed()
        if self.kind == "orb":
            low = min(low, self.last_sm - self.ref.refiner.radius)
        return max(0, low)


def _between(prev: tuple[int, float] | None, frames: list[int], k: int, v: float) -> list[tuple[int, float]]:
    """Values of ``frames`` (between the measured frame ``prev[0]`` and frame ``k``) on the line
    from ``prev[1]`` to ``v``."""
    if not frames:
        return []
    k0, v0 = prev if prev is not None else (frames[0] - 1, v)
    return [(f, v0 + (v - v0) * (f - k0) / (k - k0)) for f in frames]
