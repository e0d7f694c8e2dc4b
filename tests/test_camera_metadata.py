"""Camera metadata (ExifTool) and embedded telemetry (telemetry-parser) on the real clips."""

from __future__ import annotations

import numpy as np
import pytest

from egovid.core.camera.exif import ExifTool, find_tag, read_tags
from egovid.core.camera.telemetry import read_camera_telemetry
from egovid.core.errors import EgovidError


def test_exiftool_reads_container_and_embedded_gpmf(karma_clip):
    with ExifTool() as et:
        plain = et.tags(karma_clip)
        embedded = et.tags(karma_clip, embedded=True, duplicates=True)
    assert plain["Main:ImageWidth"] == 854 and plain["Main:ImageHeight"] == 480
    assert find_tag(plain, ["FirmwareVersion"]) == "HD5.02.02.00.00"
    # -ee -a -G3:4: every GPS fix of every GPMF payload, one Copy group per sample (47 fixes, SOURCES.md).
    lats = [v for k, v in embedded.items() if k.endswith(":GPSLatitude")]
    assert len(lats) == 47
    assert all(33.12 < v < 33.13 for v in lats)  # -n: signed decimal degrees


def test_exiftool_errors_name_the_file(tmp_path):
    bad = tmp_path / "noise.mp4"
    bad.write_bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    with pytest.raises(EgovidError, match="File format error"):
        read_tags(bad)
    with pytest.raises(EgovidError, match="not found"):
        read_tags(tmp_path / "missing.mp4")


def test_exiftool_missing_is_a_clear_error(monkeypatch):
    monkeypatch.setenv("PATH", "/nonexistent")
    with pytest.raises(EgovidError, match=r"ExifTool is not installed.*libimage-exiftool-perl"):
        ExifTool().start()


def test_gopro_telemetry(karma_clip):
    tel = read_camera_telemetry(karma_clip)
    assert (tel.make, tel.model) == ("GoPro", "HERO5 Black")
    assert tel.has_gyro
    imu = tel.imu
    # 400 Hz gyro (SOURCES.md) over the 12.1 s clip, on the video clock.
    assert 395 < imu.rate_hz < 402
    assert imu.times[0] == pytest.approx(0.0, abs=0.05) and imu.times[-1] == pytest.approx(12.06, abs=0.1)
    assert np.all(np.diff(imu.times) > 0)
    # rad/s: a gimbal-held drone turns at most a few rad/s; the final pan is clearly visible.
    rate = np.linalg.norm(imu.gyro, axis=1)
    assert rate.max() < 5.0 and rate[imu.times > 11.8].mean() > 0.5 > rate[imu.times < 11].max()
    # The accelerometer at rest-ish sees gravity (m/s²).
    assert np.median(np.linalg.norm(imu.accel, axis=1)) == pytest.approx(9.8, abs=1.0)
    assert (tel.lens_mode, tel.lens_name) == ("M", "Medium")
    assert tel.electronically_stabilized is False
    assert tel.image_orientation is None  # HERO5 records no CORI/IORI


def test_no_telemetry_is_empty_not_an_error(handheld_clip, tmp_path):
    tel = read_camera_telemetry(handheld_clip)
    assert tel.make is None and tel.imu is None and not tel.has_gyro
    assert tel.lens_mode is None and tel.electronically_stabilized is None
    with pytest.raises(EgovidError, match="not found"):
        read_camera_telemetry(tmp_path / "missing.mp4")


def test_intrinsics_resolution_order(karma_clip, handheld_clip, tmp_path):
    import math
    import shutil
    import subprocess

    from egovid.core.camera.resolve import resolve_camera

    # The HERO5's calibrated Medium profile (NO-EIS, 2704x1520 scaled to 854 px), with its
    # fisheye distortion, before GoPro's published field of view.
    cam = resolve_camera(karma_clip)
    assert cam.source == "lens-profile" and "Medium" in cam.detail, cam.detail
    assert cam.intrinsics.distortion is not None and cam.profile["calibration_size"] == [2704, 1520]
    assert cam.intrinsics.focal == pytest.approx(552.2, abs=0.5)
    assert cam.to_dict()["lens_profile"]["reason"] == cam.detail
    # A lens mode with no profile for the camera: GoPro's published field of view, equidistant.
    from egovid.core.camera.telemetry import CameraTelemetry

    unknown = CameraTelemetry(make="GoPro", model="HERO99 Black", lens_mode="M")
    cam = resolve_camera(karma_clip, telemetry=unknown)
    assert cam.source == "lens-mode" and "no lens profile" in cam.detail
    assert cam.intrinsics.focal == pytest.approx(427.0 / math.radians(47.2), rel=1e-6)
    # Flags win over the file.
    assert resolve_camera(karma_clip, focal=500.0).source == "flag"
    assert resolve_camera(karma_clip, hfov=90.0).intrinsics.focal == pytest.approx(427.0, rel=1e-6)
    # A 35 mm-equivalent focal length (as phones write it), on the diagonal of the picture.
    phone = tmp_path / "phone.mp4"
    shutil.copy(handheld_clip, phone)
    subprocess.run(
        ["exiftool", "-q", "-overwrite_original", "-XMP-exif:FocalLengthIn35mmFormat=26", str(phone)], check=True
    )
    cam = resolve_camera(phone)
    assert cam.source == "35mm-equivalent"
    assert cam.intrinsics.focal == pytest.approx(26.0 * math.hypot(1920, 1080) / math.hypot(36, 24), rel=1e-6)
    # Nothing in the file: the default camera, scaled by the long side.
    cam = resolve_camera(handheld_clip)
    assert cam.source == "default" and cam.intrinsics.focal == pytest.approx(830.0)


def test_lens_candidates_of_a_file_that_names_no_lens(karma_clip):
    """The HERO6 clip's re-mux lost its lens mode: resolved from the assumed Wide mode, its
    candidates are the camera's calibrated lenses at this size (Wide with no EIS, once the picture
    is known not to be stabilised in the camera; Linear), each with its own fisheye terms, for the
    gyro to choose from; the Karma clip names its lens (Medium), so it has nothing to choose."""
    from egovid.core.camera.resolve import lens_candidates, resolve_camera

    from conftest import real_clip

    hero6 = real_clip("gopro-hero6-2s.mp4")
    tel = read_camera_telemetry(hero6)
    cam = resolve_camera(hero6, telemetry=tel)
    assert cam.source == "lens-mode" and not tel.lens_mode
    found = lens_candidates(hero6, cam, tel, stabilized=False)
    focal = sorted(round(c.intrinsics.fx, 1) for c in found)
    assert focal == [387.6, 459.6] and all(c.source == "lens-profile" and any(c.intrinsics.distortion) for c in found)
    assert lens_candidates(hero6, cam, tel) and all("Wide" not in c.detail for c in lens_candidates(hero6, cam, tel))
    ktel = read_camera_telemetry(karma_clip)
    assert lens_candidates(karma_clip, resolve_camera(karma_clip, telemetry=ktel), ktel) == []
