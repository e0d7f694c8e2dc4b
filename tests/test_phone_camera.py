"""Phones' lens profiles: make and model from the container's own keys, the main camera assumed,
brand-aware lookup, and the profile turned by the rotation flag as the decoder turns the frames."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from egovid.core.camera.exif import ExifTool
from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.lens_profiles import camera_key, find_profile, profiles_of
from egovid.core.camera.resolve import resolve_camera
from egovid.core.errors import EgovidError
from egovid.core.video import probe
from egovid.core.video.read import iter_frames

from conftest import run_tool

ANDROID = {"com.android.manufacturer": "samsung", "com.android.model": "SM-G991B", "com.android.version": "13"}
APPLE = {"com.apple.quicktime.make": "Apple", "com.apple.quicktime.model": "iPhone 13 Pro"}
#: A white 4x4 box at coded pixels x 40-43, y 6-9 (centre 41.5, 7.5) of a 192x108 black picture.
BOX = (40, 6, 4)


def _clip(path: Path, keys: dict[str, str], rotation_cw: int = 0) -> Path:
    """A 192x108 (16:9), 3-frame H.264 clip with ``keys`` as QuickTime metadata keys (as phones
    write them) and, where asked, ExifTool's ``Rotation`` (degrees clockwise: the display matrix)."""
    x, y, n = BOX
    meta = [a for k, v in keys.items() for a in ("-metadata", f"{k}={v}")]
    run_tool([
        "ffmpeg", "-v", "error", "-y", "-f", "lavfi",
        "-i", f"color=black:s=192x108:r=10:d=0.3,drawbox=x={x}:y={y}:w={n}:h={n}:color=white:t=fill",
        "-c:v", "libx264", "-qp", "0", "-pix_fmt", "yuv420p", "-movflags", "use_metadata_tags", *meta, path,
    ])  # fmt: skip
    if rotation_cw:
        run_tool(["exiftool", "-q", "-overwrite_original", f"-Rotation={rotation_cw}", path])
    return path


def test_camera_keys_compare_brand_and_model():
    assert camera_key("Apple", "iPhone13Pro") == camera_key("apple", "iPhone 13 Pro") == "appleiphone13pro"
    assert camera_key("samsung", "SM-G991B") == camera_key("Samsung Electronics", "Galaxy S21") == "samsungs21"
    assert camera_key("Xiaomi", "Redmi Note 10") == camera_key("Redmi", "Note 10")
    assert camera_key("GoPro", "GoPro Max") == camera_key("GoPro", "MAX")
    # Brand-aware: the same model name of another maker is another camera.
    assert camera_key("OnePlus", "13") != camera_key("Xiaomi", "13")
    assert all(p.brand == "Xiaomi" for p in profiles_of("Xiaomi", "13"))


def test_android_file_gets_its_phone_profile(tmp_path):
    cam = resolve_camera(_clip(tmp_path / "android.mp4", ANDROID))
    (p,) = profiles_of("Samsung", "Galaxy S21")  # the database's one S21 calibration, 1920x1080
    assert cam.source == "lens-profile", cam.detail
    assert cam.profile["profile"] == p.name and "com.android.manufacturer/model" in cam.profile["camera"]
    assert "main (wide) camera, assumed" in cam.detail
    i = cam.intrinsics
    assert (i.fx, i.cx) == pytest.approx((p.fx * 0.1, (p.cx + 0.5) * 0.1 - 0.5))
    assert i.distortion == p.distortion


def test_apple_file_gets_its_main_camera(tmp_path):
    cam = resolve_camera(_clip(tmp_path / "apple.mov", APPLE))
    assert cam.source == "lens-profile", cam.detail
    assert cam.profile["profile"].startswith("Apple iPhone 13 Pro") and "com.apple.quicktime" in cam.detail
    chosen = next(p for p in profiles_of("Apple", "iPhone 13 Pro") if p.name == cam.profile["profile"])
    assert chosen.phone_lens == "main" and 20 <= chosen.focal_35mm <= 40
    assert cam.intrinsics.fx == pytest.approx(chosen.fx * 192 / chosen.width)
    # The file names its front camera: none of the database's iPhone 13 Pro profiles is one.
    front = _clip(tmp_path / "front.mov", {**APPLE, "com.apple.quicktime.camera.lens_model": "front TrueDepth camera"})
    cam = resolve_camera(front)
    assert cam.source == "default" and "front camera, as the file says" in cam.detail


def test_unknown_phone_falls_back_and_says_why(tmp_path):
    acme = _clip(tmp_path / "acme.mp4", {"com.android.manufacturer": "Acme", "com.android.model": "Phone X1"})
    cam = resolve_camera(acme)
    assert cam.source == "default" and "no lens profile of Acme Phone X1" in cam.detail, cam.detail
    # A model name the database holds for another maker only is not that maker's.
    r = find_profile("OnePlus", "13", 1920, 1080, phone=True)
    assert r.match is None and "Xiaomi's" in r.reason


@pytest.mark.parametrize("rotation", [0, 90, 180, 270])
def test_rotation_hand_computed(rotation):
    """HERO7 Black Wide (EIS) at its own 1920x1080 calibration: no scaling, so the display
    intrinsics are the profile's numbers moved by hand (x' = y, y' = 1919 - x at 90° CCW; ...)."""
    w, h = (1080, 1920) if rotation % 180 else (1920, 1080)
    m = find_profile("GoPro", "HERO7 Black", w, h, lens="W", stabilized=True, fps=29.97, rotation=rotation).match
    p = m.profile
    assert (p.width, p.height) == (1920, 1080)
    want = {
        0: (p.fx, p.fy, p.cx, p.cy),
        90: (p.fy, p.fx, p.cy, 1919 - p.cx),
        180: (p.fx, p.fy, 1919 - p.cx, 1079 - p.cy),
        270: (p.fy, p.fx, 1079 - p.cy, p.cx),
    }[rotation]
    assert (m.fx, m.fy, m.cx, m.cy) == pytest.approx(want, abs=1e-9)
    if rotation:
        assert f"turned {rotation}°" in m.reason


def test_rotated_intrinsics_compose():
    i = Intrinsics(192, 108, 150.0, 151.0, 90.0, 50.0, (0.1, 0.0, 0.0, 0.0))
    assert i.rotated(90).rotated(270) == i == i.rotated(180).rotated(180) == i.rotated(90).rotated(90).rotated(180)
    assert i.rotated(90) == Intrinsics(108, 192, 151.0, 150.0, 50.0, 101.0, i.distortion)  # (x, y) -> (y, 191 - x)
    with pytest.raises(EgovidError, match="multiple of 90"):
        i.rotated(45)


@pytest.fixture(scope="module")
def turned_clips(tmp_path_factory) -> dict[int, tuple[Path, dict]]:
    """The Android clip flat and turned 90, 180, 270° clockwise, each with its ExifTool tags (read
    by one ExifTool process)."""
    folder = tmp_path_factory.mktemp("turned")
    clips = {r: _clip(folder / f"turned{r}.mp4", ANDROID, r) for r in (0, 90, 180, 270)}
    with ExifTool() as et:
        return {r: (path, et.tags(path)) for r, path in clips.items()}


@pytest.mark.parametrize("rotation_cw", [90, 180, 270])
def test_intrinsics_follow_the_decoders_rotation(turned_clips, rotation_cw):
    """A box at a known coded pixel: where the decoder puts it in display orientation is where
    :meth:`Intrinsics.rotated` puts a principal point at that pixel; and a rotated phone file's
    intrinsics are its landscape twin's, turned the same way."""
    turned, tags = turned_clips[rotation_cw]
    rot = probe(turned).rotation
    assert rot == (360 - rotation_cw) % 360  # ExifTool's Rotation is clockwise, egovid's counter-clockwise
    (first,) = list(iter_frames(turned, gray=True, max_frames=1))
    ys, xs = np.nonzero(first.image > 128)
    x, y, n = BOX
    marker = Intrinsics(192, 108, 100.0, 100.0, x + (n - 1) / 2, y + (n - 1) / 2).rotated(rot)
    assert first.image.shape == (marker.height, marker.width)
    assert (xs.mean(), ys.mean()) == pytest.approx((marker.cx, marker.cy), abs=0.01)
    a = resolve_camera(turned_clips[0][0], tags=turned_clips[0][1])
    b = resolve_camera(turned, tags=tags)
    assert b.rotation == rot and b.source == a.source == "lens-profile"
    want, got = a.intrinsics.rotated(rot), b.intrinsics
    assert (got.width, got.height, got.distortion) == (want.width, want.height, want.distortion)
    assert (got.fx, got.fy, got.cx, got.cy) == pytest.approx((want.fx, want.fy, want.cx, want.cy), abs=1e-9)


def test_gopro_lookups_unchanged():
    """Every GoPro model of the database, at 4 sizes x 5 lens modes x 3 stabilisation states, looks
    up the very profile and numbers it did before the brand-aware lookup (frozen from commit
    1da6164's find_profile in tests/data/lens/gopro_lookups_before.json.gz)."""
    rows = json.loads(gzip.decompress((Path(__file__).parent / "data/lens/gopro_lookups_before.json.gz").read_bytes()))
    assert len(rows) == 2700
    changed = []
    for model, w, h, lens, stab, want in rows:
        m = find_profile("GoPro", model, w, h, lens=lens, stabilized=stab, fps=29.97).match
        got = None if m is None else [m.profile.name, *(round(v, 4) for v in (m.fx, m.fy, m.cx, m.cy))]
        if got != want:
            changed.append((model, w, h, lens, stab, want, got))
    assert not changed, changed[:5]
