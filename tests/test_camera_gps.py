"""Camera GPS as rows for the archive: GoPro (cross-checked), Tesla, and ExifTool in file order,
which pairs the fixes ExifTool numbers as separate copies (the HERO6/7/MAX 'no GPS')."""

from __future__ import annotations

import datetime as dt
import math

import exiftool
import numpy as np
import pytest

from egovid.core.camera.exif import RECORD_ARGS
from egovid.core.camera.gpmf import read_gpmf_gps
from egovid.core.camera.gps_check import read_telemetry_parser_gps
from egovid.core.camera.tesla import read_tesla_telemetry
from egovid.core.errors import EgovidError
from egovid.dashcam.route.camera_gps import (
    exiftool_documents,
    exiftool_records,
    exiftool_rows,
    gopro_gps,
    gpmf_rows,
    tesla_rows,
)
from egovid.dashcam.route.embedded import parse_gps_time
from egovid.synth.gopro import write_gopro_clip
from egovid.synth.tesla import write_tesla_clip

from conftest import real_clip


def _records(path):
    with exiftool.ExifToolHelper(common_args=["-n"]) as et:
        return exiftool_records(et.execute(*RECORD_ARGS, str(path)))


def test_hero6_fixes_pair_in_file_order():
    path = real_clip("gopro-hero6-2s.mp4")
    docs = exiftool_documents(_records(path))
    assert [len(d.fixes) for d in docs] == [17, 19]
    assert docs[0].shared["GPSDateTime"] == "2018:01:24 19:27:58.674"
    ex = exiftool_rows(_records(path), parse_gps_time, path.name)
    gp = gpmf_rows(read_gpmf_gps(path))
    # Three readers, one answer: ExifTool in file order, egovid's GPMF, telemetry-parser.
    assert len(ex.rows) == len(gp.rows) == 36
    np.testing.assert_allclose(np.array(ex.rows)[:, :4], np.array(gp.rows)[:, :4], atol=1e-6)
    checked = gopro_gps(read_gpmf_gps(path), read_telemetry_parser_gps(path), path.name)
    assert checked.check.agree and checked.check.fixes == 36


def test_karma_drone_gps_keeps_its_per_fix_times():
    rows = exiftool_rows(_records(real_clip("gopro-hero5-karma.mp4")), parse_gps_time)
    a = np.array(rows.rows)
    assert len(a) >= 40 and np.all(np.diff(a[:, 0]) > 0)  # 4 Hz fixes, each with its own GPS time
    assert np.median(np.diff(a[:, 0])) == pytest.approx(0.25, abs=0.02)


@pytest.mark.parametrize("generation", ["hero5", "hero7", "max", "fusion"])
def test_exiftool_and_gpmf_agree_on_gps5_layouts(tmp_path, generation):
    path = tmp_path / f"{generation}.mp4"
    write_gopro_clip(path, generation, seconds=3, no_fix=(2,), no_precision=(1,))
    ex = exiftool_rows(_records(path), parse_gps_time)
    gp = gpmf_rows(read_gpmf_gps(path))
    assert len(ex.rows) == len(gp.rows) == 36 and gp.dropped == {"no fix": 18} == ex.dropped
    np.testing.assert_allclose(np.array(ex.rows)[:, :4], np.array(gp.rows)[:, :4], atol=2e-6)


def test_disagreeing_readers_refuse_the_file(tmp_path):
    path = tmp_path / "hero9.mp4"
    write_gopro_clip(path, "hero9", seconds=2)
    theirs = read_telemetry_parser_gps(path)
    theirs[0].rows[3, 1] += 1e-4
    with pytest.raises(EgovidError, match="reads differently"):
        gopro_gps(read_gpmf_gps(path), theirs, path.name)


def test_tesla_rows(tmp_path):
    path = tmp_path / "2025-11-20_14-03-12-front.mp4"
    truth = write_tesla_clip(path, seconds=1.0, no_fix=4)
    out = tesla_rows(read_tesla_telemetry(path), start_utc=1.7e9)
    a = np.array(out.rows)
    assert len(a) == 32 and out.dropped == {"no fix": 4}
    np.testing.assert_allclose(a[:, 0] - 1.7e9, truth.video_t[4:], atol=1e-6)
    np.testing.assert_allclose(a[:, 2], truth.channels["lat"][4:])
    np.testing.assert_allclose(a[:, 4], truth.channels["speed_mps"][4:])
    assert math.isfinite(a[0, 5])


def test_embedded_gps_of_every_gopro_and_of_a_tesla_clip(tmp_path):
    """What ingest reads with no --gps: the HERO6 clip's 36 fixes (main found none), a HERO13's
    GPS9, and a Tesla clip's SEI positions timed by its file name."""
    from egovid.dashcam.ingest.sources import ClockOptions, examine
    from egovid.dashcam.route.embedded import read_embedded_gps

    e = read_embedded_gps(real_clip("gopro-hero6-2s.mp4"))
    assert e is not None and len(e.track) == 36 and e.timed and "GPMF GPS5" in e.reader
    h13 = tmp_path / "GX010013.MP4"
    truth = write_gopro_clip(h13, "hero13", seconds=2)
    e = read_embedded_gps(h13)
    assert e is not None and len(e.track) == 20 and "GPS9" in e.reader
    np.testing.assert_allclose(e.track.t, truth.utc, rtol=0, atol=1e-3)
    tesla = tmp_path / "2025-11-20_14-03-12-front.mp4"
    write_tesla_clip(tesla, seconds=1.0, size=(320, 240))
    assert read_embedded_gps(tesla) is None  # no time of day in the SEI: the ingest's clock decides
    src = examine(tesla, None, ClockOptions(tz_offset_h=-8.0))
    assert src.embedded is not None and len(src.embedded.track) == 36 and "Tesla SEI" in src.embedded.reader
    assert src.clock.start_utc == pytest.approx(dt.datetime(2025, 11, 20, 22, 3, 12, tzinfo=dt.UTC).timestamp())
