"""Camera telemetry embedded in video files, read with telemetry-parser (Gyroflow's reader).

telemetry-parser (PyPI) reads the IMU and metadata streams of GoPro (GPMF), Sony, Insta360, DJI,
CAMM and several phone-logger formats; dashcams are read through ExifTool instead
(:mod:`egovid.core.camera.exif`). What egovid needs from it:

* :class:`ImuSamples` — gyroscope (and accelerometer) samples, times in seconds on the video
  clock, in telemetry-parser's normalised IMU axes (not yet the camera's: the axis mapping is
  estimated against the video by :mod:`egovid.core.motion.gyro`);
* :class:`OrientationSamples` — the camera's own orientation quaternions where it records them
  (GoPro ``CORI`` camera orientation, ``IORI`` image orientation, and their product, the
  orientation of the *picture* under electronic stabilisation);
* the lens mode (GoPro ``VFOV``: W, M, N, S, L, ...), the electronic-stabilisation state (GoPro
  ``EISE``/``EISA``: HyperSmooth), the rolling-shutter readout time, make and model.

A CAMM track (Google's Camera Motion Metadata: Insta360, Street View apps) is read natively by
:mod:`egovid.core.camera.camm`, since telemetry-parser 0.3 reads nothing from a ``camm`` handler
track and only the first record of each ``meta`` sample: what the camera's own telemetry gives
comes first, CAMM fills in the gyro, accelerometer, readout time and orientation it lacks, and
replaces telemetry-parser's own reading of the same CAMM track (its camera ``"CAMM"``).
``imu_source`` and ``readout_source`` say which was used.

Everything is ``None`` (or empty) where the file has none; a file without any telemetry gives a
:class:`CameraTelemetry` with ``make is None``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from egovid.core.camera.camm import read_camm
from egovid.core.camera.imu import ImuSamples, OrientationSamples
from egovid.core.errors import EgovidError

#: GoPro lens modes (GPMF ``VFOV``/``ZFOV`` codes) and their names.
GOPRO_LENS_MODES = {
    "W": "Wide",
    "M": "Medium",
    "N": "Narrow",
    "S": "SuperView",
    "L": "Linear",
    "H": "HyperView",
    "X": "Max SuperView",
    "R": "Linear + Horizon Levelling",
}

#: telemetry-parser's camera name for a file it read as CAMM (the format, not a make).
CAMM_FORMAT_NAME = "CAMM"

#: EIS states that mean "the camera did not stabilise the picture".
_EIS_OFF = {"", "N", "NO", "OFF", "N/A", "NA", "0", "FALSE", "NONE"}


@dataclass(frozen=True)
class CameraTelemetry:
    """What telemetry-parser found in a file (``None``/empty where the file has none).

    ``lens_mode`` is the GoPro lens code (``"W"``, ``"M"``, ...; :data:`GOPRO_LENS_MODES`);
    ``stabilization`` the raw electronic-stabilisation setting as recorded (e.g. ``"N"``,
    ``"HS High"``); ``readout_ms`` the rolling-shutter readout time of one frame in
    milliseconds; ``zoom_35mm`` a 35 mm-equivalent focal length in millimetres where the camera
    records one (Sony). ``image_orientation`` is the orientation of the picture (GoPro: camera
    orientation times image orientation), ``camera_orientation`` the body's. ``imu_source`` and
    ``readout_source`` say where the IMU and the readout time came from (``None`` without them).
    """

    make: str | None = None
    model: str | None = None
    imu: ImuSamples | None = None
    camera_orientation: OrientationSamples | None = None
    image_orientation: OrientationSamples | None = None
    lens_mode: str | None = None
    stabilization: str | None = None
    readout_ms: float | None = None
    zoom_35mm: float | None = None
    tags: dict[str, Any] = field(default_factory=dict, repr=False)
    imu_source: str | None = None
    readout_source: str | None = None

    @property
    def has_gyro(self) -> bool:
        """True when the file carries gyroscope samples."""
        return self.imu is not None and len(self.imu) >= 2

    @property
    def lens_name(self) -> str | None:
        """Human name of :attr:`lens_mode` (``"Medium"``) or ``None``."""
        if self.lens_mode is None:
            return None
        return GOPRO_LENS_MODES.get(self.lens_mode.strip().upper()[:1], self.lens_mode)

    @property
    def electronically_stabilized(self) -> bool | None:
        """True when the camera stabilised the picture itself (GoPro HyperSmooth/EIS on), False
        when it says it did not, ``None`` when it does not say."""
        if self.stabilization is None:
            return None
        return str(self.stabilization).strip().upper() not in _EIS_OFF


def _fourcc(key: str) -> str:
    """telemetry-parser names unknown GPMF keys ``0x56464f56``: turn them into ``VFOV``."""
    if key.startswith("0x") and len(key) == 10:
        try:
            text = bytes.fromhex(key[2:]).decode("ascii")
        except (ValueError, UnicodeDecodeError):
            return key
        if text.isprintable():
            return text
    return key


def _flat_tags(blocks: list[dict]) -> dict[str, Any]:
    """First value of each ``Group.Key`` over all payloads (unknown keys as four-character codes)."""
    out: dict[str, Any] = {}
    for blk in blocks:
        for group, tags in blk.items():
            if not isinstance(tags, dict):
                continue
            for key, value in tags.items():
                if key == "Data":
                    continue
                out.setdefault(f"{group}.{_fourcc(key)}", value)
    return out


def _first(tags: dict[str, Any], *keys: str) -> Any | None:
    for k in keys:
        for full, v in tags.items():
            if full.endswith("." + k) and v not in (None, ""):
                return v
    return None


def _quaternion_samples(blocks: list[dict], group: str) -> OrientationSamples | None:
    """Time-stamped quaternions of ``group`` (telemetry-parser's ``Quaternion`` group holds
    ``{"t": ms, "v": {"w","x","y","z"}}`` items)."""
    t, q = [], []
    for blk in blocks:
        data = blk.get(group, {}).get("Data") if isinstance(blk.get(group), dict) else None
        if not isinstance(data, list):
            continue
        for item in data:
            if not isinstance(item, dict) or "t" not in item:
                continue
            v = item.get("v", item)
            try:
                q.append([float(v["w"]), float(v["x"]), float(v["y"]), float(v["z"])])
                t.append(float(item["t"]) / 1000.0)
            except (KeyError, TypeError, ValueError):
                continue
    if len(t) < 2:
        return None
    quats = np.asarray(q)
    norms = np.linalg.norm(quats, axis=1, keepdims=True)
    ok = norms[:, 0] > 1e-9
    order = np.argsort(np.asarray(t)[ok], kind="stable")
    return OrientationSamples(np.asarray(t)[ok][order], (quats[ok] / norms[ok])[order])


def _raw_quaternions(blocks: list[dict], group: str, like: OrientationSamples | None) -> OrientationSamples | None:
    """GoPro ``CORI``/``IORI`` as stored (int16 / Scale, no times of their own), on the times of
    telemetry-parser's per-frame product ``like`` (one sample per frame each); x is negated
    like telemetry-parser does for the product, so both share its axes."""
    q = []
    for blk in blocks:
        g = blk.get(group)
        if not isinstance(g, dict) or not isinstance(g.get("Data"), list):
            continue
        scale = float(g.get("Scale") or 32767)
        for v in g["Data"]:
            try:
                q.append([float(v["w"]) / scale, -float(v["x"]) / scale, float(v["y"]) / scale, float(v["z"]) / scale])
            except (KeyError, TypeError, ValueError):
                continue
    if like is None or len(q) != len(like) or len(q) < 2:
        return None
    quats = np.asarray(q)
    norms = np.linalg.norm(quats, axis=1, keepdims=True)
    if np.any(norms < 1e-9):
        return None
    return OrientationSamples(like.times.copy(), quats / norms)


def _imu(samples: list[dict]) -> ImuSamples | None:
    tg, g, ta, a = [], [], [], []
    for s in samples:
        t = s.get("timestamp_ms")
        if t is None:
            continue
        if s.get("gyro") is not None:
            tg.append(t)
            g.append(s["gyro"])
        if s.get("accl") is not None:
            ta.append(t)
            a.append(s["accl"])
    if len(tg) < 2:
        return None
    times = np.asarray(tg, float) / 1000.0
    gyro = np.radians(np.asarray(g, float))
    order = np.argsort(times, kind="stable")
    times, gyro = times[order], gyro[order]
    keep = np.concatenate([[True], np.diff(times) > 0]) & np.all(np.isfinite(gyro), axis=1)
    accel = accel_times = None
    if len(ta) >= 2:
        accel_times = np.asarray(ta, float) / 1000.0
        accel = np.asarray(a, float)
    return ImuSamples(times[keep], gyro[keep], accel, accel_times)


def read_camera_telemetry(path: str | os.PathLike) -> CameraTelemetry:
    """Telemetry of ``path`` (telemetry-parser's reading, then the file's CAMM track: see the
    module docstring); an empty :class:`CameraTelemetry` when the file has none.

    Raises :class:`EgovidError` only when the file does not exist or cannot be read at all.
    """
    p = Path(path)
    if not p.is_file():
        raise EgovidError(f"file not found: {p}", "check the path")
    return _with_camm(p, _parsed_telemetry(p))


def _parsed_telemetry(p: Path) -> CameraTelemetry:
    """What telemetry-parser reads from ``p``."""
    import telemetry_parser

    try:
        parser = telemetry_parser.Parser(str(p))
    except FileNotFoundError:
        raise EgovidError(f"file not found: {p}", "check the path") from None
    except OSError as exc:
        if "nsupported" in str(exc):
            return CameraTelemetry()  # no telemetry format telemetry-parser knows
        raise EgovidError(f"cannot read {p} ({exc})", "check the file's permissions") from None
    except Exception:  # telemetry-parser panics on some damaged files: treat as no telemetry
        return CameraTelemetry()
    try:
        blocks = parser.telemetry() or []
    except Exception:
        blocks = []
    try:
        imu = _imu(parser.normalized_imu() or [])
    except Exception:
        imu = None
    tags = _flat_tags(blocks)
    picture = _quaternion_samples(blocks, "Quaternion")
    lens = _first(tags, "VFOV", "ZFOV")
    eis = _first(tags, "EISA", "EISE")
    readout = _float_or_none(_first(tags, "SROT"))
    zoom = _first(tags, "LensZoom35mm", "Focal length (35mm)")
    make = parser.camera or None
    return CameraTelemetry(
        make=make,
        model=parser.model or None,
        imu=imu,
        camera_orientation=_raw_quaternions(blocks, "CameraOrientation", picture),
        image_orientation=picture,
        lens_mode=str(lens) if lens is not None else None,
        stabilization=str(eis) if eis is not None else None,
        readout_ms=readout,
        zoom_35mm=_float_or_none(zoom),
        tags=tags,
        imu_source=f"{make or 'camera'} telemetry (telemetry-parser)" if imu is not None else None,
        readout_source="the file (GoPro SROT)" if readout is not None else None,
    )


def _with_camm(p: Path, tel: CameraTelemetry) -> CameraTelemetry:
    """``tel`` with what the file's CAMM track adds (see the module docstring)."""
    camm = read_camm(p)
    if camm is None:
        return tel
    same = tel.make == CAMM_FORMAT_NAME  # telemetry-parser's own (partial) reading of this track
    changes: dict[str, Any] = {}
    imu = camm.imu()
    if imu is not None and (tel.imu is None or same):
        changes.update(imu=imu, imu_source=f"CAMM track ({camm.handler} handler)")
    readout = camm.readout_ms()
    if readout is not None and (tel.readout_ms is None or same):
        changes.update(readout_ms=readout, readout_source="the file (CAMM rolling-shutter skew)")
    orientation = camm.orientation()
    if orientation is not None and (tel.camera_orientation is None or same):
        changes.update(camera_orientation=orientation)
    return replace(tel, **changes) if changes else tel


def _float_or_none(value: Any) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) and v > 0 else None
