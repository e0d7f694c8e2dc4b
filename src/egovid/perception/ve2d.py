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

Memory is bounded: only the last N flows' worth of active targets are kept.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from egovid.errors import EgovidError
from egovid.io.camera import Intrinsics
from egovid.io.video import iter_frames, probe
from egovid.perception.model import ViewingModel
from egovid.perception.score import rms


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
    """Targets of the active segments, advanced one flow at a time."""

    def __init__(self, intr: Intrinsics, model: ViewingModel, fps: float, n: int, rows: int, cols: int):
        self.intr = intr
        self.n = n
        self.sacc = model.frames(model.saccade_frames, fps)
        mar, x_lo, x_hi = model.pe_bounds(fps)
        self.mar = math.radians(mar)
        self.x_lo = math.radians(x_lo)
        self.x_hi = math.radians(x_hi) if np.isfinite(x_hi) else np.inf
        self.d = model.d_over_f * intr.focal
        self.start = grid_centres(intr.width, intr.height, rows, cols)
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
        n_pts = len(p)
        self.active.append(
            {
                "pos": [p],
                "inside": np.ones(n_pts, bool),
                "tracked": np.full(n_pts, 2.0),  # first two frames count as tracked
                "sacc_left": np.zeros(n_pts, np.int64),
                "len": 1,
            }
        )

    def advance(self, flow: np.ndarray, scale: float) -> None:
        """Move every active target by ``flow`` (computed at ``scale`` of full resolution)."""
        if not self.active:
            return
        w, h = self.intr.width, self.intr.height
        for seg in self.active:
            p = seg["pos"][-1]
            u, v = _bilinear(flow, (p[:, 0] + 0.5) * scale - 0.5, (p[:, 1] + 0.5) * scale - 0.5)
            q = p + np.column_stack([u, v]) / scale
            seg["inside"] &= (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
            seg["pos"] = [*seg["pos"][-2:], q]
            seg["len"] += 1
            if seg["len"] >= 3:
                a = self._alpha(np.stack(seg["pos"][-3:]))
                pe = a[2] - 2.0 * a[1] + a[0]
                ok = self._ok(pe) & seg["inside"]
                in_sacc = seg["sacc_left"] > 0
                start_sacc = ~ok & ~in_sacc
                seg["tracked"] += (ok & ~in_sacc).astype(float)
                seg["sacc_left"] = np.where(in_sacc, seg["sacc_left"] - 1, np.where(start_sacc, self.sacc - 1, 0))
        finished = [s for s in self.active if s["len"] >= self.n]
        self.active = [s for s in self.active if s["len"] < self.n]
        for s in finished:
            self.done.append(float(np.mean(s["tracked"] / self.n)))


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
    info = probe(video)
    fps = info.fps
    model.validate(fps)
    intr = intrinsics or Intrinsics.default(info.width, info.height)
    n = model.frames(model.window_frames, fps)
    if info.frame_count and info.frame_count < n:
        pass  # decided after decoding, when the count is exact
    scale = min(1.0, flow_width / info.width)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
    segs = _Segments(intr, model, fps, n, grid[0], grid[1])
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
    if count < n:
        raise EgovidError(f"{video} has {count} frames, fewer than one 2D-VE segment ({n})", "score a longer clip")
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
            "saccade_frames": model.frames(model.saccade_frames, fps),
            "segment_frames": n,
            "grid": list(grid),
            "flow_width": round(info.width * scale),
        },
    )
