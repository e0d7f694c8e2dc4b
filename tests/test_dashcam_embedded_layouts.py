"""GPS embedded by dashcams and 360 cameras, in the layouts ExifTool 12.57 parses (Novatek/Viofo
``freeGPS`` blocks, BlackVue NMEA, Google CAMM): each synthetic file is read with the route
``dashcam ingest`` uses without ``--gps`` and compared with the fixes it was built from."""

from __future__ import annotations

import math

import numpy as np
import pytest

from egovid.core.camera.exif import read_records
from egovid.core.errors import EgovidError
from egovid.dashcam.route.camera_gps import bearing_deg, exiftool_records, speed_ms
from egovid.dashcam.route.embedded import parse_gps_time, read_embedded_gps
from egovid.synth.dashcam_gps import (
    GPS_LEAP_S,
    ddmm,
    from_ddmm,
    write_dashcam_gps_clip,
)

from conftest import run_cli

CASES = {
    "novatek": {},
    "novatek-doubles": {},
    "viofo-a119v3": {},
    "nextbase": {},
    "blackvue": {"void": (2,)},
    "garmin": {},
    "camm6": {"hz": 5.0, "void": (3,)},
    "camm5": {"hz": 5.0},
}


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    d = tmp_path_factory.mktemp("dashcam_gps")
    out = {}
    for layout, kw in CASES.items():
        path = d / f"{layout}.mp4"
        out[layout] = (path, write_dashcam_gps_clip(path, layout, **kw))
    return out


def test_ddmm_round_trip():
    deg = np.array([0.0, 6.5668, 46.5191, 179.999999])
    np.testing.assert_allclose(from_ddmm(ddmm(deg)), deg, atol=1e-12)
    assert ddmm(np.array([46.5]))[0] == pytest.approx(4630.0)


@pytest.mark.parametrize("layout", list(CASES))
def test_each_layout_reads_the_fixes_it_was_built_from(clips, layout, monkeypatch):
    monkeypatch.setenv("TZ", "America/New_York")  # ExifTool's own clock must not matter (camm5, garmin)
    path, truth = clips[layout]
    e = read_embedded_gps(path)
    assert e is not None and e.reader.startswith("ExifTool")
    tr = e.track
    assert len(tr) == len(truth.utc) == {"camm6": 20, "camm5": 21, "blackvue": 4}.get(layout, 5)
    np.testing.assert_allclose(tr.lat, truth.lat, atol=1e-6)
    np.testing.assert_allclose(tr.lon, truth.lon, atol=1e-6)
    np.testing.assert_allclose(tr.t, truth.utc, rtol=0, atol=1e-3)  # (rtol: 1e-7 of 1.7e9 s is 171 s)
    if np.isfinite(truth.video_t).all():
        assert e.timed
        np.testing.assert_allclose(e.video_t, truth.video_t, atol=1e-3)
    else:
        assert not e.timed  # freeGPS blocks carry no video time: the clock comes from elsewhere
    if np.isfinite(truth.speed).all():  # recorded speed, in m/s whatever unit the camera used
        np.testing.assert_allclose(tr.speed, truth.speed, rtol=1e-4)
    if np.isfinite(truth.track).all():
        np.testing.assert_allclose(tr.bearing, truth.track, atol=0.01)
    assert e.dropped == ({"no fix": 1} if layout == "camm6" else {})  # BlackVue's void RMC: ExifTool skips it


@pytest.mark.parametrize("layout", list(CASES))
def test_exiftool_reads_the_layouts_without_warnings(clips, layout):
    """ExifTool's -ee warnings: none, but where the samples hold no time (CreateDate + SampleTime)."""
    records = exiftool_records(read_records(clips[layout][0]))
    warnings = {v for _, tag, v, _ in records if tag == "Warning"}
    assert warnings == (
        {"[minor] Approximating GPSDateTime as CreateDate + SampleTime"} if layout in ("camm5", "garmin") else set()
    )
    groups = {g for _, tag, _, g in records if tag == "GPSLatitude"}
    assert groups == {"QuickTime"}


def test_gps_time_with_its_fraction_after_the_zone():
    """ExifTool 12.57's GoPro Karma GPSDateTime under QuickTimeUTC: ``…:59+00:00.54713``."""
    want = parse_gps_time("2017:04:17 19:27:59.54713Z")
    assert want is not None and parse_gps_time("2017:04:17 19:27:59+00:00.54713") == pytest.approx(want, abs=1e-6)
    assert parse_gps_time("2017:04:17 21:27:59+02:00.5") == pytest.approx(want - 0.04713, abs=1e-6)


def test_speed_units_follow_the_module_that_read_them():
    assert speed_ms({"GPSSpeed": "36"}, "QuickTime") == pytest.approx(10.0)  # km/h (ExifTool's streams)
    assert speed_ms({"GPSSpeed": "10"}, "GoPro") == pytest.approx(10.0)  # m/s
    assert speed_ms({"GPSSpeed": "10", "GPSSpeedRef": "N"}, "QuickTime") == pytest.approx(5.14444, rel=1e-5)
    assert speed_ms({"GPSSpeed": "10", "GPSSpeedRef": "M"}, "") == pytest.approx(4.4704)
    assert speed_ms({"GPSVelocityEast": "3", "GPSVelocityNorth": "-4"}, "QuickTime") == pytest.approx(5.0)
    assert math.isnan(speed_ms({}, "QuickTime"))
    assert bearing_deg({"GPSVelocityEast": "-3", "GPSVelocityNorth": "0"}) == pytest.approx(270.0)
    assert math.isnan(bearing_deg({"GPSVelocityEast": "0.1", "GPSVelocityNorth": "0"}))  # standing still
    assert bearing_deg({"GPSTrack": "12.5"}) == 12.5


@pytest.mark.xfail(strict=True, reason="ExifTool 12.57 turns CAMM GPS-epoch time into UTC without leap seconds")
def test_camm6_gps_epoch_time(tmp_path):
    """The CAMM specification counts GPS time from 1980-01-06; ExifTool adds the epoch's offset
    but not the 18 leap seconds, so such a file's fixes read 18 s late (Insta360 writes Unix time,
    which reads right: the case above)."""
    path = tmp_path / "camm6-gps.mp4"
    truth = write_dashcam_gps_clip(path, "camm6", seconds=2, hz=2.0, epoch="gps")
    e = read_embedded_gps(path)
    assert e is not None
    assert np.median(e.track.t - truth.utc) == pytest.approx(GPS_LEAP_S)  # what it reads today
    np.testing.assert_allclose(e.track.t, truth.utc, rtol=0, atol=1e-3)


def test_a_viofo_clock_in_local_time_is_refused_then_placed_with_tz_offset(tmp_path):
    """freeGPS fixes carry no video time: the camera clock places the video, checked against them."""
    from egovid.dashcam.ingest.sources import ClockOptions, examine

    path = tmp_path / "2024_0517_113012_001.MP4"
    truth = write_dashcam_gps_clip(path, "novatek", clock_h=2.0)
    with pytest.raises(EgovidError, match="looks like local time UTC\\+2: pass --tz-offset 2"):
        examine(path, None, ClockOptions())
    src = examine(path, None, ClockOptions(tz_offset_h=2.0))
    assert src.clock.start_utc == truth.start_utc and src.gps_source.startswith("embedded: ExifTool")


def test_cli_ingest_reads_a_viofo_files_own_gps(clips, tmp_path):
    """``egovid dashcam ingest`` with no --gps on a Novatek/Viofo file: the archive keeps its fixes."""
    from egovid.serve.archive_ops import ArchiveOps

    path, truth = clips["novatek"]
    root = tmp_path / "archive"
    assert run_cli("dashcam", "init", root).returncode == 0
    r = run_cli("dashcam", "ingest", root, path)
    assert r.returncode == 0, r.stderr
    ops = ArchiveOps(root)
    try:
        tr = ops.track(1)
    finally:
        ops.close()
    t = np.array(tr["t"]) + tr["utc0"]
    fixes = np.isin(np.round(t, 3), truth.utc)  # the fixes (the track also ends at the last frame)
    assert fixes.sum() == len(truth.utc) - 1  # the last fix is at 4.0 s, after the last frame
    np.testing.assert_allclose(np.array(tr["lat"])[fixes], truth.lat[:-1], atol=1e-6)
    np.testing.assert_allclose(np.array(tr["lon"])[fixes], truth.lon[:-1], atol=1e-6)
