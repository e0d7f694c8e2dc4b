"""Pinhole camera intrinsics (pure numbers; which intrinsics a video file has is decided in
:mod:`egovid.core.camera.resolve`).

Pixels are measured from the top-left corner of the image; the camera looks along +z with x to
the right and y down (the OpenCV convention). The default camera is the GoPro-like 1080p wide
view the thesis uses in §10.1.2: focal length 830 px at 1920 px (horizontal field of view 98.3°),
scaled with the image's long side, so a portrait video (rotation flag 90°) gets the same focal
length in pixels as the same camera held in landscape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from egovid.core.errors import EgovidError

#: Focal length of the default camera at 1920 px width (thesis §10.1.2), in pixels.
DEFAULT_FOCAL_AT_1080P = 830.0
#: Plausible range of horizontal field of view, in degrees; outside it a focal length is absurd.
HFOV_RANGE_DEG = (5.0, 175.0)


@dataclass(frozen=True)
class Intrinsics:
    """Intrinsics of a ``width`` x ``height`` image (all in pixels): the camera matrix and, where
    known (a calibrated lens profile), the lens's OpenCV-fisheye ``distortion`` ``k1..k4``
    (``θd = θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸)``; None: a pinhole picture)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float] | None = None

    @classmethod
    def from_focal(cls, width: int, height: int, focal_px: float) -> Intrinsics:
        """Square pixels, principal point at the image centre, focal length ``focal_px`` pixels."""
        _check_size(width, height)
        hfov = 2.0 * math.degrees(math.atan2(width / 2.0, focal_px)) if focal_px > 0 else 0.0
        if not (focal_px > 0 and HFOV_RANGE_DEG[0] <= hfov <= HFOV_RANGE_DEG[1]):
            lo = width / 2.0 / math.tan(math.radians(HFOV_RANGE_DEG[1] / 2))
            hi = width / 2.0 / math.tan(math.radians(HFOV_RANGE_DEG[0] / 2))
            raise EgovidError(
                f"focal length {focal_px:g} px is absurd for a {width} px wide video",
                f"give --focal between {lo:.0f} and {hi:.0f} px, or --hfov in degrees",
            )
        return cls(width, height, float(focal_px), float(focal_px), (width - 1) / 2.0, (height - 1) / 2.0)

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> Intrinsics:
        """Square pixels with a horizontal field of view of ``hfov_deg`` degrees."""
        _check_size(width, height)
        if not (HFOV_RANGE_DEG[0] <= hfov_deg <= HFOV_RANGE_DEG[1]):
            raise EgovidError(
                f"horizontal field of view {hfov_deg:g}° is out of range",
                f"give --hfov between {HFOV_RANGE_DEG[0]:g} and {HFOV_RANGE_DEG[1]:g} degrees",
            )
        focal = width / 2.0 / math.tan(math.radians(hfov_deg) / 2.0)
        return cls.from_focal(width, height, focal)

    @classmethod
    def default(cls, width: int, height: int) -> Intrinsics:
        """The GoPro-like default: 830 px focal length at 1920 px, scaled to the long side."""
        return cls.from_focal(width, height, DEFAULT_FOCAL_AT_1080P * max(width, height) / 1920.0)

    @property
    def K(self) -> np.ndarray:
        """The 3x3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def K_inv(self) -> np.ndarray:
        """Inverse of :attr:`K`."""
        return np.linalg.inv(self.K)

    @property
    def focal(self) -> float:
        """Mean focal length in pixels."""
        return 0.5 * (self.fx + self.fy)

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view in degrees."""
        return 2.0 * math.degrees(math.atan2(self.width / 2.0, self.fx))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view in degrees."""
        return 2.0 * math.degrees(math.atan2(self.height / 2.0, self.fy))

    def rotated(self, rotation: int) -> Intrinsics:
        """The intrinsics of this picture turned ``rotation`` degrees counter-clockwise (0, 90,
        180, 270; as the decoder turns a frame by its display rotation flag,
        :func:`egovid.core.video.orientation.to_display`): a pixel (x, y) of the ``W`` x ``H``
        picture goes to (y, W-1-x) at 90°, (W-1-x, H-1-y) at 180°, (H-1-y, x) at 270°. The
        fisheye distortion is radial, the same after a quarter turn."""
        k = (int(rotation) // 90) % 4
        if int(rotation) % 90:
            raise EgovidError(f"rotation {rotation}° is not a multiple of 90", "use 0, 90, 180 or 270")
        w, h, d = self.width, self.height, self.distortion
        if k == 1:
            return Intrinsics(h, w, self.fy, self.fx, self.cy, (w - 1) - self.cx, d)
        if k == 2:
            return Intrinsics(w, h, self.fx, self.fy, (w - 1) - self.cx, (h - 1) - self.cy, d)
        if k == 3:
            return Intrinsics(h, w, self.fy, self.fx, (h - 1) - self.cy, self.cx, d)
        return self

    def scaled(self, factor: float) -> Intrinsics:
        """Intrinsics of the same camera after resizing the image by ``factor``."""
        w = max(1, round(self.width * factor))
        h = max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return Intrinsics(
            w, h, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, self.distortion
        )


def _check_size(width: int, height: int) -> None:
    if width < 2 or height < 2:
        raise EgovidError(f"image size {width}x{height} is too small", "use a video of at least 2x2 pixels")


def resolve_intrinsics(width: int, height: int, focal: float | None = None, hfov: float | None = None) -> Intrinsics:
    """Intrinsics from ``--focal PX`` or ``--hfov DEG`` (not both; the field of view is across the
    picture's long side); the default camera otherwise. For a video file use
    :func:`egovid.core.camera.resolve.resolve_camera`, which also reads the file's lens metadata."""
    if focal is not None and hfov is not None:
        raise EgovidError("both --focal and --hfov were given", "give only one of them")
    if focal is not None:
        return Intrinsics.from_focal(width, height, focal)
    if hfov is not None:
        if height > width:  # portrait: the camera's horizontal is the picture's height
            f = Intrinsics.from_hfov(height, width, hfov).focal
            return Intrinsics.from_focal(width, height, f)
        return Intrinsics.from_hfov(width, height, hfov)
    return Intrinsics.default(width, height)
