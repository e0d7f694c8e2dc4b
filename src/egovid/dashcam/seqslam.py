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

import cv2
import numpy as np

from egovid.dashcam.align import Alignment

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


def align_seqslam(
    new_desc: np.ndarray,
    ref_desc: np.ndarray,
    prior: np.ndarray,
    *,
    band: int = 60,
    seq_len: int = 10,
    speeds: tuple[float, float] = (0.8, 1.2),
    n_speeds: int = 9,
    window: int = 10,
    uniqueness: float = 0.9,
) -> Alignment:
    """Align (N, 32, 64) new descriptors to (M, 32, 64) reference descriptors."""
    n, m = len(new_desc), len(ref_desc)
    a = new_desc.reshape(n, -1)
    b = ref_desc.reshape(m, -1)
    big = 1e6
    D = np.full((n, m), big, np.float32)
    for i in range(n):
        c = round(prior[i])
        lo, hi = max(0, c - band), min(m, c + band + 1)
        if lo < hi:
            D[i, lo:hi] = np.abs(b[lo:hi] - a[i]).mean(axis=1)
    # Local contrast enhancement along the reference axis.
    E = np.full_like(D, np.float32(4.0))  # contrast-enhanced differences; 4 = "no match" outside the band
    half = window // 2
    for i in range(n):
        row = D[i]
        valid = row < big
        idx = np.flatnonzero(valid)
        if len(idx) == 0:
            continue
        vals = row[idx]
        for t, j in enumerate(idx):
            seg = vals[max(0, t - half) : t + half + 1]
            E[i, j] = (vals[t] - seg.mean()) / max(seg.std(), 1e-6)
    refmap = np.zeros(n, np.int64)
    score = np.zeros(n)
    vs = np.linspace(speeds[0], speeds[1], n_speeds)
    prev = None
    fallbacks = 0
    cols = np.arange(m)
    for i in range(n):
        lo_i = max(0, i - seq_len + 1)
        best = np.full(m, np.inf)
        for v in vs:
            total = np.zeros(m)
            for t in range(lo_i, i + 1):
                j = np.round(cols - v * (i - t)).astype(int)
                ok = (j >= 0) & (j < m)
                total += np.where(ok, E[t, np.clip(j, 0, m - 1)], 4.0)
            best = np.minimum(best, total / (i - lo_i + 1))
        j_best = int(np.argmin(best))
        # Uniqueness on positive scores (enhanced differences shifted by the "no match" level).
        pos = best + 5.0
        outside = np.concatenate([pos[: max(0, j_best - half)], pos[j_best + half + 1 :]])
        unique = np.isfinite(pos[j_best]) and (len(outside) == 0 or pos[j_best] < uniqueness * np.min(outside))
        if not unique:
            j_best = int(np.clip(round(prior[i]), 0, m - 1)) if prev is None else min(m - 1, prev + 1)
            fallbacks += 1
        refmap[i] = j_best
        score[i] = best[j_best] if np.isfinite(best[j_best]) else 0
        prev = j_best
    return Alignment(refmap, np.zeros(n, np.int64), fallbacks, "seqslam")
