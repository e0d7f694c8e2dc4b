"""Which intrinsics a video file has, and where they come from.

:func:`resolve_camera` is the one place that decides a video's intrinsics, in this order:

1. ``--focal PX`` or ``--hfov DEG`` given by the user (through the lens of step 3 where the
   camera recorded one);
2. (in :mod:`egovid.core.motion.source`, when a gyro is recorded) the focal length fitted from the
   gyro against the video;
3. the lens mode the camera recorded (GoPro ``VFOV``: Wide, Medium, Narrow, SuperView, Linear),
   through GoPro's published field of view and an equidistant (fisheye) lens; a GoPro file that
   records none is taken as Wide (GoPro's default mode);
4. a 35 mm-equivalent focal length in the file's metadata (phones; read with ExifTool);
5. the default camera of :mod:`egovid.core.camera.intrinsics`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from egovid.core.camera.exif import find_tag, read_tags
from egovid.core.camera.intrinsics import (
    DEFAULT_FOCAL_AT_1080P,
    HFOV_RANGE_DEG,
    Intrinsics,
    resolve_intrinsics,
)
from egovid.core.camera.lens import EQUIDISTANT, PINHOLE, Lens
from egovid.core.camera.telemetry import CameraTelemetry, read_camera_telemetry
from egovid.core.errors import EgovidError
from egovid.core.video import probe

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
    rotation in degrees (the intrinsics already account for it); ``lens`` its projection
    (:mod:`egovid.core.camera.lens`: fisheye where the camera recorded a fisheye lens mode).
    """

    intrinsics: Intrinsics
    source: str
    detail: str
    rotation: int = 0
    lens: Lens = PINHOLE

    def with_focal(self, focal_px: float, source: str, detail: str) -> CameraModel:
        """The same camera (and lens) with another focal length (pixels)."""
        i = self.intrinsics
        return CameraModel(Intrinsics.from_focal(i.width, i.height, focal_px), source, detail, self.rotation, self.lens)

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
            "lens": self.lens.describe(),
        }


def _lens_mode_focal(long_side: int, mode: str) -> tuple[float, str, Lens] | None:
    code = mode.strip().upper()[:1]
    if code not in GOPRO_LENS_HFOV:
        return None
    hfov, fisheye = GOPRO_LENS_HFOV[code]
    half = math.radians(hfov / 2.0)
    focal = long_side / 2.0 / (half if fisheye else math.tan(half))
    kind = "equidistant fisheye" if fisheye else "rectilinear"
    return focal, f"{hfov:g}° published field of view, {kind}", EQUIDISTANT if fisheye else PINHOLE


def resolve_camera(
    video: str | os.PathLike,
    focal: float | None = None,
    hfov: float | None = None,
    *,
    telemetry: CameraTelemetry | None = None,
    tags: dict | None = None,
) -> CameraModel:
    """The intrinsics of ``video`` in display orientation (see the module docstring for the order).

    ``telemetry`` (:class:`~egovid.core.camera.telemetry.CameraTelemetry`) and ``tags`` (ExifTool
    tags of the file) are read from the file when not given; metadata that cannot be read is
    skipped, never an error. Raises :class:`EgovidError` for an unreadable video or absurd ``focal``/``hfov``.
    """
    info = probe(video)
    w, h, rot = info.width, info.height, info.rotation
    long_side = max(w, h)
    if telemetry is None:
        try:
            telemetry = read_camera_telemetry(video)
        except EgovidError:
            telemetry = None
    mode = getattr(telemetry, "lens_mode", None)
    assumed = False
    if not mode and (getattr(telemetry, "make", None) or "").lower() == "gopro":
        mode, assumed = "W", True  # GoPro's default lens mode (Wide) where the file does not say
    found = _lens_mode_focal(long_side, mode) if mode else None
    if focal is not None or hfov is not None:
        # The user's focal length or field of view, through the lens the camera recorded.
        lens = found[2] if found is not None else PINHOLE
        intr = resolve_intrinsics(w, h, focal, hfov)
        what = f"--focal {focal:g} px" if focal is not None else f"--hfov {hfov:g}° across the long side"
        return CameraModel(intr, "flag", what, rot, lens)
    camera = " ".join(x for x in (getattr(telemetry, "make", None), getattr(telemetry, "model", None)) if x)
    if found is not None:
        f, how, lens = found
        name = "Wide (assumed: the file records no lens mode)" if assumed else telemetry.lens_name or mode
        return CameraModel(
            Intrinsics.from_focal(w, h, f), "lens-mode", f"{camera} {name} lens ({how})".strip(), rot, lens
        )
    f35 = getattr(telemetry, "zoom_35mm", None)
    if f35 is None:
        if tags is None:
            try:
                tags = read_tags(video)
            except EgovidError:
                tags = {}
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
