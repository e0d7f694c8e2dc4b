"""Pinhole camera intrinsics, and where a video's come from.

Pixels are measured from the top-left corner of the image; the camera looks along +z with x to
the right and y down (the OpenCV convention). The default camera is the GoPro-like 1080p wide
view the thesis uses in §10.1.2: focal length 830 px at 1920 px (horizontal field of view 98.3°),
scaled with the image's long side, so a portrait video (rotation flag 90°) gets the same focal
length in pixels as the same camera held in landscape.

:func:`resolve_camera` is the one place that decides a video's intrinsics, in this order:

1. ``--focal PX`` or ``--hfov DEG`` given by the user;
2. (in :mod:`egovid.core.motion.source`, when a gyro is recorded) the focal length fitted from the
   gyro against the video;
3. the lens mode the camera recorded (GoPro ``VFOV``: Wide, Medium, Narrow, SuperView, Linear),
   through GoPro's published field of view and an equidistant (fisheye) lens;
4. a 35 mm-equivalent focal length in the file's metadata (phones; read with ExifTool);
5. the default camera above.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from egovid.core.errors import EgovidError

#: Focal length of the default camera at 1920 px width (thesis §10.1.2), in pixels.
DEFAULT_FOCAL_AT_1080P = 830.0
#: Plausible range of horizontal field of view, in degrees; outside it a focal length is absurd.
HFOV_RANGE_DEG = (5.0, 175.0)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a ``width`` x ``height`` image (all in pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

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

    def scaled(self, factor: float) -> Intrinsics:
        """Intrinsics of the same camera after resizing the image by ``factor``."""
        w = max(1, round(self.width * factor))
        h = max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return Intrinsics(w, h, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5)


def _check_size(width: int, height: int) -> None:
    if width < 2 or height < 2:
        raise EgovidError(f"image size {width}x{height} is too small", "use a video of at least 2x2 pixels")


def resolve_intrinsics(width: int, height: int, focal: float | None = None, hfov: float | None = None) -> Intrinsics:
    """Intrinsics from ``--focal PX`` or ``--hfov DEG`` (not both; the field of view is across the
    picture's long side); the default camera otherwise. For a video file use
    :func:`resolve_camera`, which also reads the file's lens metadata."""
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


# --------------------------------------------------------------------------------------------
# Intrinsics of a video file.

#: GoPro's published horizontal field of view (degrees, 16:9) per lens mode, and whether the
#: picture is fisheye (equidistant: focal = half width / half angle in radians) or rectilinear.
GOPRO_LENS_HFOV: dict[str, tuple[float, bool]] = {
    "W": (118.2, True),  # Wide
    "M": (94.4, True),  # Medium
    "N": (64.4, True),  # Narrow
    "S": (122.6, True),  # SuperView (stretched 4:3; centre approximated)
    "L": (85.8, False),  # Linear (dewarped)
    "R": (85.8, False),  # Linear + horizon levelling
}

#: Diagonal of a 35 mm film frame in millimetres (36 x 24 mm), the reference of 35 mm-equivalent
#: focal lengths.
FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)

#: ExifTool tag names that carry a 35 mm-equivalent focal length in millimetres.
FOCAL_35MM_TAGS = ("FocalLengthIn35mmFormat", "CameraFocalLength35mmEquivalent", "FocalLength35mm", "FocalLength35efl")


@dataclass(frozen=True)
class CameraModel:
    """A video's intrinsics (display orientation) and where they came from.

    ``source`` is one of ``"flag"``, ``"gyro-fit"``, ``"lens-mode"``, ``"35mm-equivalent"``,
    ``"default"``; ``detail`` says what exactly (in words); ``rotation`` the container's display
    rotation in degrees (the intrinsics already account for it).
    """

    intrinsics: Intrinsics
    source: str
    detail: str
    rotation: int = 0

    def with_focal(self, focal_px: float, source: str, detail: str) -> CameraModel:
        """The same camera with another focal length (pixels)."""
        i = self.intrinsics
        return CameraModel(Intrinsics.from_focal(i.width, i.height, focal_px), source, detail, self.rotation)

    def to_dict(self) -> dict:
        """JSON-ready description (pixels and degrees)."""
        i = self.intrinsics
        return {
            "width": i.width,
            "height": i.height,
            "focal_px": round(i.focal, 3),
            "hfov_deg": round(i.hfov_deg, 3),
            "vfov_deg": round(i.vfov_deg, 3),
            "source": self.source,
            "detail": self.detail,
            "rotation": self.rotation,
        }


def _lens_mode_focal(long_side: int, mode: str) -> tuple[float, str] | None:
    code = mode.strip().upper()[:1]
    if code not in GOPRO_LENS_HFOV:
        return None
    hfov, fisheye = GOPRO_LENS_HFOV[code]
    half = math.radians(hfov / 2.0)
    focal = long_side / 2.0 / (half if fisheye else math.tan(half))
    kind = "equidistant fisheye" if fisheye else "rectilinear"
    return focal, f"{hfov:g}° published field of view, {kind}"


def resolve_camera(
    video: str | os.PathLike,
    focal: float | None = None,
    hfov: float | None = None,
    *,
    telemetry=None,
    tags: dict | None = None,
) -> CameraModel:
    """The intrinsics of ``video`` in display orientation (see the module docstring for the order).

    ``telemetry`` (:class:`egovid.core.camera.telemetry.CameraTelemetry`) and ``tags`` (ExifTool tags of the
    file) are read from the file when not given; metadata that cannot be read is skipped, never
    an error. Raises :class:`EgovidError` for an unreadable video or absurd ``focal``/``hfov``.
    """
    from egovid.core.video import probe

    info = probe(video)
    w, h, rot = info.width, info.height, info.rotation
    long_side = max(w, h)
    if focal is not None or hfov is not None:
        intr = resolve_intrinsics(w, h, focal, hfov)
        what = f"--focal {focal:g} px" if focal is not None else f"--hfov {hfov:g}° across the long side"
        return CameraModel(intr, "flag", what, rot)
    if telemetry is None:
        from egovid.core.camera.telemetry import read_camera_telemetry

        try:
            telemetry = read_camera_telemetry(video)
        except EgovidError:
            telemetry = None
    camera = " ".join(x for x in (getattr(telemetry, "make", None), getattr(telemetry, "model", None)) if x)
    mode = getattr(telemetry, "lens_mode", None)
    if mode:
        found = _lens_mode_focal(long_side, mode)
        if found is not None:
            f, how = found
            name = telemetry.lens_name or mode
            return CameraModel(
                Intrinsics.from_focal(w, h, f), "lens-mode", f"{camera} {name} lens ({how})".strip(), rot
            )
    f35 = getattr(telemetry, "zoom_35mm", None)
    if f35 is None:
        if tags is None:
            from egovid.core.camera.exif import read_tags

            try:
                tags = read_tags(video)
            except EgovidError:
                tags = {}
        from egovid.core.camera.exif import find_tag

        f35 = _positive(find_tag(tags, FOCAL_35MM_TAGS))
    if f35 is not None:
        f = f35 * math.hypot(w, h) / FILM_DIAGONAL_MM
        if HFOV_RANGE_DEG[0] < 2 * math.degrees(math.atan2(long_side / 2, f)) < HFOV_RANGE_DEG[1]:
            return CameraModel(Intrinsics.from_focal(w, h, f), "35mm-equivalent", f"{f35:g} mm (35 mm equivalent)", rot)
    return CameraModel(
        Intrinsics.default(w, h), "default", f"{DEFAULT_FOCAL_AT_1080P:g} px at 1920 px, scaled to the long side", rot
    )


def _positive(value) -> float | None:
    try:
        v = float(str(value).split()[0])
    except (TypeError, ValueError, IndexError):
        return None
    return v if math.isfinite(v) and v > 0 else None
