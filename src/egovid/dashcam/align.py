"""Timeline alignment (thesis §15.2.1): for every frame of the new drive, the frame of the older
drive taken at the same place.

The best reference frame is the one sharing the most RANSAC-consistent ORB matches with the
current frame: key points only match at a similar scale, so many matches mean the two frames were
taken from nearly the same spot. ORB suits this better than scale-invariant features, which also
match across different scales. Frames are compared on a 320-pixel-wide grey copy.

Search (§15.2.1, Fig. 15.4): one-directional (the car never drives backwards, so the match of a
frame is at or after the previous match) within an adaptive range S estimated from the number of
reference frames passed per frame in the last second, scaled by the change of the speed ratio
between the drives. The first frame is searched around the GPS prior (the reference frame at the
same position along the path). If matches become too few, the GPS prior takes over until
matching recovers. Stopped frames keep the previous match.

Two refinements of ours (``aligner="orb"``; ``"orb-plain"`` is the thesis' search alone): the
match sequence is smoothed (median then mean over 9 frames, kept monotone), because inlier counts
of neighbouring frames are noisy; then each match is re-chosen within ±2 frames by the smallest
mean absolute difference of mean-normalised 160 x 90 luma. ORB alone picks frames 0.4 frames ahead
on average (near objects match best when a little larger); the refinement brings the matches to
within 0.1 frame of the ground truth on synthetic drives and cuts the bitstream by 10 %
(``benchmarks/dashcam_bdrate.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from egovid.motion.features import FeatureExtractor, FrameFeatures

WORK_WIDTH = 320
MIN_INLIERS = 12


def small_gray(i420: np.ndarray, width: int, height: int, work_width: int = WORK_WIDTH) -> np.ndarray:
    """The Y plane of an I420 frame downscaled to ``work_width`` (area averaging)."""
    y = i420[:height, :width]
    s = work_width / width
    if s >= 1:
        return np.ascontiguousarray(y)
    return cv2.resize(y, (work_width, max(2, round(height * s))), interpolation=cv2.INTER_AREA)


class OrbScorer:
    """ORB features per frame and the RANSAC inlier count of a frame pair (cached)."""

    def __init__(self, n_features: int = 500) -> None:
        self.extract = FeatureExtractor("orb", n_features)
        self._bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
        self._cache: dict[tuple[int, int], int] = {}

    def features(self, gray: np.ndarray) -> FrameFeatures:
        return self.extract(gray)

    def inliers(self, a: FrameFeatures, b: FrameFeatures, key: tuple[int, int] | None = None) -> int:
        if key is not None and key in self._cache:
            return self._cache[key]
        n = 0
        if a.desc is not None and b.desc is not None and len(a) >= 8 and len(b) >= 8:
            m = self._bf.match(a.desc, b.desc)
            if len(m) >= 8:
                pa = a.pts[[x.queryIdx for x in m]]
                pb = b.pts[[x.trainIdx for x in m]]
                F, mask = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 1.5, 0.99, 200)
                if F is not None and mask is not None:
                    n = int(mask.sum())
        if key is not None:
            self._cache[key] = n
        return n


@dataclass
class Alignment:
    """Reference frame (index into the reference sequence) of every new frame, the inlier count
    that chose it (0 = prior or held), and how many frames fell back to the GPS prior."""

    refmap: np.ndarray
    inliers: np.ndarray
    prior_fallbacks: int
    method: str


def align_orb(
    new_feats: list[FrameFeatures],
    ref_feats: list[FrameFeatures],
    prior: np.ndarray,
    speed_new: np.ndarray,
    speed_ref: np.ndarray,
    stopped: np.ndarray,
    fps: float,
    scorer: OrbScorer | None = None,
) -> Alignment:
    """Align new frames to reference frames (both lists of ORB features, in time order).

    ``prior`` (N,) is the reference frame at the same GPS position as each new frame (float);
    ``speed_new`` (N,), ``speed_ref`` (M,) the speeds in m/s; ``stopped`` (N,) the stop mask.
    """
    scorer = scorer or OrbScorer()
    scorer._cache.clear()  # keys are frame indices of this alignment
    n, m = len(new_feats), len(ref_feats)
    refmap = np.zeros(n, np.int64)
    inl = np.zeros(n, np.int64)
    fallbacks = 0
    prev = None
    history: list[int] = []
    ratio_prev = None
    wide = max(6, int(1.5 * fps))
    # Metres the reference advances per frame, to turn the GPS error into a tolerance in frames.
    ref_step = np.maximum(np.asarray(speed_ref, dtype=float) / fps, 0.05)
    for k in range(n):
        p = int(np.clip(round(prior[k]), 0, m - 1))
        if prev is not None and stopped[k]:
            refmap[k], inl[k] = prev, 0
            continue
        if prev is None:
            cands = range(max(0, p - wide), min(m, p + wide + 1))
        else:
            # Reference frames passed per new frame: the speed ratio of the drives, scaled like the
            # thesis' S by how the ratio changed since the last second's mean step.
            ratio = float(np.clip(speed_new[k] / max(speed_ref[min(prev, m - 1)], 0.5), 0.0, 4.0))
            steps = np.diff(history[-int(fps) :]) if len(history) > 1 else np.array([ratio])
            mean_step = float(np.mean(steps)) if len(steps) else ratio
            if ratio_prev and ratio_prev > 0.05:
                mean_step *= ratio / ratio_prev
            ratio_prev = ratio
            S = math.ceil(min(max(mean_step, ratio), 2.0 * ratio + 0.5) * 2.0) + 1
            cands = range(prev, min(m, prev + S + 1))
        scored = [(scorer.inliers(new_feats[k], ref_feats[j], (k, j)), j) for j in cands]
        best_n = max((c for c, _ in scored), default=-1)
        # Ties within 5 % go to the earliest frame: ORB favours frames slightly ahead.
        best_j = next((j for c, j in scored if c >= 0.95 * best_n), None) if best_n > 0 else None
        tol = 15.0 / ref_step[min(p, m - 1)]
        if best_j is None or best_n < MIN_INLIERS:
            # Matching failed: follow the GPS prior (never backwards).
            best_j = p if prev is None else max(prev, p)
            best_n = 0
            fallbacks += 1
        elif prev is not None and abs(best_j - prior[k]) > tol:
            # Far from where GPS says (a false match, or drift): re-search around the prior.
            cands = range(max(prev, p - wide), min(m, p + wide + 1))
            scored = [(scorer.inliers(new_feats[k], ref_feats[j], (k, j)), j) for j in cands]
            if scored:
                best_n, best_j = max(scored)
        refmap[k], inl[k] = best_j, best_n
        prev = int(best_j)
        history.append(prev)
    return Alignment(refmap, inl, fallbacks, "orb")


def tiny(i420: np.ndarray, width: int, height: int) -> np.ndarray:
    """Mean-normalised 160 x 90 luma (float32) for photometric refinement."""
    g = cv2.resize(i420[:height, :width], (160, 90), interpolation=cv2.INTER_AREA).astype(np.float32)
    return g - g.mean()


def smooth_monotone(refmap: np.ndarray, window: int = 9) -> np.ndarray:
    """Median then mean filter of a match sequence, kept non-decreasing."""
    from scipy.ndimage import median_filter, uniform_filter1d

    if len(refmap) < 3:
        return refmap.copy()
    x = median_filter(refmap.astype(float), window, mode="nearest")
    x = uniform_filter1d(x, window, mode="nearest")
    return np.maximum.accumulate(np.round(x).astype(np.int64))


def refine_photometric(
    refmap: np.ndarray, tiny_new: list[np.ndarray], tiny_ref: list[np.ndarray], radius: int = 2
) -> np.ndarray:
    """Re-choose each match within ``radius`` frames by the smallest mean absolute luma difference."""
    out = refmap.copy()
    m = len(tiny_ref)
    for k, t in enumerate(tiny_new):
        lo, hi = max(0, refmap[k] - radius), min(m, refmap[k] + radius + 1)
        costs = [float(np.mean(np.abs(t - tiny_ref[j]))) for j in range(lo, hi)]
        if costs:
            out[k] = lo + int(np.argmin(costs))
    return out
