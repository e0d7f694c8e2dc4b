"""2D Viewing Experience (thesis §8.4, eq. 8.14–8.18) from dense optical flow.

The frames are split into I x J regions (10 x 20); a target starts at each region's centre at
every frame k and is carried along by the optical flow (OpenCV DIS, on a downscaled grey copy)
for N = 30 frames. Its angular position in the viewer's eye is (eq. 8.14)

    α_x = atan((x - w/2) / sqrt((y - h/2)² + d²)),   α_y likewise,

with the viewing distance d in pixels (d/f times the focal length). We use the signed offset
``x - w/2``; eq. 8.14's absolute value would fold a target that crosses the screen centre and
invent a position error there. PE is the second difference of α (eq. 8.15), the retinal slip
ω = FPS · PE (eq. 8.16 divides by FPS, which would make condition 7.8 unsatisfiable: DESIGN.md),
and a target is pursued at frame n + 2 when conditions (7.8) or (7.9) hold for both directions
(the 2D bias b = 0.038°). A failure starts a catch-up saccade of 5 frames during which nothing is
tracked ("1011111" → "1000001"); a target that leaves the frame is lost for the rest of the
segment. The first two frames of a segment count as tracked. The 2D-VE of the video is the RMS
over segments of the mean tracked fraction (eq. 8.18).

Frame rate: like the 3D scores, the model runs at 30 fps (:mod:`egovid.fpv.perception.model`). A
segment starts at every frame and follows its targets for one model segment (N = 30 samples, 1 s);
at other rates the targets' angular tracks are resampled in time to the model's 30 fps before the
conditions are checked, so the same motion filmed at 25 or 60 fps scores the same.

Memory is bounded: only the active segments' tracks (one model segment long) are kept.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.video import iter_frames, probe
from egovid.fpv.perception.model import MODEL_FPS, ViewingModel, is_model_rate, model_times, resample
from egovid.fpv.perception.score import rms


@dataclass
class VE2DResult:
    """2D-VE of a video: per-segment values (segment k starts at frame k) and their RMS."""

    score: float
    segments: np.ndarray
    fps: float
    frames: int
    seconds: float
    params: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "method": "ve2d",
            "score": self.score,
            "fps": self.fps,
            "frames": self.frames,
            "params": self.params,
            "segments": self.segments.round(6).tolist(),
        }


def _bilinear(flow: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flow vectors at float positions (flow image coordinates), edge-clamped."""
    h, w = flow.shape[:2]
    xc = np.clip(x, 0, w - 1.001)
    yc = np.clip(y, 0, h - 1.001)
    x0 = xc.astype(np.int64)
    y0 = yc.astype(np.int64)
    fx, fy = xc - x0, yc - y0
    f00 = flow[y0, x0]
    f01 = flow[y0, x0 + 1]
    f10 = flow[y0 + 1, x0]
    f11 = flow[y0 + 1, x0 + 1]
    top = f00 * (1 - fx)[..., None] + f01 * fx[..., None]
    bot = f10 * (1 - fx)[..., None] + f11 * fx[..., None]
    v = top * (1 - fy)[..., None] + bot * fy[..., None]
    return v[..., 0], v[..., 1]


def grid_centres(width: int, height: int, rows: int = 10, cols: int = 20) -> np.ndarray:
    """(rows*cols, 2) pixel centres of an I x J grid of regions."""
    xs = (np.arange(cols) + 0.5) * width / cols - 0.5
    ys = (np.arange(rows) + 0.5) * height / rows - 0.5
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()])


class _Segments:
    """Targets of the active segments, advanced one flow at a time.

    ``n`` is the segment length in samples at the model's 30 fps; at another ``fps`` a segment
    follows its targets over the native frames that span those ``n`` samples, and the angular
    tracks are resampled to the model's grid when the segment is complete."""

    def __init__(self, intr: Intrinsics, model: ViewingModel, fps: float, n: int, rows: int, cols: int):
        self.intr = intr
        self.n = n
        self.sacc = model.saccade_frames
        mar, x_lo, x_hi = model.pe_bounds()
        self.mar = math.radians(mar)
        self.x_lo = math.radians(x_lo)
        self.x_hi = math.radians(x_hi)
        self.d = model.d_over_f * intr.focal
        self.start = grid_centres(intr.width, intr.height, rows, cols)
        self.native = is_model_rate(fps)
        self.fps = fps
        # Native frames a segment needs to cover its n model samples (n - 1 steps of 1/30 s).
        self.n_frames = n if self.native else math.ceil((n - 1) / MODEL_FPS * fps - 1e-9) + 1
        self.active: list[dict] = []
        self.done: list[float] = []

    def _alpha(self, p: np.ndarray) -> np.ndarray:
        cx, cy = self.intr.width / 2.0, self.intr.height / 2.0
        dx, dy = p[..., 0] - cx, p[..., 1] - cy
        ax = np.arctan2(dx, np.sqrt(dy * dy + self.d * self.d))
        ay = np.arctan2(dy, np.sqrt(dx * dx + self.d * self.d))
        return np.stack([ax, ay], axis=-1)

    def _ok(self, pe: np.ndarray) -> np.ndarray:
        x = np.abs(pe)
        good = (x < self.mar) | ((x >= self.x_lo) & (x <= self.x_hi))
        return good[..., 0] & good[..., 1]

    def begin(self) -> None:
        p = self.start.copy()
        self.active.append({"pos": [p], "inside": [np.ones(len(p), bool)]})

    def advance(self, flow: np.ndarray, scale: float) -> None:
        """Move every active target by ``flow`` (computed at ``scale`` of full resolution)."""
        w, h = self.intr.width, self.intr.height
        for seg in self.active:
            p = seg["pos"][-1]
            u, v = _bilinear(flow, (p[:, 0] + 0.5) * scale - 0.5, (p[:, 1] + 0.5) * scale - 0.5)
            q = p + np.column_stack([u, v]) / scale
            inside = (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
            seg["pos"].append(q)
            seg["inside"].append(seg["inside"][-1] & inside)
        finished = [s for s in self.active if len(s["pos"]) >= self.n_frames]
        self.active = [s for s in self.active if len(s["pos"]) < self.n_frames]
        for s in finished:
            self.done.append(self._tracked_fraction(np.stack(s["pos"]), np.stack(s["inside"])))

    def _tracked_fraction(self, pos: np.ndarray, inside: np.ndarray) -> float:
        """Mean fraction of the segment's n model frames during which each target is pursued."""
        alpha = self._alpha(pos)  # (frames, targets, 2) radians
        if not self.native:
            t = np.arange(len(alpha)) / self.fps
            tm = model_times((self.n - 1) / MODEL_FPS)[: self.n]
            alpha = resample(alpha, t, tm)
            # A target counts as gone from the first model sample at or after it left the frame.
            idx = np.minimum(np.ceil(tm * self.fps - 1e-9).astype(int), len(inside) - 1)
            inside = inside[idx]
        tracked = np.full(alpha.shape[1], 2.0)  # the first two frames count as tracked
        sacc_left = np.zeros(alpha.shape[1], np.int64)
        for j in range(2, self.n):
            pe = alpha[j] - 2.0 * alpha[j - 1] + alpha[j - 2]
            ok = self._ok(pe) & inside[j]
            in_sacc = sacc_left > 0
            start_sacc = ~ok & ~in_sacc
            tracked += (ok & ~in_sacc).astype(float)
            sacc_left = np.where(in_sacc, sacc_left - 1, np.where(start_sacc, self.sacc - 1, 0))
        return float(np.mean(tracked / self.n))


def ve2d_video(
    video: str | os.PathLike,
    intrinsics: Intrinsics | None = None,
    model: ViewingModel | None = None,
    *,
    grid: tuple[int, int] = (10, 20),
    flow_width: int = 320,
    progress: Callable[[int, int], None] | None = None,
) -> VE2DResult:
    """2D-VE of a video (eq. 8.18); ``flow_width`` is the width of the optical-flow copy."""
    import time

    model = model or ViewingModel.model_2d()
    model.validate()
    info = probe(video)
    fps = info.fps
    intr = intrinsics or Intrinsics.default(info.width, info.height)
    n = model.window_frames
    scale = min(1.0, flow_width / info.width)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
    segs = _Segments(intr, model, fps, n, grid[0], grid[1])
    need = segs.n_frames
    prev = None
    count = 0
    t0 = time.perf_counter()
    for frame in iter_frames(video, gray=True, scale=scale if scale < 1 else None):
        img = frame.image
        if prev is not None:
            flow = dis.calc(prev, img, None)
            segs.advance(flow, img.shape[1] / intr.width)
        segs.begin()
        prev = img
        count += 1
        if progress is not None:
            progress(count, info.frame_count)
    if count < need:
        raise EgovidError(
            f"{video} has {count} frames, fewer than one 2D-VE segment ({need} frames, {n / MODEL_FPS:.1f} s)",
            "score a longer clip",
        )
    segments = np.array(segs.done)
    return VE2DResult(
        score=rms(segments),
        segments=segments,
        fps=fps,
        frames=count,
        seconds=time.perf_counter() - t0,
        params={
            "bias_deg": model.bias_deg,
            "mar_deg": model.mar_deg,
            "d_over_f": model.d_over_f,
            "model_fps": MODEL_FPS,
            "resampled_from_fps": None if segs.native else fps,
            "saccade_frames": model.saccade_frames,
            "segment_frames": n,
            "segment_native_frames": need,
            "grid": list(grid),
            "flow_width": round(info.width * scale),
        },
    )
