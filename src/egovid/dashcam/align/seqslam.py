"""SeqSLAM timeline alignment, the comparison baseline of thesis §15.2.1 / §16.2 (after Milford &
Wyeth 2012; written from the published recipe, not from the GPL OpenSeqSLAM code).

1. frames to grey 64 x 32; 2. each 8 x 8 patch normalised to zero mean and unit variance;
3. sum-of-absolute-differences matrix between new and reference frames (within a band around the
GPS prior, as for the ORB aligner); 4. local contrast enhancement: each difference normalised by
the mean and standard deviation of its 10 neighbours along the reference axis; 5. for every new
frame, straight trajectories of 10 frames with speed ratios 0.8–1.2 through the matrix, the one
with the smallest summed difference wins; 6. a match is kept only if the best score is below 0.9
times the best score outside its neighbourhood (uniqueness), otherwise the previous match is
advanced by the speed ratio. It assumes both drives moved at similar speeds along similar lines of
sight, which is what the thesis found it to fail on.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import cv2
import numpy as np

from egovid.dashcam.align.orb import Alignment

SIZE = (64, 32)
PATCH = 8


def descriptor(gray: np.ndarray) -> np.ndarray:
    """The patch-normalised 64 x 32 image (float32) of a grey frame."""
    small = cv2.resize(gray, SIZE, interpolation=cv2.INTER_AREA).astype(np.float32)
    h, w = small.shape
    p = small.reshape(h // PATCH, PATCH, w // PATCH, PATCH).transpose(0, 2, 1, 3)
    mu = p.mean(axis=(2, 3), keepdims=True)
    sd = p.std(axis=(2, 3), keepdims=True)
    p = (p - mu) / np.maximum(sd, 1e-3)
    return p.transpose(0, 2, 1, 3).reshape(h, w)


class SeqslamSearch:
    """SeqSLAM one new frame at a time: a frame's match depends on its own and the ``seq_len`` − 1
    previous rows of the contrast-enhanced difference matrix, each computed from the reference
    descriptors in a band of ``band`` frames around the GPS prior (``ref_desc(j)``, j < ``m``)."""

    def __init__(
        self,
        ref_desc: Callable[[int], np.ndarray],
        m: int,
        prior: np.ndarray,
        *,
        band: int = 60,
        seq_len: int = 10,
        speeds: tuple[float, float] = (0.8, 1.2),
        n_speeds: int = 9,
        window: int = 10,
        uniqueness: float = 0.9,
    ) -> None:
        self.ref_desc, self.m, self.prior = ref_desc, m, prior
        self.band, self.seq_len, self.window, self.uniqueness = band, seq_len, window, uniqueness
        self.vs = np.linspace(speeds[0], speeds[1], n_speeds)
        self.rows: deque[np.ndarray] = deque(maxlen=seq_len)
        self.prev: int | None = None
        self.fallbacks = 0

    def _row(self, i: int, desc: np.ndarray) -> np.ndarray:
        """Row i of the contrast-enhanced differences (4 = "no match" outside the band)."""
        m = self.m
        e = np.full(m, np.float32(4.0))
        c = round(self.prior[i])
        lo, hi = max(0, c - self.band), min(m, c + self.band + 1)
        if lo >= hi:
            return e
        a = desc.reshape(-1)
        b = np.stack([self.ref_desc(j).reshape(-1) for j in range(lo, hi)])
        vals = np.abs(b - a).mean(axis=1).astype(np.float32)
        half = self.window // 2
        for t in range(len(vals)):
            seg = vals[max(0, t - half) : t + half + 1]
            e[lo + t] = (vals[t] - seg.mean()) / max(seg.std(), 1e-6)
        return e

    def step(self, i: int, desc: np.ndarray) -> int:
        """The match of new frame ``i`` (frames come in order)."""
        m = self.m
        self.rows.append(self._row(i, desc))
        half = self.window // 2
        cols = np.arange(m)
        lo_i = max(0, i - self.seq_len + 1)
        best = np.full(m, np.inf)
        for v in self.vs:
            total = np.zeros(m)
            for t in range(lo_i, i + 1):
                j = np.round(cols - v * (i - t)).astype(int)
                ok = (j >= 0) & (j < m)
                total += np.where(ok, self.rows[t - i - 1][np.clip(j, 0, m - 1)], 4.0)
            best = np.minimum(best, total / (i - lo_i + 1))
        j_best = int(np.argmin(best))
        # Uniqueness on positive scores (enhanced differences shifted by the "no match" level).
        pos = best + 5.0
        outside = np.concatenate([pos[: max(0, j_best - half)], pos[j_best + half + 1 :]])
        unique = np.isfinite(pos[j_best]) and (len(outside) == 0 or pos[j_best] < self.uniqueness * np.min(outside))
        if not unique:
            j_best = int(np.clip(round(self.prior[i]), 0, m - 1)) if self.prev is None else min(m - 1, self.prev + 1)
            self.fallbacks += 1
        self.prev = j_best
        return j_best


def align_seqslam(new_desc: np.ndarray, ref_desc: np.ndarray, prior: np.ndarray, **kwargs) -> Alignment:
    """Align (N, 32, 64) new descriptors to (M, 32, 64) reference descriptors (see
    :class:`SeqslamSearch` for the keyword arguments)."""
    search = SeqslamSearch(ref_desc.__getitem__, len(ref_desc), prior, **kwargs)
    refmap = np.array([search.step(i, d) for i, d in enumerate(new_desc)], np.int64)
    return Alignment(refmap, np.zeros(len(refmap), np.int64), search.fallbacks, "seqslam")
