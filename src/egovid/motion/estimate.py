"""Estimate per-frame camera rotations of a video (thesis ch. 6), streaming.

Pipeline: decode a downscaled grey copy → keypoints once per frame → pairwise rotations to the
frames ``lags`` back (default 1 and 5) → robust SO(3) pose graph → orientations. Only the last
``max(lags)`` frames' features are held in memory, so memory does not grow with video length
(apart from one 3x3 matrix per frame and per edge).
"""

from __future__ import annotations

import math
import os
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from egovid.errors import EgovidError
from egovid.io.camera import Intrinsics
from egovid.io.trajectory import Trajectory
from egovid.io.video import iter_frames, probe
from egovid.motion.features import FeatureExtractor, FrameFeatures, Matcher
from egovid.motion.pairwise import PairRotation, relative_rotation
from egovid.motion.posegraph import Edge, chain, optimize

#: Width (pixels) of the grey copy that features are extracted from.
DEFAULT_WORK_WIDTH = 640


@dataclass
class MotionOptions:
    """Tuning of :func:`estimate_motion`.

    ``lags`` are the frame distances of the pose-graph edges (thesis: 1 and l = 5);
    ``work_width`` the width in pixels of the downscaled copy used for features.
    """

    lags: tuple[int, ...] = (1, 5)
    features: str = "orb"
    n_features: int = 800
    work_width: int = DEFAULT_WORK_WIDTH
    threshold_px: float = 1.0
    refine: bool = True
    threads: int = 2


def _capped(info: np.ndarray | None, deg_per_px: float) -> np.ndarray | None:
    """Limit an edge's information to a floor of 0.02 px noise per point: below that the
    residuals no longer measure noise but interpolation and compression artefacts."""
    if info is None:
        return None
    limit = 1.0 / math.radians(0.02 * deg_per_px) ** 2 * 500
    w, V = np.linalg.eigh(0.5 * (info + info.T))
    return (V * np.minimum(np.maximum(w, 0.0), limit)) @ V.T


@dataclass
class MotionEstimate:
    """Result of :func:`estimate_motion`.

    ``trajectory`` holds the pose-graph orientations (frame 0 = identity); ``chained`` those of
    plain lag-1 chaining (eq. 6.1) for comparison; ``pairs`` the per-edge diagnostics.
    """

    trajectory: Trajectory
    chained: np.ndarray
    intrinsics: Intrinsics
    pairs: list[tuple[int, int, PairRotation]] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def failed_pairs(self) -> int:
        """Number of frame pairs whose rotation could not be estimated."""
        return sum(1 for _, _, p in self.pairs if not p.ok)


def estimate_motion(
    video: str | os.PathLike,
    intrinsics: Intrinsics | None = None,
    options: MotionOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> MotionEstimate:
    """Per-frame camera rotations of ``video``.

    Parameters
    ----------
    intrinsics:
        Camera of the full-resolution video (default: :meth:`Intrinsics.default`).
    progress:
        Optional ``progress(frames_done, frames_expected)`` callback.

    Raises :class:`EgovidError` for unreadable videos and videos with fewer than 2 frames.
    """
    opts = options or MotionOptions()
    if not opts.lags or min(opts.lags) < 1 or 1 not in opts.lags:
        raise EgovidError(f"lags {opts.lags} must include 1 and be positive", "use e.g. --lags 1,5")
    info = probe(video)
    intr = intrinsics or Intrinsics.default(info.width, info.height)
    if (intr.width, intr.height) != (info.width, info.height):
        raise EgovidError(
            f"intrinsics are for {intr.width}x{intr.height} but the video is {info.width}x{info.height}",
            "give --focal for this video's resolution",
        )
    scale = min(1.0, opts.work_width / info.width)
    work = intr.scaled(scale)
    K = work.K
    deg_per_px = math.degrees(1.0 / work.focal)
    extractor = FeatureExtractor(opts.features, opts.n_features)
    matcher = Matcher(extractor.binary)
    max_lag = max(opts.lags)
    window: deque[tuple[int, FrameFeatures]] = deque(maxlen=max_lag)
    pairs: list[tuple[int, int, PairRotation]] = []
    times: list[float] = []
    t_start = time.perf_counter()

    def pair_job(i: int, fi: FrameFeatures, j: int, fj: FrameFeatures) -> tuple[int, int, PairRotation]:
        pi, pj = matcher(fi, fj)
        images = (fi.image, fj.image) if opts.refine else None
        return i, j, relative_rotation(pi, pj, K, threshold_px=opts.threshold_px, images=images)

    pool = ThreadPoolExecutor(max_workers=max(1, opts.threads))
    try:
        pending = []
        for frame in iter_frames(video, gray=True, scale=scale if scale < 1.0 else None):
            if frame.image.shape[1] != work.width or frame.image.shape[0] != work.height:
                # FFmpeg may round the scaled size differently; follow the actual image.
                work = intr.scaled(frame.image.shape[1] / intr.width)
                K = work.K
            feats = extractor(frame.image)
            k = frame.index
            for lag in opts.lags:
                if len(window) >= lag:
                    j, fj = window[-lag]
                    pending.append(pool.submit(pair_job, j, fj, k, feats))
            window.append((k, feats))
            times.append(frame.time)
            if len(pending) > 8:
                pairs.extend(f.result() for f in pending[:-4])
                pending = pending[-4:]
            if progress is not None:
                progress(k + 1, info.frame_count)
        pairs.extend(f.result() for f in pending)
    finally:
        pool.shutdown(wait=True)
    n = len(times)
    if n < 2:
        raise EgovidError(f"{video} has {n} frame; motion needs at least 2", "give a longer video")
    t_pairs = time.perf_counter()
    # Q from relative_rotation maps camera-j to camera-i coordinates for points (i = earlier):
    # we matched (earlier, later) as (fi, fj) with fi = earlier, so Q = R_earlier.T R_later.
    edges = [Edge(i, j, p.Q, info=_capped(p.info, deg_per_px)) for i, j, p in pairs if p.ok]
    failed_steps = {i for i, j, p in pairs if j == i + 1 and not p.ok}
    for i in failed_steps:
        # Keep the graph connected through a frame that could not be matched: a weak "no
        # rotation" edge that the longer edges can override.
        edges.append(Edge(i, i + 1, np.eye(3), 5.0))
    chained = chain(n, edges)
    R = optimize(n, edges, init=chained)
    t_graph = time.perf_counter()
    traj = Trajectory(np.asarray(times), R)
    return MotionEstimate(
        trajectory=traj,
        chained=chained,
        intrinsics=intr,
        pairs=pairs,
        seconds={"pairs": t_pairs - t_start, "graph": t_graph - t_pairs, "total": t_graph - t_start},
    )
