"""Embedded GPS and the video clock: GPS time as the time base, the camera clock checked against it."""

from __future__ import annotations

import datetime as dt
import functools
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from egovid.core.errors import EgovidError
from egovid.core.times import creation_time_utc
from egovid.dashcam.route.clock import name_time, resolve_clock
from egovid.dashcam.route.embedded import fixes_from_exiftool, parse_gps_time, read_embedded_gps
from egovid.dashcam.route.tracks import GpsTrack


def utc(*args) -> float:
    return dt.datetime(*args, tzinfo=dt.UTC).timestamp()


# The Karma's own clocks, read by hand from its GPMF track (SYST: boot time 146.544283 s is UNIX
# time 1492457278.000, i.e. 19:27:58 UTC, in the payload covering video seconds 0-1.001) and the
# container's creation_time 2017-04-17T19:27:57Z (1 s resolution): the first frame was recorded
# between 19:27:57.0 and 19:27:58.0 UTC.
KARMA_FIRST_FRAME = (utc(2017, 4, 17, 19, 27, 57), utc(2017, 4, 17, 19, 27, 58))


def _track(t0: float, seconds: float, hz: float = 1.0, source: str = "log.gpx") -> GpsTrack:
    t = t0 + np.arange(0.0, seconds + 1e-9, 1.0 / hz)
    lat = 48.1 + 1e-5 * (t - t0)
    lon = np.full_like(t, 11.5)
    return GpsTrack(t, lat, lon, np.full_like(t, 1.1), np.zeros_like(t), source)


def test_file_name_and_creation_time_parsing():
    assert name_time("2024_0131_235959_001F.MP4") == utc(2024, 1, 31, 23, 59, 59)  # Novatek / Viofo
    assert name_time("20240131_235959_NF.mp4") == utc(2024, 1, 31, 23, 59, 59)  # BlackVue
    assert name_time("240915_143027_001_FH.MP4") == utc(2024, 9, 15, 14, 30, 27)  # Nextbase
    assert name_time("2024-01-31_23-59-59-front.mp4") == utc(2024, 1, 31, 23, 59, 59)  # Tesla
    assert name_time("REC_2024_01_31_23_59_59_F.MP4") == utc(2024, 1, 31, 23, 59, 59)  # Thinkware
    assert name_time("GOPR0042.MP4") is None and name_time("clip_20241399_999999.mp4") is None
    assert creation_time_utc("2017-04-17T19:27:57.000000Z") == utc(2017, 4, 17, 19, 27, 57)
    for unset in ("1904-01-01T00:00:00Z", "1970-01-01T00:00:00Z", "2000-01-01T00:00:05Z", "garbage", None):
        assert creation_time_utc(unset) is None
    assert parse_gps_time("2017:04:17 19:27:57.52602") == pytest.approx(utc(2017, 4, 17, 19, 27, 57) + 0.52602)
    assert parse_gps_time("2024:01:31 23:59:59+01:00") == utc(2024, 1, 31, 22, 59, 59)
    assert parse_gps_time("1999:08:22 00:00:00") is None  # a GPS week roll-over, not a real time


def test_exiftool_samples_become_fixes_on_the_video_clock():
    # Two timed-metadata samples of 1 s with two fixes each, keyed the way ExifTool -a -G3:4 keys
    # them (the fix without a Copy number is its document's last); one fix is void.
    tags = {
        "Doc1:SampleTime": 0, "Doc1:SampleDuration": 1.0,
        "Doc1:GPSDateTime": "2024:05:04 08:00:10.5", "Doc1:GPSLatitude": 48.2, "Doc1:GPSLongitude": 11.6,
        "Doc1:Copy1:GPSDateTime": "2024:05:04 08:00:10.0", "Doc1:Copy1:GPSLatitude": 48.1,
        "Doc1:Copy1:GPSLongitude": 11.5,
        "Doc2:Copy1:SampleTime": 1.0, "Doc2:Copy1:SampleDuration": 1.0,
        "Doc2:Copy2:GPSDateTime": "2024:05:04 08:00:11.0", "Doc2:Copy2:GPSLatitude": 48.3,
        "Doc2:Copy2:GPSLongitude": 11.7, "Doc2:Copy2:GPSSpeed": 36.0, "Doc2:Copy2:GPSSpeedRef": "K",
        "Doc2:Copy3:GPSDateTime": "2024:05:04 08:00:11.5", "Doc2:Copy3:GPSLatitude": 0.0,
        "Doc2:Copy3:GPSLongitude": 0.0,
    }  # fmt: skip
    e = fixes_from_exiftool(tags)
    assert e is not None and e.timed
    np.testing.assert_allclose(e.track.lat, [48.1, 48.2, 48.3])
    np.testing.assert_allclose(e.video_t, [0.0, 0.5, 1.0])
    assert e.track.speed[2] == pytest.approx(10.0)  # 36 km/h
    assert e.dropped == {"no fix": 1}
    assert e.start_utc() == pytest.approx(utc(2024, 5, 4, 8, 0, 10))


def test_gps_time_is_the_time_base_and_the_camera_clock_is_checked():
    t0 = utc(2024, 5, 4, 8, 0, 0)
    tags = {f"Doc{k + 1}:{key}": v for k in range(5) for key, v in
            (("SampleTime", k), ("SampleDuration", 1), ("GPSDateTime", f"2024:05:04 08:00:{k + 3:02d}"),
             ("GPSLatitude", 48.1 + k * 1e-4), ("GPSLongitude", 11.5))}  # fmt: skip
    e = fixes_from_exiftool(tags)
    # A camera writing local time (UTC-7) into creation_time: GPS wins and the clock is reported.
    c = resolve_clock(5.0, embedded=e, creation_time=t0 + 3 - 7 * 3600)
    assert c.start_utc == pytest.approx(t0 + 3) and c.source.startswith("GPS time")
    assert any("-7.00 h off GPS time (time zone UTC-7?)" in n for n in c.notes)
    assert resolve_clock(5.0, embedded=e, creation_time=t0 + 3.4).notes == ()  # agrees
    assert resolve_clock(5.0, embedded=e, start=t0).start_utc == t0  # --start overrides


def test_a_separate_log_needs_a_checked_clock():
    t0 = utc(2024, 5, 4, 8, 0, 0)
    log = _track(t0, 3600.0)  # one log for an hour of loop files
    # creation_time in UTC inside the log: used.
    assert resolve_clock(60.0, track=log, creation_time=t0 + 600).start_utc == t0 + 600
    # Local time UTC+8 tagged as UTC: refused, naming the offset that fits.
    with pytest.raises(EgovidError, match=r"UTC\+8: pass --tz-offset 8"):
        resolve_clock(60.0, track=log, creation_time=t0 + 600 + 8 * 3600, video_name="a.mp4")
    c = resolve_clock(60.0, track=log, creation_time=t0 + 600 + 8 * 3600, tz_offset_h=8)
    assert c.start_utc == t0 + 600 and "tz-offset" in c.source
    # No creation_time: the file name's local time with --tz-offset.
    c = resolve_clock(60.0, track=log, file_time=t0 + 900 - 5.5 * 3600, tz_offset_h=-5.5)
    assert c.start_utc == t0 + 900 and c.source.startswith("file name")
    # A wrong camera clock is never replaced silently, not even by the first fix of a log as long as
    # the video; a video with no clock at all takes it.
    own = _track(t0, 60.0)
    with pytest.raises(EgovidError, match="covers 0% of the video"):
        resolve_clock(60.0, track=own, creation_time=t0 - 3 * 86400)
    c = resolve_clock(60.0, track=own)
    assert c.start_utc == t0 and c.source == "GPS log start" and "no clock" in c.notes[0]
    with pytest.raises(EgovidError, match="--start"):
        resolve_clock(60.0, track=log)
    with pytest.raises(EgovidError, match="--gps"):
        resolve_clock(60.0)


def test_karma_clip_gives_its_utc_start_from_its_own_gps(karma_clip):
    e = read_embedded_gps(karma_clip)
    assert e is not None and e.timed and len(e.track) == 47 and "ExifTool" in e.reader
    c = resolve_clock(12.0, embedded=e, creation_time=creation_time_utc("2017-04-17T19:27:57Z"))
    assert KARMA_FIRST_FRAME[0] <= c.start_utc <= KARMA_FIRST_FRAME[1]
    assert c.notes == ()  # this camera's clock agrees with GPS time
    # The fixes follow the drone along the cliff: about 80 m north-west in 12 s.
    from egovid.dashcam.route.tracks import project

    xy = project(e.track.lat, e.track.lon, (e.track.lat[0], e.track.lon[0]))
    assert 60 < np.hypot(*xy[-1]) < 100 and xy[-1, 0] < 0 < xy[-1, 1]


@functools.cache
def _ffmpeg() -> str:
    exe = shutil.which("ffmpeg")
    if exe is None:
        pytest.skip("no ffmpeg (make test installs it)")
    return exe


def test_nmea_in_a_text_track(tmp_path: Path):
    import pynmea2

    srt = []
    for k in range(4):
        rmc = pynmea2.RMC("GP", "RMC", ("080010.00", "A", "4806.000", "N", "01130.000", "E", "10.0", "45.0",
                                        "040524", "", "", "A"))  # fmt: skip
        rmc.data[0] = f"0800{10 + k:02d}.00"
        rmc.data[2] = f"4806.{k:03d}"
        bad = "$GPRMC,080019.00,A,4806.900,N,01130.000,E,10.0,45.0,040524,,,A*00"  # bad checksum
        srt.append(f"{k + 1}\n00:00:0{k},500 --> 00:00:0{k + 1},400\n{rmc.render()}\n{bad}\n")
    (tmp_path / "gps.srt").write_text("\n".join(srt))
    video = tmp_path / "nmea.mp4"
    subprocess.run([_ffmpeg(), "-loglevel", "error", "-f", "lavfi", "-i", "testsrc=size=160x120:rate=10:duration=5",
                    "-i", tmp_path / "gps.srt", "-c:v", "libx264", "-c:s", "mov_text", video], check=True)  # fmt: skip
    e = read_embedded_gps(video)
    assert e is not None and e.reader.startswith("NMEA text track")
    np.testing.assert_allclose(e.video_t, [0.5, 1.5, 2.5, 3.5], atol=0.01)
    assert e.dropped == {"checksum": 4}
    c = resolve_clock(5.0, embedded=e)
    assert c.start_utc == pytest.approx(utc(2024, 5, 4, 8, 0, 9, 500000), abs=0.01)


def test_a_camera_clock_set_to_local_time_is_reported_not_used(karma_clip, tmp_path):
    from egovid.dashcam.ingest.sources import ClockOptions, examine

    exiftool = shutil.which("exiftool")
    if exiftool is None:
        pytest.skip("no exiftool (make test installs it)")
    shifted = tmp_path / "karma-local-time.mp4"  # creation_time in Pacific Daylight Time, tagged UTC
    subprocess.run([exiftool, "-q", "-QuickTime:CreateDate=2017:04:17 12:27:57", "-o", shifted, karma_clip], check=True)
    src = examine(shifted, None, ClockOptions())
    assert KARMA_FIRST_FRAME[0] <= src.clock.start_utc <= KARMA_FIRST_FRAME[1]
    assert any("-7.00 h off GPS time (time zone UTC-7?)" in n for n in src.clock.notes)
    assert src.gps_source.startswith("embedded: ExifTool") and src.info.width == 854
