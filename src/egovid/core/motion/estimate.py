"""Estimate per-frame camera rotations of a video from the pictures (thesis ch. 6), streaming.

Pipeline: decode a downscaled grey copy (in presentation order) → keypoints once per frame →
pairwise rotations to the frame 1 back and, on every other frame taking turns, 2 or 5 back
(``lags``, ``long_every``) → the constant
bias of the longer pairs removed → SO(3) pose graph with the noise of each edge group
calibrated from the data → orientations, whose frame-to-frame detail (above ``detail_hz``)
comes from the distance-1 pairs (:func:`steps_detail`). Only the last ``max(lags)``
frames' features are held in memory, so memory does not grow with video length (apart from one
3x3 matrix per frame and per edge, and the matched points of the first ``keep_matches`` frames
when asked for, for a focal-length fit).

Nothing here raises on a decodable video: pairs with too few features (black or featureless
frames, tiny pictures) or a failed fit are bridged, by the gyro when the caller has one
(``bridge``), else by interpolating the angular velocity across the gap, and flagged in
:attr:`MotionEstimate.confidence`. Results are deterministic: exact brute-force matching, seeded
RANSAC and an ordered reduction of the parallel pair jobs give identical output on every run.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import partial

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.motion.features import FeatureExtractor, FrameFeatures, Matcher
from egovid.core.motion.pairwise import PairRotation, correspondences, rotation_from_correspondences
from egovid.core.motion.posegraph import Edge, chain, optimize
from egovid.core.motion.rolling_shutter import undistort_fisheye
from egovid.core.rotations import so3_exp, so3_log
from egovid.core.trajectory import Trajectory
from egovid.core.video import iter_frames, probe

#: Width (pixels) of the grey copy that features are extracted from.
DEFAULT_WORK_WIDTH = 640
#: Stated noise (degrees) of an edge that only interpolates across a gap; weak on purpose.
BRIDGE_SIGMA_DEG = 1.0
#: Frequency (Hz) above which orientations follow the distance-1 steps, below it the pose graph.
STEPS_DETAIL_HZ = 1.0
#: Confidence of a frame step: measured by its own pair, only by longer pairs or the gyro, guessed.
CONF_MEASURED, CONF_SPANNED, CONF_INTERPOLATED = 1.0, 0.5, 0.0


LONG_DELAY = 6  # frames between a frame and the choice of its longer pairs (long_every > 1)


@dataclass
class MotionOptions:
    """Tuning of :func:`estimate_motion`.

    ``lags`` are the frame distances of the pose-graph edges: every frame is paired with the
    previous one, and the longer distances take turns on every ``long_every``-th frame (default
    1, 2, 5 on every other frame: frame i is paired with i + 2 when i % 4 == 0 and with i + 5
    when i % 4 == 2, 1.5 pairs per frame, and every step is still spanned by a longer pair; near
    a failed distance-1 pair, on every frame, as they are all that bridges it; the
    thesis uses 1 and 5 on every frame, which leaves a 5-periodic error on real footage, see
    :mod:`egovid.core.motion.posegraph`). The longer pairs only hold the slow drift of chaining once
    the frame-to-frame detail comes from the distance-1 pairs (``detail_hz``): with
    ``detail_hz=None`` (the graph alone) give ``long_every=1``, or ``long_every=0``: every
    distance on every frame (``len(lags)`` pairs per frame), the graph then a rotation average
    whose per-frame error is below the distance-1 pairs' (a synthetic walk past near things,
    lags 1, 2, 4: 0.069° against the chain's 0.097° per frame, ``tests/test_motion.py``; on the
    real HERO6 walk it was worse than the default, 0.44 against 0.24°/frame, docs/fpv.md);
    ``work_width`` the width in pixels of the downscaled copy used for features;
    ``keep_matches`` keeps the refined point matches of pairs within the first that many frames
    (for :func:`refit`; there the longer pairs are measured on every frame, for the focal-length
    fit); ``calibrate`` scales each edge group's noise to its residuals;
    ``max_frames`` stops after that many frames; above ``detail_hz`` (Hz) the orientations follow
    the distance-1 pairs and below it the pose graph (:func:`steps_detail`; None: the graph alone).
    """

    lags: tuple[int, ...] = (1, 2, 5)
    features: str = "orb"
    n_features: int = 500
    work_width: int = DEFAULT_WORK_WIDTH
    threshold_px: float = 1.0
    refine: bool = True
    threads: int = 2
    keep_matches: int = 0
    calibrate: bool = True
    max_frames: int | None = None
    detail_hz: float | None = STEPS_DETAIL_HZ
    long_every: int = 2


def _capped(info: np.ndarray | None, deg_per_px: float) -> np.ndarray | None:
    """Limit an edge's information to a floor of 0.02 px noise per point: below that the
    residuals no longer measure noise but interpolation and compression artefacts."""
    if info is None:
        return None
    limit = 1.0 / math.radians(0.02 * deg_per_px) ** 2 * 500
    w, V = np.linalg.eigh(0.5 * (info + info.T))
    return (V * np.minimum(np.maximum(w, 0.0), limit)) @ V.T


@dataclass
class PairSet:
    """The pairwise measurements of a video: frame ``times`` (N,) seconds, ``pairs`` as
    ``(i, j, PairRotation)`` with ``i < j``, the ``work`` intrinsics of the downscaled copy they
    were measured in, and ``matches[(i, j)] = (pts_i, pts_j)`` (work pixels) where kept."""

    times: np.ndarray
    pairs: list[tuple[int, int, PairRotation]]
    work: Intrinsics
    matches: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    threshold_px: float = 1.0
    seconds: float = 0.0

    def __len__(self) -> int:
        return len(self.times)


@dataclass
class MotionEstimate:
    """Result of :func:`estimate_motion`.

    ``trajectory`` holds the pose-graph orientations (frame 0 = identity); ``chained`` those of
    plain lag-1 chaining (eq. 6.1) for comparison; ``pairs`` the per-edge diagnostics;
    ``confidence`` (N,) per frame: 1 = the step from the previous frame was measured by its own
    pair, 0.5 = only by longer pairs or the gyro, 0 = interpolated across a gap;
    ``noise_scale`` the calibrated variance factor per edge group.
    """

    trajectory: Trajectory
    chained: np.ndarray
    intrinsics: Intrinsics
    pairs: list[tuple[int, int, PairRotation]] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    confidence: np.ndarray | None = None
    noise_scale: dict[str, float] = field(default_factory=dict)
    pairset: PairSet | None = field(default=None, repr=False)

    @property
    def failed_pairs(self) -> int:
        """Number of frame pairs whose rotation could not be estimated."""
        return sum(1 for _, _, p in self.pairs if not p.ok)


def collect_pairs(
    video: str | os.PathLike,
    intrinsics: Intrinsics | None = None,
    options: MotionOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> PairSet:
    """Decode ``video`` once and measure the rotation of every frame pair at the ``lags``.

    Raises :class:`EgovidError` for unreadable videos and bad options; never for what the
    pictures contain.
    """
    opts = options or MotionOptions()
    if not opts.lags or min(opts.lags) < 1 or 1 not in opts.lags:
        raise EgovidError(f"lags {opts.lags} must include 1 and be positive", "use e.g. --lags 1,5")
    if opts.long_every < 0:
        raise EgovidError(
            f"long_every {opts.long_every} must be 0 (every distance on every frame) or more", "use 0, 1 or 2"
        )
    info = probe(video)
    intr = intrinsics or Intrinsics.default(info.width, info.height)
    if (intr.width, intr.height) != (info.width, info.height):
        raise EgovidError(
            f"intrinsics are for {intr.width}x{intr.height} but the video is {info.width}x{info.height}",
            "give --focal for this video's resolution",
        )
    scale = min(1.0, opts.work_width / info.width)
    work = intr.scaled(scale)
    times: list[float] = []
    t_start = time.perf_counter()
    cv2.setRNGSeed(12345)
    # The solver's libraries take ~1 s to import; the pair jobs leave the interpreter free most of
    # the time (OpenCV and the compiled fit run without the GIL), so import them meanwhile.
    threading.Thread(target=_import_solver, name="import-solver", daemon=True).start()
    with _PairScheduler(opts, intr.distortion) as scheduler:
        for frame in iter_frames(video, gray=True, scale=scale if scale < 1.0 else None, max_frames=opts.max_frames):
            if frame.image.shape[1] != work.width or frame.image.shape[0] != work.height:
                # FFmpeg may round the scaled size differently; follow the actual image.
                work = intr.scaled(frame.image.shape[1] / intr.width)
            scheduler.add(frame.index, frame.image, work.K)
            times.append(frame.time)
            if progress is not None:
                progress(frame.index + 1, info.frame_count)
        scheduler.finish(work.K)
    rank = {lag: r for r, lag in enumerate(opts.lags)}
    pairs = sorted(scheduler.pairs, key=lambda p: (p[1], rank[p[1] - p[0]]))  # by frame, then lag
    return PairSet(np.asarray(times), pairs, work, scheduler.matches, opts.threshold_px, time.perf_counter() - t_start)


class _PairScheduler:
    """The pair jobs of :func:`collect_pairs` on a thread pool: keypoints of each frame as it is
    decoded, its distance-1 pair at once, its longer pairs ``delay`` frames later (see
    :data:`LONG_DELAY`); only the last ``max(lags) + delay + 1`` frames' features are held."""

    def __init__(self, opts: MotionOptions, distortion: tuple[float, ...] | None = None) -> None:
        # A fisheye lens (OpenCV k1..k4; all zero is the equidistant one, not a pinhole): fit the rays.
        self.distortion = tuple(distortion) if distortion is not None else None
        self.opts = opts
        self.matcher = Matcher(FeatureExtractor(opts.features, opts.n_features).binary)
        self.local = threading.local()
        self.max_lag = max(opts.lags)
        self.long_lags = sorted(set(opts.lags) - {1})
        # With long_every > 1 the longer pairs ending at a frame are chosen LONG_DELAY frames later,
        # once the distance-1 pairs around it are measured: near a failed step they follow the
        # every-frame schedule (the longer pairs are all that bridges it).
        self.delay = LONG_DELAY if opts.long_every > 1 and self.long_lags else 0
        self.window: deque[tuple[int, Future[FrameFeatures]]] = deque(maxlen=self.max_lag + self.delay + 1)
        self.steps: dict[int, Future] = {}  # j -> the distance-1 pair (j - 1, j)
        self.pending: list[Future] = []
        self.pairs: list[tuple[int, int, PairRotation]] = []
        self.matches: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self.pool = ThreadPoolExecutor(max_workers=max(1, opts.threads))

    def __enter__(self) -> _PairScheduler:
        return self

    def __exit__(self, *exc) -> None:
        self.pool.shutdown(wait=True)

    def add(self, k: int, image: np.ndarray, K: np.ndarray) -> None:
        """Frame ``k``'s grey work image: its keypoints, its pair with frame k - 1, the longer
        pairs now due."""
        # Keypoints in the pool too: decoding (the caller) overlaps detection and matching (here).
        feats = self.pool.submit(self._features_job, image)
        if self.window:
            j, fj = self.window[-1]
            self.steps[k] = self.pool.submit(self._pair_job, j, fj, k, feats, K)
            self.pending.append(self.steps[k])
        self.window.append((k, feats))
        if k - self.delay >= self.window[0][0]:
            self._schedule_long(k - self.delay, K)
        if len(self.pending) > 8:
            self._collect(f.result() for f in self.pending[:-4])
            self.pending = self.pending[-4:]

    def finish(self, K: np.ndarray) -> None:
        """The longer pairs of the last frames (still to be chosen), then every result."""
        if self.window:
            last = self.window[-1][0]
            for t in range(max(self.window[0][0], last - self.delay + 1), last + 1):
                self._schedule_long(t, K)
        self._collect(f.result() for f in self.pending)

    def _features_job(self, image: np.ndarray) -> FrameFeatures:
        # One extractor per worker thread (OpenCV's detectors keep state between calls).
        ex = getattr(self.local, "extractor", None)
        if ex is None:
            ex = self.local.extractor = FeatureExtractor(self.opts.features, self.opts.n_features)
        return ex(image)

    def _pair_job(self, i: int, ffi: Future[FrameFeatures], j: int, ffj: Future[FrameFeatures], K: np.ndarray):
        # The features of both frames were submitted before this job, so they are running or
        # done in another worker (first in, first out): waiting here cannot deadlock.
        opts = self.opts
        fi, fj = ffi.result(), ffj.result()
        pi, pj = self.matcher(fi, fj)
        images = (fi.image, fj.image) if opts.refine else None
        undistort = None
        if self.distortion is not None:  # a calibrated fisheye lens: select and fit the rays, not the pixels
            undistort = partial(undistort_fisheye, K=K, distortion=self.distortion)
        found = correspondences(pi, pj, K, threshold_px=opts.threshold_px, images=images, undistort=undistort)
        if found is None:
            return i, j, PairRotation(np.eye(3), 0, len(pi), "none", False), None
        keep = found if j < opts.keep_matches else None  # raw work pixels (see rolling_shutter.refit_pairs)
        if undistort is not None:
            found = (undistort(found[0]), undistort(found[1]))
        return i, j, rotation_from_correspondences(*found, K, threshold_px=opts.threshold_px), keep

    def _collect(self, results) -> None:
        for i, j, p, keep in results:
            self.pairs.append((i, j, p))
            if keep is not None:
                self.matches[(i, j)] = keep

    def _failed_near(self, t: int) -> bool:
        """Whether a distance-1 pair among the steps a longer pair ending at ``t`` can span failed."""
        for s in range(t - self.max_lag + 1, t + 1):
            f = self.steps.get(s)
            if f is not None and not f.result()[2].ok:
                return True
        return False

    def _schedule_long(self, t: int, K: np.ndarray) -> None:
        """Submit the longer pairs ending at frame ``t`` (its features and its partners' are in
        the window)."""
        feats_of = dict(self.window)
        # Pairs whose matches are kept serve a focal-length fit, which needs pairs that turn
        # enough (the longer ones do most): there, every frame gets its longer pair.
        every = self.opts.long_every if t >= self.opts.keep_matches or self.opts.long_every == 0 else 1
        if every > 1 and self._failed_near(t):
            every = 1
        for lag in self.long_lags:
            if t - lag in feats_of and _scheduled(t - lag, lag, self.long_lags, every):
                self.pending.append(self.pool.submit(self._pair_job, t - lag, feats_of[t - lag], t, feats_of[t], K))
        for s in [s for s in self.steps if s <= t - self.max_lag]:
            del self.steps[s]


def _import_solver() -> None:
    """Import what :func:`solve_motion` needs (GTSAM, SciPy's filters); failures are left to the
    solver's own import, which reports them."""
    try:
        import gtsam  # noqa: F401
        import scipy.signal  # noqa: F401
    except Exception:  # the solver imports them again and says what is wrong
        pass


def _scheduled(i: int, lag: int, long_lags: list[int], every: int = 1) -> bool:
    """Whether frame ``i`` is paired with frame ``i + lag``: always at distance 1; the longer
    distances take turns on every ``every``-th frame (with lags 1, 2, 5 and ``every`` 1: frame
    i is paired with i + 2 when i is even and with i + 5 when i is odd; with ``every`` 2, with
    i + 2 when i % 4 == 0 and with i + 5 when i % 4 == 2), so each frame costs 1 + 1/every
    pairs on average whatever the count; with ``every`` 0, every distance on every frame."""
    if lag == 1 or not long_lags or every == 0:
        return True
    return i % (every * len(long_lags)) == every * long_lags.index(lag)


def remove_closure_bias(pairs: list[tuple[int, int, PairRotation]]) -> list[tuple[int, int, PairRotation]]:
    """Longer pairs with the constant bias they show against the chained distance-1 pairs removed.

    On real footage the rotation measured over a longer distance is biased (lens distortion the
    pinhole model misses, parallax the essential model trades against rotation): on the GoPro
    clip the distance-5 pairs turn 0.05° less than the five distance-1 pairs they span, in pitch
    and roll, which made the pose graph drift 2.8° against the gyro. The median closure residual
    ``Log((Q_{i,i+1}···Q_{j-1,j})ᵀ Q_ij)`` per distance estimates that bias; with it removed, the
    longer pairs still correct the random walk of chaining, not its constant drift (which no
    pair of this video can tell from a bias).
    """
    step = {i: p.Q for i, j, p in pairs if p.ok and j == i + 1}
    out = list(pairs)
    by_lag: dict[int, list[tuple[int, np.ndarray]]] = {}
    for k, (i, j, p) in enumerate(pairs):
        if p.ok and j - i > 1 and all(m in step for m in range(i, j)):
            C = np.eye(3)
            for m in range(i, j):
                C = C @ step[m]
            by_lag.setdefault(j - i, []).append((k, so3_log(C.T @ p.Q)))
    for items in by_lag.values():
        if len(items) < 10:
            continue
        bias = np.median(np.array([r for _, r in items]), axis=0)
        fix = so3_exp(-bias)
        for k, _ in items:
            i, j, p = pairs[k]
            out[k] = (i, j, replace(p, Q=p.Q @ fix))
    return out


def refit(pairs: PairSet, full: Intrinsics, focal_px: float) -> PairSet:
    """The pair set re-fitted for another focal length ``focal_px`` (pixels of the full-resolution
    video whose intrinsics were ``full``), from the kept matches; pairs without kept matches are
    left as they were. Cheap: no decoding, matching or RANSAC, only the final fits."""
    sx, sy = pairs.work.width / full.width, pairs.work.height / full.height
    work = Intrinsics(pairs.work.width, pairs.work.height, focal_px * sx, focal_px * sy, pairs.work.cx, pairs.work.cy)
    out = []
    for i, j, p in pairs.pairs:
        m = pairs.matches.get((i, j))
        out.append((i, j, rotation_from_correspondences(*m, work.K, threshold_px=pairs.threshold_px) if m else p))
    return PairSet(pairs.times, out, work, pairs.matches, pairs.threshold_px, pairs.seconds)


def solve_motion(
    pairs: PairSet,
    intrinsics: Intrinsics,
    *,
    bridge: np.ndarray | None = None,
    extra_edges: list[Edge] | None = None,
    calibrate: bool = True,
    detail_hz: float | None = STEPS_DETAIL_HZ,
) -> MotionEstimate:
    """Orientations of all frames from the pairs (and ``extra_edges``, e.g. gyro factors).

    ``bridge`` (N, 3, 3) camera-to-world rotations from another source (the synced gyro) fill the
    steps no vision pair measured; without it those steps interpolate the angular velocity of
    their neighbours. Each frame's confidence says which. Without ``extra_edges``, the result
    follows the distance-1 pairs above ``detail_hz`` (:func:`steps_detail`); with them (the gyro's
    steps) the graph alone decides.
    """
    t0 = time.perf_counter()
    n = len(pairs.times)
    if n == 0:
        raise EgovidError("the video has no frames", "give a video with at least one frame")
    deg_per_px = math.degrees(1.0 / pairs.work.focal)
    debiased = remove_closure_bias(pairs.pairs) if calibrate else pairs.pairs
    edges = [Edge(i, j, p.Q, info=_capped(p.info, deg_per_px)) for i, j, p in debiased if p.ok]
    measured = np.zeros(max(n - 1, 0), bool)
    spanned = np.zeros(max(n - 1, 0), bool)
    for e in edges:
        if e.j == e.i + 1:
            measured[e.i] = True
        else:
            spanned[e.i : e.j] = True
    conf_steps = np.where(measured, CONF_MEASURED, np.where(spanned, CONF_SPANNED, CONF_INTERPOLATED))
    gaps = np.flatnonzero(~measured)
    if len(gaps):
        if bridge is not None:
            for k in gaps:
                edges.append(Edge(k, k + 1, bridge[k].T @ bridge[k + 1], 0.05, group="bridge-gyro"))
            conf_steps[gaps] = np.maximum(conf_steps[gaps], CONF_SPANNED)
        else:
            edges += _interpolated_steps(gaps, edges, n)
    if extra_edges:
        edges += extra_edges
    chained = chain(n, edges)
    report: dict = {}
    R = optimize(n, edges, init=chained, calibrate=calibrate, report=report)
    if not extra_edges and detail_hz is not None:
        # Steps no distance-1 pair measured (gaps) come from the graph, where longer pairs span them.
        own = {e.i: e.Q for e in edges if e.j == e.i + 1 and e.group not in ("bridge", "bridge-gyro")}
        steps = [own.get(k, R[k].T @ R[k + 1]) for k in range(n - 1)]
        R = steps_detail(R, steps, pairs.times, detail_hz)
    conf = np.concatenate([[conf_steps[0] if len(conf_steps) else CONF_INTERPOLATED], conf_steps])
    return MotionEstimate(
        trajectory=Trajectory(pairs.times, R),
        chained=chained,
        intrinsics=intrinsics,
        pairs=pairs.pairs,
        seconds={
            "pairs": pairs.seconds,
            "graph": time.perf_counter() - t0,
            "total": pairs.seconds + time.perf_counter() - t0,
        },
        confidence=conf,
        noise_scale=report.get("noise_scale", {}),
        pairset=pairs,
    )


def steps_detail(
    graph: np.ndarray, steps: list[np.ndarray], times: np.ndarray, cutoff_hz: float = STEPS_DETAIL_HZ
) -> np.ndarray:
    """Orientations ((N, 3, 3) camera-to-world) that follow the pose graph ``graph`` below
    ``cutoff_hz`` and the chained frame steps ``steps`` ((N-1) rotations ``R_kᵀR_{k+1}``, the
    distance-1 pairs) above it (a complementary filter).

    The longer pairs are there to stop the random walk of chaining, a slow error; frame to frame,
    their errors are larger than a distance-1 pair's (on real footage parallax, rolling shutter and
    lens distortion grow with the distance, and no closure bias removes the part that changes
    from pair to pair), and the graph spreads them over the frames they span, with the period of
    the lags. On the handheld phone clip this put 0.025 px of high-frequency image motion (>3 Hz,
    480 px width) into the difference between the picture's own shift and the motion the
    rotations predict; the chained steps leave 0.017 px. So the steps' difference from the graph's
    steps is high-passed (zero-phase Butterworth, order 2, in each frame's axes) and added to the
    graph's steps: the result drifts no more than the graph and jitters no more than the chain.
    Clips too short to filter keep the graph.
    """
    from scipy.signal import butter, sosfiltfilt

    n = len(graph)
    dt = np.diff(times)
    if n < 16 or not np.all(np.isfinite(dt)) or np.median(dt) <= 0:
        return graph
    fs = 1.0 / float(np.median(dt))
    if cutoff_hz >= 0.45 * fs:
        return graph
    sos = butter(2, cutoff_hz, btype="lowpass", fs=fs, output="sos")

    def high(x: np.ndarray) -> np.ndarray:
        return x - sosfiltfilt(sos, x, axis=0, padtype="even")

    # In each frame's own axes: the difference of the steps (a constant bias of the frame steps is
    # constant there, whatever the camera does), high-passed, on top of the graph's steps...
    g = so3_log(np.swapaxes(graph[:-1], 1, 2) @ graph[1:])
    c = so3_log(np.asarray(steps))
    E = so3_exp(g + high(c - g))
    R = np.empty_like(graph)
    R[0] = graph[0]
    for k in range(n - 1):
        R[k + 1] = R[k] @ E[k]
    # ...then what the composition still drifts from the graph is taken off again.
    off = so3_log(np.swapaxes(graph, 1, 2) @ R)
    return graph @ so3_exp(high(off))


def _interpolated_steps(gaps: np.ndarray, edges: list[Edge], n: int) -> list[Edge]:
    """Weak edges across unmeasured steps: the mean angular velocity of the nearest measured
    steps before and after (no rotation when there are none), so the graph stays connected and
    longer edges that span the gap can override them."""
    steps = {e.i: so3_log(e.Q) for e in edges if e.j == e.i + 1}
    known = np.array(sorted(steps))
    out = []
    for k in gaps:
        near = []
        if len(known):
            pos = np.searchsorted(known, k)
            if pos > 0:
                near.append(steps[int(known[pos - 1])])
            if pos < len(known):
                near.append(steps[int(known[pos])])
        w = np.mean(near, axis=0) if near else np.zeros(3)
        out.append(Edge(int(k), int(k) + 1, so3_exp(w), BRIDGE_SIGMA_DEG, group="bridge"))
    return out


def estimate_motion(
    video: str | os.PathLike,
    intrinsics: Intrinsics | None = None,
    options: MotionOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> MotionEstimate:
    """Per-frame camera rotations of ``video`` from the pictures alone.

    Parameters
    ----------
    intrinsics:
        Camera of the full-resolution video (default: :meth:`Intrinsics.default`; see
        :func:`egovid.core.camera.resolve.resolve_camera` for the file's own).
    progress:
        Optional ``progress(frames_done, frames_expected)`` callback.

    Raises :class:`EgovidError` for unreadable videos; a video of one frame gives one identity
    orientation with confidence 0.
    """
    opts = options or MotionOptions()
    info = probe(video)
    intr = intrinsics or Intrinsics.default(info.width, info.height)
    pairs = collect_pairs(video, intr, opts, progress)
    return solve_motion(pairs, intr, calibrate=opts.calibrate, detail_hz=opts.detail_hz)
