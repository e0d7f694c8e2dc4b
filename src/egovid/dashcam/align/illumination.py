"""Illumination matching (thesis §15.3.2): pick, among older drives of the same path, the one
whose light is most like the new drive's.

Per frame, the grey image is cut into four quadrants (upper ones see the sky, sun and clouds,
lower ones the road and shadows; left and right tell where shadows and sun are). For each quadrant
the feature is (mean, C) with Tamura's contrast ``C = σ / α4^¼``, ``α4 = μ4/σ⁴`` the kurtosis
(the thesis' "fourth moment"). A sequence's feature is the average over its frames. Each candidate
is ranked per quadrant by the distance of its features to the new sequence's; the rank scores
(best = K points, worst = 1) are summed over the quadrants and the highest total wins, so one
quadrant spoiled by an overtaking truck cannot decide alone. A candidate whose light differs too
much everywhere is no match: the new sequence then becomes a root (intra-coded).
"""

from __future__ import annotations

import numpy as np

QUADRANTS = ("upper-left", "upper-right", "lower-left", "lower-right")
#: Largest per-quadrant feature distance (grey levels) for a usable reference.
MAX_DISTANCE = 45.0


def frame_features(gray: np.ndarray) -> np.ndarray:
    """(8,) = (mean, C) for each quadrant of a grey image, in the order of :data:`QUADRANTS`."""
    g = np.asarray(gray, dtype=np.float64)
    h, w = g.shape
    out = np.empty(8)
    for k, (ys, xs) in enumerate(
        (
            (slice(0, h // 2), slice(0, w // 2)),
            (slice(0, h // 2), slice(w // 2, w)),
            (slice(h // 2, h), slice(0, w // 2)),
            (slice(h // 2, h), slice(w // 2, w)),
        )
    ):
        q = g[ys, xs]
        mu = q.mean()
        d = q - mu
        var = float(np.mean(d * d))
        if var < 1e-9:
            out[2 * k], out[2 * k + 1] = mu, 0.0
            continue
        kurt = float(np.mean(d**4)) / var**2
        out[2 * k] = mu
        out[2 * k + 1] = np.sqrt(var) / kurt**0.25
    return out


def quadrant_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(4,) Euclidean distance of the (mean, C) features per quadrant."""
    return np.hypot(a[0::2] - b[0::2], a[1::2] - b[1::2])


def rank_scores(new: np.ndarray, candidates: dict[int, np.ndarray]) -> dict[int, int]:
    """Summed per-quadrant rank scores of every candidate (higher = more similar light)."""
    ids = list(candidates)
    if not ids:
        return {}
    D = np.array([quadrant_distances(new, candidates[i]) for i in ids])  # (K, 4)
    K = len(ids)
    score = np.zeros(K, dtype=int)
    for q in range(4):
        order = np.argsort(D[:, q], kind="stable")
        score[order] += K - np.arange(K)
    return {i: int(s) for i, s in zip(ids, score, strict=True)}


def best_match(new: np.ndarray, candidates: dict[int, np.ndarray], max_distance: float = MAX_DISTANCE) -> int | None:
    """The candidate with the highest rank score (ties: smallest total distance), or None when no
    candidate's light is within ``max_distance`` in at least two quadrants."""
    usable = {i: f for i, f in candidates.items() if np.sum(quadrant_distances(new, f) <= max_distance) >= 2}
    if not usable:
        return None
    scores = rank_scores(new, usable)
    return max(usable, key=lambda i: (scores[i], -float(np.sum(quadrant_distances(new, usable[i])))))
