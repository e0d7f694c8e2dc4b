"""Render a stabilised video: one rotation homography (and zoom) per frame, on the decoded planes.

Frame k, taken with orientation ``R_k`` (camera-to-world), is re-rendered as if taken with the
edited orientation ``R̃_k``: pixels move by ``H_k = K (R̃_kᵀ R_k) K⁻¹`` (the thesis' ``K R̃ Rᵀ K⁻¹``
in its world-to-camera convention), then by the frame's zoom about the image centre. Borders:

* ``crop`` (default): the zoom of every frame (from :mod:`egovid.fpv.stabilize.path`) keeps the
  frame covered, so there are none;
* ``black``: uncovered pixels stay black;
* ``fill``: uncovered pixels are taken from the previous output frame re-projected to the new
  orientation (a temporal mosaic), and mirrored content where that has none yet.

Frames are warped as decoded, plane by plane (Y at full size, U and V at their 4:2:0 size with the
same homography re-expressed on the chroma grid), so no colour conversion touches the pixels and
the colour tags, range, rotation flag, audio and telemetry of the input are kept
(:class:`egovid.core.video.VideoWriter` ``keep_from``). A 10-bit input (a phone's HDR HEVC) stays
10-bit from decoder to encoder (uint16 planes; :func:`output_bits`, :data:`ENCODINGS`). The content
mask of a frame (for the masked ITF and the black share) is the warp of an all-ones image by the
same homography, computed only where a frame can have borders. Frames stream from the decoder to
the encoder; the output has the same frame count and timestamps, and nothing appears at the target
path unless the whole video succeeded.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.video import Frame, VideoInfo, VideoWriter, iter_frames, probe

BORDERS = ("black", "crop", "fill")
#: Choices of the output's bits per sample: ``auto`` is the input's (10 for 10 bits and more).
BIT_DEPTHS = ("auto", "8", "10")
#: The output's encoder and pixel format by bits per sample: H.264 at 8 bits (as ever); HEVC
#: Main10 at 10, what phones record 10-bit and HDR video in and what players and phones decode in
#: hardware (x264's High10 profile would do too, but almost no hardware decodes it).
ENCODINGS = {8: ("libx264", "yuv420p"), 10: ("libx265", "yuv420p10le")}
#: Luma -> chroma pixel coordinates of 4:2:0 (chroma sited between luma pixels).
_TO_CHROMA = np.array([[0.5, 0.0, -0.25], [0.0, 0.5, -0.25], [0.0, 0.0, 1.0]])


def output_bits(info: VideoInfo, bit_depth: str | int = "auto") -> int:
    """Bits per sample of the stabilised output of a video ``info`` (8 or 10): ``bit_depth``, one
    of :data:`BIT_DEPTHS`; ``auto`` keeps 10 bits where the input has more than 8."""
    bit_depth = str(bit_depth)
    if bit_depth not in BIT_DEPTHS:
        raise EgovidError(f"unknown bit depth {bit_depth!r}", f"choose one of {', '.join(BIT_DEPTHS)}")
    if bit_depth == "auto":
        return 10 if info.bit_depth > 8 else 8
    return int(bit_depth)


@dataclass(frozen=True)
class OutputFormat:
    """How both renderers decode and store a video: ``bits`` per sample (of the decoded I420
    planes and the output), the output's ``codec`` and ``pix_fmt`` (:data:`ENCODINGS`), and the
    (luma, chroma) sample values of ``black`` at those bits in the input's range."""

    bits: int
    codec: str
    pix_fmt: str
    black: tuple[int, int]

    @classmethod
    def of(cls, info: VideoInfo, bit_depth: str | int = "auto") -> OutputFormat:
        """The format of the stabilised output of video ``info`` for ``bit_depth`` (:func:`output_bits`)."""
        bits = output_bits(info, bit_depth)
        black = ((0 if info.colour.full_range else 16) << (bits - 8), 128 << (bits - 8))
        return cls(bits, *ENCODINGS[bits], black)


def homographies(R_old: np.ndarray, R_new: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(K, 3, 3) pixel maps original → stabilised, ``K R̃ᵀ R K⁻¹``."""
    K, K_inv = intr.K, intr.K_inv
    Q = np.swapaxes(R_new, 1, 2) @ R_old
    return K @ Q @ K_inv


def zoom_about_centre(keep: np.ndarray | float, width: int, height: int) -> np.ndarray:
    """Homographies ((K, 3, 3), or (3, 3) for a scalar) scaling by ``1/keep`` about the centre."""
    k = np.asarray(keep, dtype=float)
    s = 1.0 / k
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    Z = np.zeros((*k.shape, 3, 3))
    Z[..., 0, 0] = s
    Z[..., 1, 1] = s
    Z[..., 0, 2] = cx * (1 - s)
    Z[..., 1, 2] = cy * (1 - s)
    Z[..., 2, 2] = 1.0
    return Z


def content_masks(H: np.ndarray, keep: np.ndarray, width: int, height: int) -> Callable[[int], np.ndarray]:
    """``mask(k)``: the (height, width) bool content mask of output frame k, the warp of an
    all-ones frame by its homography ``H[k]`` and zoom ``1/keep[k]`` (geometry, never colour)."""
    Hz = zoom_about_centre(np.asarray(keep, dtype=float), width, height) @ H
    ones = np.full((height, width), 255, np.uint8)

    def mask(k: int) -> np.ndarray:
        return cv2.warpPerspective(ones, Hz[k], (width, height), flags=cv2.INTER_NEAREST) > 127

    return mask


def covered_share(H: np.ndarray, width: int, height: int, masks: Callable[[int], np.ndarray], k: int) -> float:
    """Share (0-1) of a width x height output frame that frame k's content covers after the
    pixel map ``H`` (3x3): the area of the mapped frame rectangle inside the output, from the
    geometry (exact, no pixel warp); ``masks(k)`` counts pixels where the map folds the frame
    behind the camera."""
    corners = np.array(
        [[-0.5, -0.5, 1], [width - 0.5, -0.5, 1], [width - 0.5, height - 0.5, 1], [-0.5, height - 0.5, 1]]
    )
    q = corners @ H.T
    if np.any(q[:, 2] <= 1e-9):
        m = masks(k)
        return float(np.count_nonzero(m) / m.size)
    quad = (q[:, :2] / q[:, 2:3]).astype(np.float32)
    rect = corners[:, :2].astype(np.float32)
    area, _ = cv2.intersectConvexConvex(quad, rect)
    return float(min(1.0, max(0.0, area / (width * height))))


@dataclass
class RenderStats:
    """Measured while rendering: mean share of black (uncovered) pixels, the per-frame zoom (mean
    and largest), what was and was not kept from the input, and the output's bits per sample."""

    frames: int
    black_share: float
    zoom_mean: float
    zoom_max: float
    seconds: float
    kept: list[str]
    dropped: list[str]
    bits: int = 8


def _warp_i420(img: np.ndarray, H: np.ndarray, w: int, h: int, border: tuple[int, int], mode: int) -> np.ndarray:
    """Warp one I420 picture ((h*3/2, w) uint8, or uint16 at 10 bits) by the luma homography ``H``."""
    out = np.empty_like(img)
    out[:h] = cv2.warpPerspective(img[:h], H, (w, h), flags=cv2.INTER_LINEAR, borderMode=mode, borderValue=border[0])
    Hc = _TO_CHROMA @ H @ np.linalg.inv(_TO_CHROMA)
    cw, ch = w // 2, h // 2
    planes = img[h:].reshape(2, ch, cw)
    oc = out[h:].reshape(2, ch, cw)
    for p in range(2):
        oc[p] = cv2.warpPerspective(
            planes[p], Hc, (cw, ch), flags=cv2.INTER_LINEAR, borderMode=mode, borderValue=border[1]
        )
    return out


class _Mosaic:
    """The ``fill`` border mode: uncovered pixels of output frame k taken from output frame k - 1
    re-projected to frame k's orientation and zoom (``masks(k)``: frame k's own content)."""

    def __init__(
        self,
        masks: Callable[[int], np.ndarray],
        zoom: np.ndarray,
        R_new: np.ndarray,
        intrinsics: Intrinsics,
        black: tuple[int, int],
        width: int,
        height: int,
    ) -> None:
        self.masks, self.zoom, self.R_new, self.intr, self.black = masks, zoom, R_new, intrinsics, black
        self.w, self.h = width, height
        self.ones = np.full((self.h, self.w), 255, np.uint8)

    def fill(self, out: np.ndarray, prev_out: np.ndarray, k: int) -> None:
        """Fill the uncovered pixels of the I420 picture ``out`` (frame k) from ``prev_out``, in place."""
        w, h, Zi, R_new = self.w, self.h, self.zoom, self.R_new
        mask = self.masks(k)
        Hp = Zi[k] @ homographies(R_new[k - 1 : k], R_new[k : k + 1], self.intr)[0] @ np.linalg.inv(Zi[k - 1])
        prev = _warp_i420(prev_out, Hp, w, h, self.black, cv2.BORDER_CONSTANT)
        prev_ok = cv2.warpPerspective(self.ones, Hp, (w, h), flags=cv2.INTER_NEAREST) > 127
        use = prev_ok & ~mask
        out[:h][use] = prev[:h][use]
        cu = use[::2, ::2]
        for p in range(2):
            plane = out[h:].reshape(2, h // 2, w // 2)[p]
            plane[cu] = prev[h:].reshape(2, h // 2, w // 2)[p][cu]


def _pipelined(
    frames: Iterator[Frame], work: Callable[[Frame], np.ndarray], write: Callable[[np.ndarray, float], None]
) -> int:
    """``write(work(frame), frame.time)`` for every frame, in order; returns how many.

    Three stages overlap on threads (PyAV decodes and encodes, OpenCV warps, all without the
    GIL): the next frame decodes and the previous one encodes while this one is worked on. One
    job in flight per stage keeps the order and bounds memory to a few frames."""
    stages = ThreadPoolExecutor(max_workers=2, thread_name_prefix="render")
    encoding: Future | None = None
    n = 0
    try:
        decoding = stages.submit(next, frames, None)
        while (frame := decoding.result()) is not None:
            decoding = stages.submit(next, frames, None)
            out = work(frame)
            if encoding is not None:
                encoding.result()
            encoding = stages.submit(write, out, frame.time)
            n += 1
        if encoding is not None:
            encoding.result()
    finally:
        # Nothing may touch the writer or the decoder once this is left: wait for every job
        # submitted, not only those held in `encoding` and `decoding` (a signal handled inside
        # `submit` leaves its job running and unassigned; closing the writer under it crashed the
        # process on an interrupt).
        stages.shutdown(wait=True)
    return n


def render_stabilized(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    H: np.ndarray,
    *,
    keep: np.ndarray | None = None,
    borders: str = "crop",
    R_new: np.ndarray | None = None,
    intrinsics: Intrinsics | None = None,
    crf: int = 18,
    preset: str = "veryfast",
    thread_type: str = "AUTO",
    bit_depth: str | int = "auto",
    progress: Callable[[int, int], None] | None = None,
    frames: Iterator[Frame] | None = None,
) -> RenderStats:
    """Warp every frame of ``src`` by ``H[k]`` and the zoom ``1/keep[k]``, and encode to ``dst``
    (atomically, keeping what the camera wrote) at the bits per sample :func:`output_bits` gives
    for ``bit_depth``, with that depth's encoder (:data:`ENCODINGS`). ``frames`` are ``src``'s
    I420 frames at those bits where the caller decodes them already (else they are decoded here)."""
    if borders not in BORDERS:
        raise EgovidError(f"unknown border mode {borders!r}", f"choose one of {', '.join(BORDERS)}")
    info = probe(src)
    w, h = info.width, info.height
    if w % 2 or h % 2:
        raise EgovidError(f"{src} is {w}x{h}; the stabiliser needs even dimensions", "crop or scale it by one pixel")
    keep = np.ones(len(H)) if keep is None else np.asarray(keep, dtype=float)
    H = zoom_about_centre(keep, w, h) @ H
    fmt = OutputFormat.of(info, bit_depth)
    black = fmt.black
    mode = cv2.BORDER_REFLECT if borders == "fill" else cv2.BORDER_CONSTANT
    masks = content_masks(H, np.ones(len(H)), w, h)  # H already holds the zoom
    mosaic = None
    if borders == "fill" and R_new is not None and intrinsics is not None:
        mosaic = _Mosaic(masks, zoom_about_centre(keep, w, h), R_new, intrinsics, black, w, h)
    state = {"prev": None, "black": 0.0}
    t0 = time.perf_counter()

    def warp(frame: Frame) -> np.ndarray:
        k = frame.index
        if k >= len(H):
            raise EgovidError(
                f"{src} has more frames than its motion ({len(H)})", "re-estimate the motion of this video"
            )
        out = _warp_i420(frame.image, H[k], w, h, black, mode)
        if mosaic is not None and state["prev"] is not None:
            mosaic.fill(out, state["prev"], k)
        if borders != "crop":
            state["black"] += 1.0 - covered_share(H[k], w, h, masks, k)
        state["prev"] = out
        if progress is not None:
            progress(k + 1, info.frame_count)
        return out

    if frames is None:
        frames = iter_frames(src, i420=True, bits=fmt.bits)
    try:
        # Frame threads, as the ffmpeg command gives x264 (PyAV's default is slice threads,
        # about 25 % slower for a whole video at the same settings).
        with VideoWriter(
            dst, w, h, info.fps, codec=fmt.codec, pix_fmt=fmt.pix_fmt, crf=crf, preset=preset,
            thread_type=thread_type, keep_from=src,
        ) as writer:  # fmt: skip
            n = _pipelined(frames, warp, writer.write_i420)
            if n != len(H):
                raise EgovidError(
                    f"{src} decoded {n} frames but its motion has {len(H)}", "re-estimate the motion of this video"
                )
    finally:
        close = getattr(frames, "close", None)
        if close is not None:
            close()
    zoom = 1.0 / keep
    return RenderStats(
        n,
        state["black"] / max(n, 1),
        float(zoom.mean()),
        float(zoom.max()),
        time.perf_counter() - t0,
        writer.kept,
        writer.dropped,
        fmt.bits,
    )
