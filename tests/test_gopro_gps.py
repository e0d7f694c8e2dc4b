"""GPS of every GoPro generation: egovid's GPMF reader against the written truth and, fix for
fix, against telemetry-parser's independent reading of the same files (real HERO6 clip too)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import telemetry_parser

from egovid.core.camera.gpmf import GPS9_EPOCH, parse_gpsu, parse_klv, read_gpmf_gps, values
from egovid.core.camera.gps_check import compare, read_telemetry_parser_gps, telemetry_parser_rows
from egovid.synth.gopro import LAYOUTS, klv, nest, text, write_gopro_clip

from conftest import real_clip


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    d = tmp_path_factory.mktemp("gopro")
    out = {}
    for name in LAYOUTS:
        path = d / f"{name}.mp4"
        truth = write_gopro_clip(path, name, seconds=3, no_fix=(2,) if name == "hero7" else (), no_precision=(1,))
        out[name] = (path, truth)
    return out


def test_klv_round_trip_and_types():
    buf = nest("DEVC", text("DVNM", "HERO9 Black"), klv("TYPE", "c", 1, 3, b"lSf"))
    (devc,) = parse_klv(buf)
    assert devc.key == "DEVC" and [c.key for c in devc.children] == ["DVNM", "TYPE"]
    assert values(devc.children[0]) == ["HERO9 Black"]
    item = klv("TEST", "?", 10, 2, struct.pack(">lHf", -5, 7, 1.5) * 2)
    (it,) = parse_klv(item)
    np.testing.assert_array_equal(values(it, "lSf"), [[-5, 7, 1.5], [-5, 7, 1.5]])
    assert parse_klv(item[:-3]) == ()  # truncated: nothing invented
    assert parse_gpsu("180124192758.674") == pytest.approx(1516822078.674)


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_every_generation_reads_its_truth(clips, name):
    path, truth = clips[name]
    gps = read_gpmf_gps(path)
    layout = "GPS9" if truth.layout.gps9 else "GPS5"
    sel = truth.stream == layout
    assert gps is not None and gps.layout == layout and gps.device == truth.layout.device
    assert len(gps) == sel.sum()
    np.testing.assert_allclose(gps.lat, truth.lat[sel], atol=1e-7)
    np.testing.assert_allclose(gps.lon, truth.lon[sel], atol=1e-7)
    np.testing.assert_allclose(gps.alt, truth.alt[sel], atol=1e-3)
    np.testing.assert_allclose(gps.utc, truth.utc[sel], rtol=0, atol=1e-3)  # GPSU/GPS9 are milliseconds
    np.testing.assert_allclose(gps.video_t, truth.video_t[sel], atol=1e-3)
    np.testing.assert_array_equal(gps.fix, np.asarray(truth.fix)[truth.payload[sel]])
    assert np.isnan(gps.dop[gps.payload == 1]).all()  # GPSP 9999: not reported, not DOP 99.99
    assert np.isfinite(gps.dop[gps.payload == 0]).all()


@pytest.mark.parametrize("name", [n for n, lay in LAYOUTS.items() if lay.gps5 and not lay.gps9])
def test_telemetry_parser_reads_the_same_gps5_fixes(clips, name):
    path, _ = clips[name]
    agreement = compare(read_gpmf_gps(path), read_telemetry_parser_gps(path))
    assert agreement.checked and agreement.agree, agreement.detail
    assert agreement.fixes == 54 and agreement.position_deg <= 1e-9 and agreement.time_s <= 1e-3


@pytest.mark.parametrize("name", ["hero11", "hero13"])
def test_gps9_against_telemetry_parsers_raw_items(clips, name):
    """telemetry-parser 0.3 returns GPS9 undecoded (the item's bytes, its TYPE and Scale): decoded
    here with NumPy alone, independently of egovid's KLV code, fix for fix."""
    path, _ = clips[name]
    ours = read_gpmf_gps(path)
    rows = []
    for blk in telemetry_parser.Parser(str(path)).telemetry():
        g = blk.get("GPS9")
        if not g:
            continue
        raw = bytes(g["0x47505339"])
        assert g["0x54595045"] == "lllllllSS"
        size, repeat = raw[5], struct.unpack(">H", raw[6:8])[0]
        dt = np.dtype([(f"f{i}", ">i4") for i in range(7)] + [("dop", ">u2"), ("fix", ">u2")])
        a = np.frombuffer(raw[8 : 8 + size * repeat], dtype=dt)
        scale = np.asarray(g["Scale"], float)
        rows.append(np.column_stack([a[f"f{i}"] / scale[i] for i in range(7)] + [a["fix"]]))
    theirs = np.concatenate(rows)
    assert len(theirs) == len(ours)
    np.testing.assert_allclose(ours.lat, theirs[:, 0], atol=1e-9)
    np.testing.assert_allclose(ours.lon, theirs[:, 1], atol=1e-9)
    np.testing.assert_allclose(ours.utc, GPS9_EPOCH + theirs[:, 5] * 86400 + theirs[:, 6], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(ours.fix, theirs[:, 7])
    assert not compare(ours, read_telemetry_parser_gps(path)).checked  # said, not counted as agreement


def test_real_hero6_gps_agrees_with_telemetry_parser():
    """The HERO6 clip's GPS5 (one GPSU per payload, 17 + 19 fixes) read fix for fix."""
    path = real_clip("gopro-hero6-2s.mp4")
    gps = read_gpmf_gps(path)
    assert gps.layout == "GPS5" and gps.device == "Hero6 Black" and len(gps) == 36
    assert gps.utc[0] == pytest.approx(parse_gpsu("180124192758.674"))
    assert gps.lat.min() > 33.12 and gps.lat.max() < 33.13 and -117.33 < gps.lon.min() < -117.32
    agreement = compare(gps, read_telemetry_parser_gps(path))
    assert agreement.agree and agreement.fixes == 36, agreement.detail


def test_a_disagreement_is_reported(clips):
    path, _ = clips["hero6"]
    ours = read_gpmf_gps(path)
    theirs = read_telemetry_parser_gps(path)
    theirs[1].rows[4, 0] += 1e-5  # one fix, about a metre north
    agreement = compare(ours, theirs)
    assert agreement.checked and not agreement.agree and "payload 1 fix 4" in agreement.detail
    fewer = compare(ours, theirs[:2])
    assert not fewer.agree and "payloads" in fewer.detail
    assert telemetry_parser_rows([{"GPS": {"Data": []}}]) == []
