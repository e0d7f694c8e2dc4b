"""The shipped lens-profile index and its lookup (Gyroflow's CC0 database)."""

from __future__ import annotations

import pytest

from egovid.core.camera.lens_profiles import (
    find_profile,
    lens_class,
    load_profiles,
    model_key,
    profiles_of,
    stabilization_state,
)


def test_index_holds_the_database():
    profiles = load_profiles()
    assert len(profiles) > 9500  # 9,810 files less the few without a camera matrix
    brands = {p.brand for p in profiles}
    assert {"GoPro", "Sony", "DJI", "Insta360", "Apple"} <= brands
    assert all(p.fx > 0 and p.width > 0 and len(p.distortion) == 4 for p in profiles)


def test_words_are_compared_without_case_or_brand():
    assert model_key("GoPro", "GoPro Max") == model_key("", "MAX") == "max"
    assert model_key("GoPro", "Hero6 Black") == model_key("GoPro", "HERO6 Black")
    assert lens_class("Max", "Max") == "max superview" and lens_class("Max", "HERO10 Black") == "max lens mod"
    assert lens_class("Linear + anamorph") == "anamorphic"
    assert stabilization_state("NO-EIS") is False and stabilization_state("HS EIS") is True
    assert stabilization_state("") is None


def test_hero5_medium_scaled_from_its_27k_calibration():
    """The Karma clip's camera (HERO5 Black, Medium, no EIS, 854x480 at 29.97 fps): the non-EIS
    Medium calibration at 2704x1520, scaled by 854/2704 (same 16:9 aspect)."""
    found = find_profile("GoPro", "HERO5 Black", 854, 480, lens="M", stabilized=False, fps=29.97)
    m = found.match
    assert m is not None, found.reason
    p = m.profile
    assert p.lens_class == "medium" and p.eis is not True and (p.width, p.height) == (2704, 1520)
    assert m.fx == pytest.approx(p.fx * 854 / 2704)
    assert m.cx == pytest.approx((p.cx + 0.5) * 854 / 2704 - 0.5)
    assert m.distortion == p.distortion
    assert "Medium" in m.reason and "scaled" in m.reason


def test_refusals_say_why():
    # No lens mode in the file: a GoPro has several lenses, so no profile is guessed.
    r = find_profile("GoPro", "Hero6 Black", 848, 480, fps=29.97)
    assert r.match is None and "does not say which" in r.reason
    # SuperView's non-linear stretch has no fisheye profile.
    r = find_profile("GoPro", "HERO5 Black", 1920, 1080, lens="S", stabilized=False)
    assert r.match is None and "non-linearly" in r.reason
    # Another aspect ratio is another crop of the sensor.
    r = find_profile("GoPro", "HERO5 Black", 1000, 1000, lens="W")
    assert r.match is None and "aspect" in r.reason
    assert find_profile("Nobody", "Camera 1", 640, 480).match is None


def test_stabilisation_setting_decides_among_profiles():
    on = find_profile("GoPro", "HERO6 Black", 2704, 1520, lens="W", stabilized=True, fps=29.97).match
    off = find_profile("GoPro", "HERO6 Black", 3840, 2160, lens="W", stabilized=False, fps=29.97).match
    assert on.profile.eis is True and off.profile.eis is False
    # EIS crops the picture: a longer focal length relative to the width.
    assert on.fx / on.width > off.fx / off.width


def test_portrait_video_swaps_the_axes():
    land = find_profile("GoPro", "HERO7 Black", 1920, 1080, lens="W", stabilized=True, fps=29.97).match
    port = find_profile("GoPro", "HERO7 Black", 1080, 1920, lens="W", stabilized=True, fps=29.97).match
    assert port.fx == pytest.approx(land.fy) and port.fy == pytest.approx(land.fx)
    assert port.cy == pytest.approx(land.cx) and port.cx == pytest.approx(1079 - land.cy)


def test_readout_time_only_from_the_same_mode():
    # HERO6 Wide NO-EIS 3840x2160 @ 29.97 is calibrated with a readout time.
    m = find_profile("GoPro", "HERO6 Black", 3840, 2160, lens="W", stabilized=False, fps=29.97).match
    assert m.readout_ms == pytest.approx(m.profile.readout_ms) and m.readout_ms > 0
    other_rate = find_profile("GoPro", "HERO6 Black", 3840, 2160, lens="W", stabilized=False, fps=119.88).match
    assert other_rate.readout_ms is None
    assert profiles_of("GoPro", "HERO6 Black")


def test_a_measured_focal_length_picks_the_lens():
    """The HERO6 clip names no lens; its gyro-fitted 385 px (848 px wide) is the Wide lens."""
    r = find_profile("GoPro", "Hero6 Black", 848, 480, fps=29.97, focal_px=385.1)
    assert r.match is not None and r.match.profile.lens_class == "wide", r.reason
    assert abs(r.match.fx / 385.1 - 1) < 0.08 and "fits" in r.reason
    assert find_profile("GoPro", "Hero6 Black", 848, 480, fps=29.97, focal_px=300.0).match is None
