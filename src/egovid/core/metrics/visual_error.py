"""Visual errors of a visual odometer: OITF and RITF (thesis §21.5.2, eq. 21.13–21.19).

Image replacement (Fig. 21.2): a static picture I is moved by the ground-truth camera rotation
(frame k shows I rotated by ``R_k``) and then stabilised with the odometer's estimate (undoing
``R̂_k``). Both steps are one homography, ``H_k = K R̂_k R_kᵀ K⁻¹`` from I to the stabilised frame:
a perfect estimate gives the same picture in every frame. The content mask of every stabilised
frame comes from the homographies (it must lie inside I and inside the camera frame of step one),
never from pixel colour.

* **OITF** = ITF of the stabilised frames in order: small when the estimate drifts slowly (good
  enough for stabilisation);
* **RITF** = ITF of the same frames in a random order (fixed seed): small only if the estimate
  has no accumulated error (what augmented reality needs).

Identical frames have infinite PSNR; it is capped at ``cap_db`` (default 60 dB — interpolation
noise of a perfect estimate stays well below it, and a cap keeps averages meaningful). The values
are averaged over several pictures.
"""

from __future__ import annotations

import itertools

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.metrics.psnr import masked_psnr

DEFAULT_CAP_DB = 60.0


def _homographies(R_gt: np.ndarray, R_est: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(H (N,3,3): picture -> stabilised frame, H_stab (N,3,3): camera frame -> stabilised frame)."""
    K, Ki = intr.K, intr.K_inv
    H_stab = K @ R_est @ Ki  # frame -> stabilised (undo the estimate)
    H_move = K @ np.swapaxes(R_gt, -1, -2) @ Ki  # picture -> frame seen after the true rotation
    return H_stab @ H_move, H_stab


def _inside(H: np.ndarray, w: int, h: int) -> np.ndarray:
    """Pixels of the w x h output whose inverse image under ``H`` lies in the w x h source (an
    all-ones image warped with nearest-neighbour sampling)."""
    ones = np.full((h, w), 255, np.uint8)
    return cv2.warpPerspective(ones, H, (w, h), flags=cv2.INTER_NEAREST) > 127


def content_masks(R_gt: np.ndarray, R_est: np.ndarray, intr: Intrinsics) -> list[np.ndarray]:
    """Per stabilised frame, the pixels that show the picture and lie inside the camera frame of
    step one (eq. 21.19, from the homographies, never from pixel colour)."""
    w, h = intr.width, intr.height
    H, H_stab = _homographies(R_gt, R_est, intr)
    return [_inside(Hk, w, h) & _inside(Sk, w, h) for Hk, Sk in zip(H, H_stab, strict=True)]


def _picture(image: np.ndarray, w: int, h: int) -> np.ndarray:
    """A picture resized to the w x h frame, grey."""
    img = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img


def stabilised_frames(
    image: np.ndarray, R_gt: np.ndarray, R_est: np.ndarray, intr: Intrinsics, masks: list[np.ndarray] | None = None
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Grey stabilised frames and their content masks for one picture (resized to the frame)."""
    w, h = intr.width, intr.height
    img = _picture(image, w, h)
    H, _ = _homographies(R_gt, R_est, intr)
    frames = [cv2.warpPerspective(img, Hk, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT) for Hk in H]
    return frames, masks if masks is not None else content_masks(R_gt, R_est, intr)


def _stabilised_planes(pictures: list[np.ndarray], H: np.ndarray, w: int, h: int) -> list[tuple[np.ndarray, ...]]:
    """Per frame, the stabilised frame of every picture (grey planes), up to four pictures warped
    as the channels of one image: OpenCV interpolates each channel alone, so every plane is
    bit-identical to warping its picture by itself, at about a third of the cost."""
    chunks = [pictures[i : i + 4] for i in range(0, len(pictures), 4)]
    groups = [cv2.merge(c) if len(c) > 1 else c[0] for c in chunks]
    out = []
    for Hk in H:
        planes: list[np.ndarray] = []
        for g in groups:
            warped = cv2.warpPerspective(g, Hk, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            planes.extend(cv2.split(warped) if warped.ndim == 3 else [warped])
        out.append(tuple(planes))
    return out


def _itfs(frames: list[tuple[np.ndarray, ...]], masks: list[np.ndarray], order, cap_db: float) -> list[float]:
    """ITF (eq. 21.13, masks of eq. 21.18) of every picture's stabilised frames taken in ``order``;
    the mask of a frame pair is shared by all pictures. Same values as :class:`ITFAccumulator`."""
    order = list(order)
    n_pic = len(frames[0]) if frames else 0
    sums, counts = [0.0] * n_pic, [0] * n_pic
    for a, b in itertools.pairwise(order):
        both = masks[a] & masks[b]
        for p in range(n_pic):
            v = masked_psnr(frames[a][p], frames[b][p], both, cap_db)
            if np.isfinite(v):
                sums[p] += v
                counts[p] += 1
    return [s / c if c else float("nan") for s, c in zip(sums, counts, strict=True)]


def visual_errors(
    images: list[np.ndarray],
    R_gt: np.ndarray,
    R_est: np.ndarray,
    intr: Intrinsics,
    *,
    cap_db: float = DEFAULT_CAP_DB,
    seed: int = 0,
) -> tuple[float, float]:
    """(OITF, RITF) in dB averaged over ``images``; rotations relative to the first frame."""
    R_gt = np.swapaxes(R_gt[0], -1, -2) @ R_gt
    R_est = np.swapaxes(R_est[0], -1, -2) @ R_est
    order = np.random.default_rng(seed).permutation(len(R_gt))
    w, h = intr.width, intr.height
    masks = content_masks(R_gt, R_est, intr)  # the same for every picture
    H, _ = _homographies(R_gt, R_est, intr)
    frames = _stabilised_planes([_picture(img, w, h) for img in images], H, w, h)
    oitf = _itfs(frames, masks, range(len(frames)), cap_db)
    ritf = _itfs(frames, masks, order, cap_db)
    return float(np.nanmean(oitf)), float(np.nanmean(ritf))
