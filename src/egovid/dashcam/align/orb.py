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

Two refinements of ours (``aligner="orb"``; ``"orb-plain"`` is the thesis' search alone): the match
sequence is smoothed (median then a local line over 9 frames, kept monotone), because inlier counts
of neighbouring frames are noisy; then :class:`ScaleRefiner` re-chooses each match within ±3 frames
as the frame at which the *vertical image scale* between the two frames is 1, i.e. where the older
camera stood level with the new one. The joint codec is sensitive to this: on the different-day
drives, using the ground-truth frame ±1 instead of the ground truth costs 4–7 points of BD-rate. The
vertical scale is blind to a lane offset (sideways motion moves image points horizontally); the full
similarity scale was biased by 0.2–0.25 frames on drives 0.15–0.2 m to the side. On the synthetic
different-day drives the matches land 0.07–0.10 frames from the ground truth on average (the earlier
photometric re-choice: 0.24–0.76), and the different-day set's BD-rate saving rises from 29.6 to
31.4 %, level with the ground truth's 31.5 % (``benchmarks/dashcam_bdrate.py``; docs/dashcam.md).
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from egovid.core.motion.features import FeatureExtractor, FrameFeatures

WORK_WIDTH = 320
MIN_INLIERS = 12


def small_gray(i420: np.ndarray, width: int, height: int, work_width: int = WORK_WIDTH) -> np.ndarray:
    """The Y plane of an I420 frame downscaled to ``work_width`` (area averaging)."""
    y = i420[:height, :width]
    s = work_width / width
    if s >= 1:
        return np.ascontiguousarray(y)
    return cv2.resize(y, (work_width, max(2, round(height * s))), interpolation=cv2.INTER_AREA)


@numba.njit(nogil=True, cache=True)
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (x * np.uint64(0x0101010101010101)) >> np.uint64(56)


@numba.njit(nogil=True, cache=True)
def _cross_check(a, b):
    """Mutual nearest neighbours of (n, w) and (m, w) uint64 bit strings; row by row, so the inner
    loops run over b and vectorise."""
    n, m, w = a.shape[0], b.shape[0], a.shape[1]
    bt = b.T.copy()
    row = np.empty(m, np.int32)
    best_b = np.full(m, 1 << 30, np.int32)
    arg_b = np.full(m, -1, np.int64)
    arg_a = np.empty(n, np.int64)
    for i in range(n):
        row[:] = 0
        for t in range(w):
            at = a[i, t]
            for j in range(m):
                row[j] += np.int32(_popcount(at ^ bt[t, j]))
        arg_a[i] = np.argmin(row)
        for j in range(m):
            better = row[j] < best_b[j]
            best_b[j] = row[j] if better else best_b[j]
            arg_b[j] = i if better else arg_b[j]
    keep = np.zeros(n, np.bool_)
    for i in range(n):
        keep[i] = arg_b[arg_a[i]] == i
    qi = np.flatnonzero(keep)
    return qi, arg_a[qi]


def cross_check_matches(desc_a: np.ndarray, desc_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours of two sets of binary descriptors ((N, 32) uint8, Hamming
    distance): (indices into a, indices into b), in the order of a — what OpenCV's
    ``BFMatcher(NORM_HAMMING, crossCheck=True)`` returns (ties to the lowest index), about 10 times
    faster than the pip build of OpenCV, which counts bits by table look-up."""
    if len(desc_a) == 0 or len(desc_b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if desc_a.shape[1] % 8:
        pad = 8 - desc_a.shape[1] % 8
        desc_a, desc_b = (np.pad(d, ((0, 0), (0, pad))) for d in (desc_a, desc_b))
    a = np.ascontiguousarray(desc_a).view(np.uint64)
    b = np.ascontiguousarray(desc_b).view(np.uint64)
    return _cross_check(a, b)


_WARM = threading.Lock()
_warmed: list[threading.Thread] = []


def warm_up() -> None:
    """Load the compiled matcher in a background thread (once per process): numba's first call
    takes about 0.4-0.6 s even from its on-disk cache, and would otherwise land in the first frame's
    search, while the encoder waits for its first baseline."""
    with _WARM:
        if not _warmed:
            z = np.zeros((8, 32), np.uint8)
            t = threading.Thread(target=cross_check_matches, args=(z, z), name="egovid-warm-up", daemon=True)
            t.start()
            _warmed.append(t)


class MatchCache:
    """:func:`cross_check_matches` remembering its last ``size`` results, for an aligner whose
    search and refinement look at the same pairs of features (one thread)."""

    def __init__(self, size: int = 256) -> None:
        self.size = size
        self._memo: dict[tuple[int, int], tuple] = {}

    def __call__(self, desc_a: np.ndarray, desc_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = (id(desc_a), id(desc_b))
        hit = self._memo.get(key)
        if hit is not None and hit[0] is desc_a and hit[1] is desc_b:
            return hit[2]
        out = cross_check_matches(desc_a, desc_b)
        self._memo[key] = (desc_a, desc_b, out)  # holding the arrays keeps their ids unique
        if len(self._memo) > self.size:
            del self._memo[next(iter(self._memo))]
        return out


class OrbScorer:
    """ORB features per frame and the RANSAC inlier count of a frame pair (cached). ``matcher``:
    the cross-check matcher (default :func:`cross_check_matches`; a :class:`MatchCache` shares
    matches with the refinement)."""

    def __init__(self, n_features: int = 500, matcher: Callable | None = None) -> None:
        self.extract = FeatureExtractor("orb", n_features)
        self.matcher = matcher or cross_check_matches
        self._cache: dict[tuple[int, int], int] = {}

    def features(self, gray: np.ndarray) -> FrameFeatures:
        """Key points of a grey frame (the frame itself is not kept)."""
        f = self.extract(gray)
        f.image = None
        return f

    def inliers(self, a: FrameFeatures, b: FrameFeatures, key: tuple[int, int] | None = None) -> int:
        if key is not None and key in self._cache:
            return self._cache[key]
        n = 0
        if a.desc is not None and b.desc is not None and len(a) >= 8 and len(b) >= 8:
            qi, ti = self.matcher(a.desc, b.desc)
            if len(qi) >= 8:
                pa, pb = a.pts[qi], b.pts[ti]
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


class OrbSearch:
    """The thesis' search (§15.2.1), one new frame at a time (see the module docstring).

    ``ref_feats(j)`` gives the ORB features of reference frame j (0 … ``m`` − 1; asked in a window
    that only moves forward, from the current match up to the search range, or ``1.5 s`` around the
    GPS prior); ``prior`` (N,) is the reference frame at the same GPS position as each new frame
    (float); ``speed_new`` (N,), ``speed_ref`` (M,) the speeds in m/s; ``stopped`` (N,) the stop
    mask; ``fps`` the new drive's frame rate."""

    def __init__(
        self,
        ref_feats: Callable[[int], FrameFeatures],
        m: int,
        prior: np.ndarray,
        speed_new: np.ndarray,
        speed_ref: np.ndarray,
        stopped: np.ndarray,
        fps: float,
        scorer: OrbScorer | None = None,
        coarse: int = 1,
    ) -> None:
        self.ref_feats, self.m = ref_feats, m
        self.coarse = max(1, int(coarse))
        self.prior, self.speed_new, self.speed_ref, self.stopped = prior, speed_new, speed_ref, stopped
        self.fps = fps
        self.scorer = scorer or OrbScorer()
        self.fallbacks = 0
        self.prev: int | None = None
        self.history: list[int] = []
        self.moved: list[int] = []  # moving frames seen up to each history entry
        self.n_moving = 0
        self.ratio_prev: float | None = None
        # Metres the reference advances per frame, to turn the GPS error into a tolerance in frames.
        self.ref_step = np.maximum(np.asarray(speed_ref, dtype=float) / fps, 0.05)

    def lowest_needed(self) -> int:
        """No reference frame below this will be asked for again."""
        return 0 if self.prev is None else self.prev

    def skip(self, k: int) -> None:
        """New frame ``k`` is not searched (the caller interpolates its match)."""
        if not self.stopped[k]:
            self.n_moving += 1

    def _score(self, k: int, feat: FrameFeatures, cands: range, wide: bool) -> list[tuple[int, int]]:
        """(inliers, j) of the candidates, in order of j. A wide search (around the GPS prior) with
        ``coarse`` = c > 1 scores every c-th candidate, then the c − 1 either side of the best:
        inlier counts rise and fall over several frames, and the prior's window holds 3 s of
        reference frames, scored once per drive but at the start, while the encoder waits."""
        scorer = self.scorer
        if not wide or self.coarse == 1 or len(cands) <= 3 * self.coarse:
            return [(scorer.inliers(feat, self.ref_feats(j), (k, j)), j) for j in cands]
        c = self.coarse
        got = {j: scorer.inliers(feat, self.ref_feats(j), (k, j)) for j in cands[::c]}
        best = max(got.items(), key=lambda t: (t[1], -t[0]))[0]
        for j in range(max(cands.start, best - c + 1), min(cands.stop, best + c)):
            if j not in got:
                got[j] = scorer.inliers(feat, self.ref_feats(j), (k, j))
        return [(got[j], j) for j in sorted(got)]

    def step(self, k: int, feat: FrameFeatures) -> tuple[int, int]:
        """The match of new frame ``k`` (frames come in order; those in between may be
        :meth:`skip`-ped) and the inlier count that chose it (0: held over a stop, or the GPS
        prior)."""
        m, prev, fps, prior = self.m, self.prev, self.fps, self.prior
        scorer = self.scorer
        scorer._cache.clear()  # keys are (k, j) of this frame only
        p = int(np.clip(round(prior[k]), 0, m - 1))
        if prev is not None and self.stopped[k]:
            return prev, 0
        self.n_moving += 1
        wide = None
        if prev is None:
            wide = cands = wide_window(p, m, fps)
        else:
            # Reference frames passed per new frame: the speed ratio of the drives, scaled like the
            # thesis' S by how the ratio changed since the last second's mean step. S covers twice
            # the expected step; after skipped frames, the steps since the last search and one more.
            ratio = float(np.clip(self.speed_new[k] / max(self.speed_ref[min(prev, m - 1)], 0.5), 0.0, 4.0))
            gap = self.n_moving - self.moved[-1]
            span = max(1, int(fps) // gap)
            hist, moved = self.history[-span:], self.moved[-span:]
            mean_step = (hist[-1] - hist[0]) / (moved[-1] - moved[0]) if len(hist) > 1 else ratio
            if self.ratio_prev and self.ratio_prev > 0.05:
                mean_step *= ratio / self.ratio_prev
            self.ratio_prev = ratio
            S = math.ceil(min(max(mean_step, ratio), 2.0 * ratio + 0.5) * (gap + 1)) + 1
            cands = range(prev, min(m, prev + S + 1))
        scored = self._score(k, feat, cands, wide is not None)
        best_n = max((c for c, _ in scored), default=-1)
        # Ties within 5 % go to the earliest frame: ORB favours frames slightly ahead.
        best_j = next((j for c, j in scored if c >= 0.95 * best_n), None) if best_n > 0 else None
        tol = 15.0 / self.ref_step[min(p, m - 1)]
        if best_j is None or best_n < MIN_INLIERS:
            # Matching failed: follow the GPS prior (never backwards).
            best_j = p if prev is None else max(prev, p)
            best_n = 0
            self.fallbacks += 1
        elif prev is not None and abs(best_j - prior[k]) > tol:
            # Far from where GPS says (a false match, or drift): re-search around the prior.
            cands = wide_window(p, m, fps, low=prev)
            scored = self._score(k, feat, cands, True)
            if scored:
                best_n, best_j = max(scored)
        self.prev = int(best_j)
        self.history = [*self.history[-int(fps) :], self.prev]
        self.moved = [*self.moved[-int(fps) :], self.n_moving]
        return int(best_j), int(best_n)


def wide_window(p: int, m: int, fps: float, low: int = 0) -> range:
    """The reference frames (of ``m``) a wide search around the GPS prior's frame ``p`` scores:
    1.5 s either side (at least 6 frames), none below ``low``."""
    half = max(6, int(1.5 * fps))
    return range(max(low, p - half), min(m, p + half + 1))


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
    """Align new frames to reference frames (both lists of ORB features, in time order; see
    :class:`OrbSearch`)."""
    search = OrbSearch(ref_feats.__getitem__, len(ref_feats), prior, speed_new, speed_ref, stopped, fps, scorer)
    n = len(new_feats)
    refmap = np.zeros(n, np.int64)
    inl = np.zeros(n, np.int64)
    for k in range(n):
        refmap[k], inl[k] = search.step(k, new_feats[k])
    return Alignment(refmap, inl, search.fallbacks, "orb")


def _filter_stretch(x: np.ndarray, window: int, median: int | None, length: int) -> np.ndarray:
    """Median then local-line filter of ``x``, a stretch of ``length`` frames (or a slice of one:
    the filter sizes follow the whole stretch)."""
    from scipy.ndimage import median_filter  # heavy (3 s to import under load): only where aligning

    y = median_filter(x, min(median or window, length), mode="nearest")
    n = min(window, length)
    return _line_filter(y, n - (1 - n % 2))  # an odd window of >= 3


def _line_filter(y: np.ndarray, wl: int) -> np.ndarray:
    """SciPy's ``savgol_filter(y, wl, 1, mode="interp")`` (a least-squares line over ``wl`` frames,
    odd; the first and last ``wl // 2`` values on the line through the first and last ``wl``),
    computed directly: the same values to rounding, 30 times faster on the short slices the
    streamed smoothing filters (SciPy solves for the coefficients on every call). Each output
    depends only on its own window's values, whatever the slice around it."""
    n, h = len(y), wl // 2
    if n < wl:
        from scipy.signal import savgol_filter  # heavy (10 s to import under load): only where needed

        return savgol_filter(y, wl, 1, mode="interp")
    out = np.empty(n)
    out[h : n - h] = np.convolve(y, np.full(wl, 1.0 / wl), "valid")  # the line at each window's centre
    t = np.arange(-h, h + 1, dtype=float)
    head, tail = y[:wl], y[n - wl :]
    for w, at, ts in ((head, slice(0, h), t[:h]), (tail, slice(n - h, n), t[h + 1 :])):
        mean = w.sum() / wl
        out[at] = mean + float(t @ (w - mean)) / float(t @ t) * ts
    return out


def _stretches(moving: np.ndarray) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.concatenate([[0], moving.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def smooth_monotone(
    refmap: np.ndarray, window: int = 9, median: int | None = None, stopped: np.ndarray | None = None
) -> np.ndarray:
    """Median (``median`` frames, default ``window``) then local-line (``window`` frames;
    Savitzky-Golay of order 1, which keeps a steady slope exact up to the ends, where a moving mean
    would pull it towards the end value) filter of a match sequence (reference frame per new
    frame, may be fractional), rounded and kept non-decreasing. With ``stopped``, each stretch
    between stops is filtered on its own (a line cannot follow the corner of a stop) and stopped
    frames repeat the previous match. :class:`StreamSmoother` gives the same, frame by frame."""
    x = np.asarray(refmap, dtype=float).copy()
    moving = np.ones(len(x), bool) if stopped is None else ~np.asarray(stopped, bool)
    for a, b in _stretches(moving):
        if b - a >= 3:
            x[a:b] = _filter_stretch(x[a:b], window, median, b - a)
    out = np.maximum.accumulate(np.round(x).astype(np.int64))
    for k in range(1, len(out)):
        if not moving[k]:
            out[k] = out[k - 1]
    return out


class StreamSmoother:
    """:func:`smooth_monotone` of an ``n``-frame sequence whose values arrive one at a time: each
    output is given as soon as the inputs it depends on are known (``reach`` = median half-width +
    line half-width frames ahead; at the start of a stretch, a window's worth), computed on a slice
    that reproduces the whole-sequence filter exactly."""

    def __init__(self, n: int, window: int = 9, median: int | None = None, stopped: np.ndarray | None = None) -> None:
        self.n, self.window, self.median = n, window, median
        self.x = np.zeros(n)
        self.moving = np.ones(n, bool) if stopped is None else ~np.asarray(stopped, bool)
        self.stretch = np.full(n, -1, np.int64)
        self.bounds: list[tuple[int, int]] = _stretches(self.moving)
        for i, (a, b) in enumerate(self.bounds):
            self.stretch[a:b] = i
        self.known = 0  # inputs 0 … known − 1 are in
        self.done = 0  # outputs 0 … done − 1 are out
        self.reach = (median or window) // 2 + window // 2
        self._last = 0
        self._acc = -(1 << 62)

    def _needs(self, k: int) -> int:
        """The last input index output ``k`` depends on."""
        if not self.moving[k]:
            return k
        a, b = self.bounds[self.stretch[k]]
        half, med = self.window // 2, (self.median or self.window) // 2
        if b - a < 3:
            return k
        if b - a < self.window + med + 1:
            return b - 1  # a short stretch: every output depends on all of it
        if k < a + half:
            return a + self.window - 1 + med
        if k >= b - half:
            return b - 1
        return min(b - 1, k + self.reach)

    def _value(self, k: int) -> float:
        if not self.moving[k]:
            return float(self.x[k])
        a, b = self.bounds[self.stretch[k]]
        if b - a < 3:
            return float(self.x[k])
        e = self._needs(k) + 1
        s = max(a, k - self.reach)  # outputs this far from a cut slice's edge are not affected by it
        if e == b:  # the line fitted to the stretch's last frames needs them all
            s = max(a, min(s, b - self.window - self.reach))
        return float(_filter_stretch(self.x[s:e], self.window, self.median, b - a)[k - s])

    def push(self, value: float) -> list[int]:
        """Add the next input; returns the outputs that became final, in order (as
        :func:`smooth_monotone`: rounded, non-decreasing, stopped frames repeating the previous)."""
        self.x[self.known] = value
        self.known += 1
        out = []
        while self.done < self.n and self._needs(self.done) < self.known:
            k = self.done
            self._acc = max(self._acc, int(np.round(self._value(k))))
            v = self._acc if k == 0 or self.moving[k] else out[-1] if out else self._last
            self._last = v
            out.append(v)
            self.done += 1
        return out


def vertical_log_scale(new: FrameFeatures, ref: FrameFeatures, matcher: Callable | None = None) -> float | None:
    """Natural log of the vertical image scale from a new frame to a reference frame (> 0: the
    reference shows the scene larger, i.e. was taken further along the road), from ORB matches:
    RANSAC similarity inliers, then ``y_ref = a·y_new + b`` by least squares with outliers trimmed
    (residual > max(1 px, 3 × median)). None with fewer than 12 matches or 10 inliers.

    Vertical, because moving sideways (another lane) shifts image points horizontally only, while
    moving along the road scales both coordinates about the focus of expansion."""
    if new.desc is None or ref.desc is None or len(new) < 12 or len(ref) < 12:
        return None
    qi, ti = (matcher or cross_check_matches)(new.desc, ref.desc)
    if len(qi) < 12:
        return None
    p = new.pts[qi].astype(np.float32)
    q = ref.pts[ti].astype(np.float32)
    _, inl = cv2.estimateAffinePartial2D(p, q, method=cv2.RANSAC, ransacReprojThreshold=2.0)
    if inl is None or inl.sum() < 10:
        return None
    keep = inl.ravel().astype(bool)
    y, yr = p[keep, 1].astype(np.float64), q[keep, 1].astype(np.float64)
    a = 0.0
    for _ in range(3):
        A = np.stack([y, np.ones_like(y)], axis=1)
        (a, b), *_ = np.linalg.lstsq(A, yr, rcond=None)
        r = np.abs(a * y + b - yr)
        ok = r <= max(1.0, 3.0 * float(np.median(r)))
        y, yr = y[ok], yr[ok]
        if len(y) < 8:
            break
    return float(np.log(a)) if a > 0 else None


class ScaleRefiner:
    """Re-chooses each match to the reference frame taken at the same distance along the road, to
    sub-frame precision (the ``orb`` aligner's refinement of the thesis' search).

    For a new frame, the vertical log scale (:func:`vertical_log_scale`) to the reference frames
    within ``radius`` of its match grows with the reference index; a least-squares line through
    it crosses zero where the older camera stood level with the new one. The crossings are median
    (5 frames) and local-line (``window`` frames) filtered, rounded, kept monotone and inside the
    reference sequence; frames with fewer than 3 measured scales keep their match, stopped frames
    take the previous one. Uses its own ORB
    (1000 key points, OpenCV's default pyramid) on the 320-pixel-wide grey frames: the scale needs
    more and finer-scaled points than the inlier count of the search does. ``n_features`` 0: the
    caller passes the search's features instead (one ORB per frame; with a shared
    :class:`MatchCache` as ``matcher`` the pairs the search matched are not matched again)."""

    def __init__(
        self, n_features: int = 1000, radius: int = 3, window: int = 9, matcher: Callable | None = None
    ) -> None:
        self.n_features = n_features
        self._orb = cv2.ORB_create(n_features) if n_features else None
        self.radius, self.window = radius, window
        self.matcher = matcher

    def features(self, gray: np.ndarray) -> FrameFeatures:
        """Key points of a grey frame from :func:`small_gray`."""
        kps, desc = self._orb.detectAndCompute(gray, None)
        return FrameFeatures(np.array([k.pt for k in kps], np.float32).reshape(-1, 2), desc)

    def refine(
        self,
        refmap: np.ndarray,
        new_feats: list[FrameFeatures],
        ref_feats: list[FrameFeatures],
        stopped: np.ndarray,
    ) -> np.ndarray:
        """``refmap`` (N,) re-chosen; ``new_feats``/``ref_feats`` from :meth:`features`;
        ``stopped`` (N,) the stop mask. Frames are measured in parallel threads (the matcher
        releases the GIL); the result does not depend on the thread count."""
        from concurrent.futures import ThreadPoolExecutor

        m = len(ref_feats)
        moving = [k for k in range(len(new_feats)) if not stopped[k]]
        x = refmap.astype(float)
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            x[moving] = list(
                pool.map(lambda k: self.crossing(int(refmap[k]), new_feats[k], ref_feats.__getitem__, m), moving)
            )
        return np.clip(smooth_monotone(x, self.window, median=5, stopped=stopped), 0, m - 1)

    def crossing(self, match: int, new: FrameFeatures, ref_feats: Callable[[int], FrameFeatures], m: int) -> float:
        """Where the vertical log scale between a new frame and the reference frames within
        ``radius`` of its ``match`` crosses zero (a fractional reference frame index; the match
        itself when fewer than 3 scales could be measured)."""
        js, ls = [], []
        for j in range(max(0, match - self.radius), min(m, match + self.radius + 1)):
            v = vertical_log_scale(new, ref_feats(j), self.matcher)
            if v is not None:
                js.append(j)
                ls.append(v)
        if len(js) >= 3:
            slope, icpt = np.polyfit(np.array(js, float), np.array(ls), 1)
            if slope > 1e-4:
                return float(np.clip(-icpt / slope, js[0], js[-1]))
        return float(match)
