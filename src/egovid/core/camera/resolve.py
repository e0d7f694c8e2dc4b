"""Which intrinsics a video file has, and where they come from.

:func:`resolve_camera` is the one place that decides a video's intrinsics, in this order (the
JSON says which, and why, under ``intrinsics.source``/``detail``):

1. ``--focal PX`` or ``--hfov DEG`` given by the user (``flag``);
2. the file's own facts: a 35 mm-equivalent focal length in its metadata (phones, Sony; read with
   telemetry-parser or ExifTool; ``35mm-equivalent``);
3. the calibrated lens profile of the camera (Gyroflow's database,
   :mod:`egovid.core.camera.lens_profiles`): camera model, lens mode, stabilisation setting and
   resolution from the file, with the lens's fisheye distortion (``lens-profile``); a phone is
   known by its container's own keys (:func:`phone_camera`: Android's ``com.android.manufacturer``
   / ``com.android.model``, Apple's ``com.apple.quicktime.make`` / ``.model``), and its main
   camera is taken unless the file names another (Apple's ``com.apple.quicktime.camera.lens_model``);
   the profile is turned by the container's rotation flag as the decoder turns the frames;
4. (in :mod:`egovid.core.motion.source`, when a gyro is recorded) for a GoPro file that names no
   lens, the calibrated lens the gyro confirms among the camera's (:func:`lens_candidates`,
   ``lens-profile``); else the focal length fitted from the gyro against the video
   (``gyro-fit``), which refines only what follows;
5. the lens mode the camera recorded (GoPro ``VFOV``: Wide, Medium, Narrow, SuperView, Linear),
   through GoPro's published field of view and an equidistant (fisheye) lens (``lens-mode``); a
   GoPro file that records none is taken as Wide (GoPro's default mode);
6. the default camera of :mod:`egovid.core.camera.intrinsics` (``default``).

A fisheye lens is the intrinsics' OpenCV-fisheye ``distortion`` (``k = 0``: equidistant), and
:attr:`CameraModel.lens` is the same lens for projecting rays (:mod:`egovid.core.camera.lens`); a
``--focal``/``--hfov`` given by the user keeps the lens kind the camera recorded.

The frame readout time of a rolling shutter comes with it: GoPro's ``SROT`` (the file's own),
else the profile's calibrated one for this very mode (``readout_ms``, ``readout_source``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace

from egovid.core.camera.exif import find_tag, read_tags
from egovid.core.camera.intrinsics import (
    DEFAULT_FOCAL_AT_1080P,
    HFOV_RANGE_DEG,
    Intrinsics,
    resolve_intrinsics,
)
from egovid.core.camera.lens import EQUIDISTANT, PINHOLE, Lens
from egovid.core.camera.lens_profiles import LensMatch, find_profile
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

#: ExifTool tag names of a phone's make and model in its container's own keys, with the keys
#: they come from: Android's MediaRecorder writes ``com.android.manufacturer``/``.model``
#: (ExifTool: ``AndroidManufacturer``/``AndroidModel``), Apple's camera
#: ``com.apple.quicktime.make``/``.model`` (ExifTool: ``Make``/``Model``, which only Apple's keys
#: make a phone's) and ``com.apple.quicktime.camera.lens_model`` (``CameraLensModel``).
PHONE_TAGS = {
    "android": ("AndroidManufacturer", "AndroidModel", "com.android.manufacturer/model"),
    "apple": ("Make", "Model", "com.apple.quicktime.make/model"),
}
#: ExifTool tag names of the Apple camera's lens words (``"iPhone 13 Pro front TrueDepth camera 2.71mm f/2.2"``).
PHONE_LENS_TAGS = ("CameraLensModel", "LensModel")

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
    readout_ms: float | None = None
    readout_source: str = ""
    profile: dict | None = None

    @property
    def lens(self) -> Lens:
        """How the lens maps rays to pixels: the OpenCV fisheye of the intrinsics' distortion, else a pinhole."""
        d = self.intrinsics.distortion
        return PINHOLE if d is None else Lens("fisheye", tuple(float(x) for x in d))

    def with_focal(self, focal_px: float, source: str, detail: str) -> CameraModel:
        """The same camera with another focal length (pixels). An equidistant fisheye stays one; a
        profile's distortion terms belong to its own focal length, so they are dropped (a pinhole)."""
        i = self.intrinsics
        keep = i.distortion if i.distortion is not None and not any(i.distortion) else None
        intr = replace(Intrinsics.from_focal(i.width, i.height, focal_px), distortion=keep)
        return CameraModel(intr, source, detail, self.rotation, self.readout_ms, self.readout_source)

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
            "distortion_fisheye_k": list(i.distortion) if i.distortion is not None else None,
            "readout_ms": self.readout_ms,
            "readout_source": self.readout_source or None,
            "lens_profile": self.profile,
        }


def _lens_mode_focal(long_side: int, mode: str) -> tuple[float, str, bool] | None:
    """GoPro's published lens mode ``mode`` at ``long_side`` pixels: (focal length in pixels, how,
    whether the lens is an equidistant fisheye); None for a mode egovid does not know."""
    code = mode.strip().upper()[:1]
    if code not in GOPRO_LENS_HFOV:
        return None
    hfov, fisheye = GOPRO_LENS_HFOV[code]
    half = math.radians(hfov / 2.0)
    focal = long_side / 2.0 / (half if fisheye else math.tan(half))
    kind = "equidistant fisheye" if fisheye else "rectilinear"
    return focal, f"{hfov:g}° published field of view, {kind}", fisheye


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
    if focal is not None or hfov is not None:  # the user's, through the lens the camera recorded
        intr = resolve_intrinsics(w, h, focal, hfov)
        if found is not None and found[2]:
            intr = replace(intr, distortion=EQUIDISTANT.k)
        what = f"--focal {focal:g} px" if focal is not None else f"--hfov {hfov:g}° across the long side"
        return CameraModel(intr, "flag", what, rot)
    camera = " ".join(x for x in (getattr(telemetry, "make", None), getattr(telemetry, "model", None)) if x)
    readout = getattr(telemetry, "readout_ms", None)
    readout_from = (getattr(telemetry, "readout_source", None) or "the file") if readout else ""
    f35 = getattr(telemetry, "zoom_35mm", None)
    if tags is None and (f35 is None or not getattr(telemetry, "make", None)):
        try:
            tags = read_tags(video)
        except EgovidError:
            tags = {}
    if f35 is None:
        f35 = _positive(find_tag(tags, FOCAL_35MM_TAGS))
    if f35 is not None:
        f = f35 * math.hypot(w, h) / FILM_DIAGONAL_MM
        if HFOV_RANGE_DEG[0] < 2 * math.degrees(math.atan2(long_side / 2, f)) < HFOV_RANGE_DEG[1]:
            return CameraModel(
                Intrinsics.from_focal(w, h, f), "35mm-equivalent", f"{f35:g} mm (35 mm equivalent)", rot,
                readout, readout_from,
            )  # fmt: skip
    phone = None if getattr(telemetry, "make", None) else phone_camera(tags or {})
    if phone is not None:
        make, model, lens, origin = phone
        looked = find_profile(make, model, w, h, lens=lens, fps=info.fps, phone=True, rotation=rot)
        camera = f"{make} {model} (the file's {origin})"
    else:
        looked = find_profile(
            getattr(telemetry, "make", None), _model_of(telemetry), w, h, lens=None if assumed else mode,
            stabilized=getattr(telemetry, "electronically_stabilized", None), fps=info.fps, rotation=rot,
        )  # fmt: skip
    if looked.match is not None:
        m = looked.match
        detail = looked.reason if phone is None else f"{camera}: {looked.reason}"
        about = m.to_dict() if phone is None else {**m.to_dict(), "camera": camera}
        return _profile_camera(m, w, h, detail, rot, readout, readout_from, about)
    if found is not None:
        f, how, fisheye = found
        name = "Wide (assumed: the file records no lens mode)" if assumed else telemetry.lens_name or mode
        detail = f"{camera} {name} lens ({how}); no lens profile: {looked.reason}".strip()
        intr = replace(Intrinsics.from_focal(w, h, f), distortion=EQUIDISTANT.k if fisheye else None)
        return CameraModel(intr, "lens-mode", detail, rot, readout, readout_from)
    return CameraModel(
        Intrinsics.default(w, h), "default",
        f"{DEFAULT_FOCAL_AT_1080P:g} px at 1920 px, scaled to the long side; no lens profile: {looked.reason}"
        + (f" ({camera})" if phone is not None else ""),
        rot, readout, readout_from,
    )  # fmt: skip


def lens_candidates(
    video: str | os.PathLike, camera: CameraModel, telemetry: CameraTelemetry, stabilized: bool | None = None
) -> list[CameraModel]:
    """The calibrated lenses a camera that names none may have used: one ``lens-profile`` camera per
    GoPro lens class with a profile for this camera, size and setting (:data:`GOPRO_LENS_HFOV`'s
    modes with a fisheye model), for a ``camera`` resolved from the lens mode GoPro assumes (Wide)
    because the file records none (a re-muxed file); ``stabilized`` is whether the camera stabilised
    the picture where the file does not say (measured: :mod:`egovid.core.motion.eis`; None: unknown,
    then only profiles that agree among themselves). Empty otherwise: a file that names its lens,
    or a camera already resolved otherwise, has nothing to choose. Which one the video shows is
    for the gyro to tell (:func:`egovid.core.motion.source.camera_motion`)."""
    if camera.source != "lens-mode" or getattr(telemetry, "lens_mode", None):
        return []
    info = probe(video)
    out: list[CameraModel] = []
    seen: set[tuple[float, tuple[float, ...] | None]] = set()
    for code in GOPRO_LENS_HFOV:
        looked = find_profile(
            telemetry.make, _model_of(telemetry), info.width, info.height, lens=code,
            stabilized=telemetry.electronically_stabilized if stabilized is None else stabilized, fps=info.fps,
            rotation=camera.rotation,
        )  # fmt: skip
        m = looked.match
        if m is None or (m.fx, m.distortion) in seen:
            continue
        seen.add((m.fx, m.distortion))
        w, h, rot = info.width, info.height, camera.rotation
        out.append(_profile_camera(m, w, h, looked.reason, rot, camera.readout_ms, camera.readout_source, m.to_dict()))
    return out


def _profile_camera(
    m: LensMatch,
    width: int,
    height: int,
    detail: str,
    rotation: int,
    readout: float | None,
    readout_from: str | None,
    about: dict,
) -> CameraModel:
    """The ``lens-profile`` camera of profile match ``m`` for a ``width`` x ``height`` px video:
    its intrinsics and distortion, and its readout (ms) where the file gave none."""
    if readout is None and m.readout_ms:
        readout, readout_from = m.readout_ms, "the lens profile"
    intr = Intrinsics(width, height, m.fx, m.fy, m.cx, m.cy, m.distortion)
    return CameraModel(intr, "lens-profile", detail, rotation, readout, readout_from, about)


def phone_camera(tags: dict) -> tuple[str, str, str | None, str] | None:
    """The phone that recorded a file, from its container's own keys in ExifTool ``tags``
    (:data:`PHONE_TAGS`): ``(make, model, lens words or None, which keys)``; None when the file
    carries no phone's keys (a ``Make`` that is not Apple's is no phone's: cameras write it too)."""
    for kind, (make_tag, model_tag, origin) in PHONE_TAGS.items():
        make, model = find_tag(tags, [make_tag]), find_tag(tags, [model_tag])
        if not make or not model or (kind == "apple" and str(make).strip().lower() != "apple"):
            continue
        lens = find_tag(tags, PHONE_LENS_TAGS) if kind == "apple" else None
        return str(make).strip(), str(model).strip(), str(lens).strip() if lens else None, origin
    return None


def _model_of(telemetry) -> str | None:
    """The camera model: telemetry-parser's, else the GPMF device name when it names a model
    (a re-muxed GoPro file keeps only that: ``Hero6 Black``)."""
    model = getattr(telemetry, "model", None)
    if model:
        return model
    name = (getattr(telemetry, "tags", None) or {}).get("Default.Name")
    return str(name) if name and str(name).lower() not in ("camera", "") else None


def _positive(value) -> float | None:
    try:
        v = float(str(value).split()[0])
    except (TypeError, ValueError, IndexError):
        return None
    return v if math.isfinite(v) and v > 0 else None
