"""Local features, extracted once per frame on a downscaled grey image.

ORB (default) or SIFT from OpenCV; SURF, which the thesis used, is in no pip wheel. Keypoints are
returned in the pixel coordinates of the image they were found in, together with the intrinsics
of that image, so callers never mix scales.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from egovid.core.errors import EgovidError

FEATURES = ("orb", "sift")


@dataclass
class FrameFeatures:
    """Keypoints ``pts`` (N, 2) float32 pixels, their ``desc`` (N, D) descriptors, and the grey
    ``image`` they came from (kept for sub-pixel refinement of matches)."""

    pts: np.ndarray
    desc: np.ndarray | None
    image: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.pts)


class FeatureExtractor:
    """Detect and describe keypoints; create once, call per frame.

    Parameters
    ----------
    kind:
        ``"orb"`` (fast, binary) or ``"sift"`` (slower, float).
    n_features:
        Upper bound on keypoints per frame.
    """

    def __init__(self, kind: str = "orb", n_features: int = 800) -> None:
        kind = kind.lower()
        if kind not in FEATURES:
            raise EgovidError(f"unknown feature type {kind!r}", f"choose one of {', '.join(FEATURES)}")
        if n_features < 20:
            raise EgovidError(f"{n_features} features per frame are too few", "use at least 100")
        self.kind = kind
        if kind == "orb":
            self._det = cv2.ORB_create(nfeatures=n_features, scaleFactor=1.2, nlevels=6, fastThreshold=12)
        else:
            self._det = cv2.SIFT_create(nfeatures=n_features)

    @property
    def binary(self) -> bool:
        """True when descriptors are binary (Hamming distance)."""
        return self.kind == "orb"

    def __call__(self, gray: np.ndarray) -> FrameFeatures:
        """Keypoints of an HxW uint8 grey image."""
        kps, desc = self._det.detectAndCompute(gray, None)
        if desc is None or not kps:
            return FrameFeatures(np.zeros((0, 2), np.float32), None, gray)
        pts = np.array([k.pt for k in kps], dtype=np.float32)
        return FrameFeatures(pts, desc, gray)


class Matcher:
    """Brute-force nearest-neighbour matching (Hamming distance for binary, L2 for float
    descriptors) with Lowe's ratio test. Exact and deterministic: the same descriptors always give
    the same matches, whatever thread runs it (FLANN's LSH index draws random hash functions from
    the process-wide C ``rand()``, so its matches changed with thread timing). Safe to call from
    several threads. The two nearest neighbours come from ``cv2.batchDistance`` as arrays (what
    ``BFMatcher.knnMatch`` computes, without building a Python object per match)."""

    def __init__(self, binary: bool, ratio: float = 0.8) -> None:
        self.ratio = ratio
        self.binary = binary

    def __call__(self, a: FrameFeatures, b: FrameFeatures) -> tuple[np.ndarray, np.ndarray]:
        """Matched point pairs ``(pts_a (M, 2), pts_b (M, 2))``."""
        if a.desc is None or b.desc is None or len(a) < 2 or len(b) < 2:
            empty = np.zeros((0, 2), np.float32)
            return empty, empty
        dist, idx = cv2.batchDistance(
            a.desc,
            b.desc,
            cv2.CV_32S if self.binary else cv2.CV_32F,
            normType=cv2.NORM_HAMMING if self.binary else cv2.NORM_L2,
            K=2,
            update=0,
            crosscheck=False,
        )
        ok = (idx[:, 1] >= 0) & (dist[:, 0] < self.ratio * dist[:, 1].astype(np.float64))
        return a.pts[ok], b.pts[idx[ok, 0]]
