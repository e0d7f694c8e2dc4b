"""Render a stabilised video: one rotation homography per frame on full-resolution frames.

Frame k, taken with orientation ``R_k`` (camera-to-world), is re-rendered as if taken with the
edited orientation ``R̃_k``: pixels move by ``H_k = K (R̃_kᵀ R_k) K⁻¹`` (the thesis' ``K R̃ Rᵀ K⁻¹``
in its world-to-camera convention). Borders:

* ``black``: uncovered pixels stay black;
* ``crop``: the largest centred crop of the frame's aspect ratio that no frame leaves uncovered is
  scaled back to full size (one fixed zoom for the whole video);
* ``fill``: uncovered pixels are taken from the previous output frame re-projected to the new
  orientation (a temporal mosaic), and mirrored content where that has none yet.

The content mask of every output frame is the warp of an all-ones image by the same homography,
so ITF and the black-area share are measured on true content only. Frames stream from the decoder
to the encoder; the output has the same frame count and timestamps, the audio is copied and the
container metadata kept, and nothing appears at the target path unless the whole video succeeded.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from egovid.errors import EgovidError
from egovid.io.camera import Intrinsics
from egovid.io.video import VideoWriter, iter_frames, probe
from egovid.metrics.itf import ITFAccumulator

BORDERS = ("black", "crop", "fill")


def homographies(R_old: np.ndarray, R_new: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(K, 3, 3) pixel maps original → stabilised, ``K R̃ᵀ R K⁻¹``."""
    K, K_inv = intr.K, intr.K_inv
    Q = np.swapaxes(R_new, 1, 2) @ R_old
    return K @ Q @ K_inv


def _inside_quads(quads: np.ndarray, pts: np.ndarray) -> bool:
    """True if every point lies inside every convex quad ((K, 4, 2), corners in order)."""
    a = quads
    b = np.roll(quads, -1, axis=1)
    edge = b - a  # (K, 4, 2)
    rel = pts[None, None, :, :] - a[:, :, None, :]  # (K, 4, P, 2)
    cross = edge[:, :, None, 0] * rel[..., 1] - edge[:, :, None, 1] * rel[..., 0]
    sign = np.sign(np.sum(cross, axis=(1, 2)))[:, None, None]  # orientation of each quad
    return bool(np.all(cross * sign >= -1e-6))


def crop_factor(H: np.ndarray, width: int, height: int) -> float:
    """Largest c in (0, 1] such that the centred (c·w) x (c·h) rectangle is covered by every
    warped frame (bisection)."""
    corners = np.array([[0, 0], [width - 1, 0], [width - 1, height - 1], [0, height - 1]], float)
    h = np.concatenate([corners, np.ones((4, 1))], axis=1) @ np.swapaxes(H, 1, 2)
    quads = h[..., :2] / h[..., 2:3]
    if np.any(h[..., 2] <= 0):
        return 0.0
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0

    def rect(c: float) -> np.ndarray:
        dx, dy = c * (width - 1) / 2.0, c * (height - 1) / 2.0
        return np.array([[cx - dx, cy - dy], [cx + dx, cy - dy], [cx + dx, cy + dy], [cx - dx, cy + dy]])

    lo, hi = 0.0, 1.0
    if _inside_quads(quads, rect(1.0)):
        return 1.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if _inside_quads(quads, rect(mid)):
            lo = mid
        else:
            hi = mid
    return lo


def zoom_about_centre(c: float, width: int, height: int) -> np.ndarray:
    """Homography scaling by 1/c about the image centre."""
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    s = 1.0 / c
    return np.array([[s, 0, cx * (1 - s)], [0, s, cy * (1 - s)], [0, 0, 1.0]])


@dataclass
class RenderStats:
    """Measured while rendering: ITF (dB) before and after (masked), black share, crop factor."""

    frames: int
    itf_before: float
    itf_after: float
    black_share: float
    crop: float
    seconds: float


def render_stabilized(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    H: np.ndarray,
    *,
    borders: str = "crop",
    R_new: np.ndarray | None = None,
    intrinsics: Intrinsics | None = None,
    crf: int = 18,
    preset: str = "veryfast",
    progress: Callable[[int, int], None] | None = None,
) -> RenderStats:
    """Warp every frame of ``src`` by ``H[k]`` and encode to ``dst`` (atomically)."""
    if borders not in BORDERS:
        raise EgovidError(f"unknown border mode {borders!r}", f"choose one of {', '.join(BORDERS)}")
    info = probe(src)
    w, h = info.width, info.height
    crop = 1.0
    if borders == "crop":
        crop = crop_factor(H, w, h)
        if crop < 0.2:
            raise EgovidError(
                f"the stabilised frames overlap too little to crop (zoom would be {1 / max(crop, 1e-3):.1f}x)",
                "use --borders black or fill, or a lower --strength",
            )
        H = zoom_about_centre(crop, w, h)[None] @ H
    ones = np.full((h, w), 255, np.uint8)
    before = ITFAccumulator()
    after = ITFAccumulator()
    black = 0.0
    prev_out = None
    t0 = time.perf_counter()
    n = 0
    flags = cv2.INTER_LINEAR
    with VideoWriter(dst, w, h, info.fps, crf=crf, preset=preset, keep_from=src) as writer:
        for frame in iter_frames(src):
            k = frame.index
            if k >= len(H):
                raise EgovidError(
                    f"{src} has more frames than its motion ({len(H)})", "re-estimate the motion of this video"
                )
            Hk = H[k]
            mode = cv2.BORDER_REFLECT if borders == "fill" else cv2.BORDER_CONSTANT
            out = cv2.warpPerspective(frame.image, Hk, (w, h), flags=flags, borderMode=mode)
            mask = cv2.warpPerspective(ones, Hk, (w, h), flags=cv2.INTER_NEAREST) > 127
            if borders == "fill" and prev_out is not None and R_new is not None and intrinsics is not None:
                Hp = homographies(R_new[k - 1 : k], R_new[k : k + 1], intrinsics)[0]
                if crop != 1.0:
                    Z = zoom_about_centre(crop, w, h)
                    Hp = Z @ Hp @ np.linalg.inv(Z)
                prev = cv2.warpPerspective(prev_out, Hp, (w, h), flags=flags, borderMode=cv2.BORDER_CONSTANT)
                prev_ok = cv2.warpPerspective(ones, Hp, (w, h), flags=cv2.INTER_NEAREST) > 127
                use = prev_ok & ~mask
                out[use] = prev[use]
            writer.write(out, frame.time)
            before.add(frame.image)
            after.add(out, mask)
            black += 1.0 - np.count_nonzero(mask) / mask.size
            prev_out = out
            n += 1
            if progress is not None:
                progress(n, info.frame_count)
        if n != len(H):
            raise EgovidError(
                f"{src} decoded {n} frames but its motion has {len(H)}", "re-estimate the motion of this video"
            )
    return RenderStats(n, before.value, after.value, black / max(n, 1), crop, time.perf_counter() - t0)
