"""Tesla's per-frame SEI telemetry, read from clips written as Tesla's public description lays
them out (protobuf in a user_data_unregistered SEI before every frame)."""

from __future__ import annotations

import numpy as np
import pytest

from egovid.core.camera.tesla import (
    CHANNELS,
    decode_sei_metadata,
    nal_units,
    read_tesla_telemetry,
    sei_payloads,
    telemetry_from_samples,
    unescape,
)
from egovid.synth.tesla import encode_sei_metadata, escape, sei_nal, write_tesla_clip

from conftest import real_clip


def test_protobuf_and_nal_round_trip():
    values = {"version": 1, "frame_seq_no": 123456789012, "speed_mps": 17.25, "lat": 37.5, "lon": -122.25}
    msg = encode_sei_metadata(values)
    assert decode_sei_metadata(msg) == pytest.approx(values)
    # Unknown fields (a later firmware) are skipped, a truncated message is refused.
    later = msg + bytes([0x88, 0x01, 7]) + bytes([0x92, 0x01, 2, 0xAA, 0xBB])  # fields 17 (varint), 18 (bytes)
    assert decode_sei_metadata(later) == pytest.approx(values)
    with pytest.raises(ValueError):
        decode_sei_metadata(msg[:-3])
    raw = bytes([0, 0, 1, 0, 0, 0, 0, 0, 3, 7])
    assert unescape(escape(raw)) == raw and b"\x00\x00\x01" not in escape(raw)
    nal = sei_nal(msg)
    assert sei_payloads(nal, hevc=False) == [msg]
    assert nal_units(len(nal).to_bytes(4, "big") + nal) == [nal]
    assert nal_units(b"\x00\x00\x00\x01" + nal + b"\x00\x00\x01\x65\x88") == [nal, b"\x65\x88"]
    # An SEI of another kind (x264's own user data) is not Tesla's.
    other = b"\x06\x05\x12" + bytes(range(16)) + b"x264\x80"
    assert sei_payloads(other, hevc=False) == []


def test_clip_telemetry_frame_by_frame(tmp_path):
    path = tmp_path / "2025-11-20_14-03-12-front.mp4"
    truth = write_tesla_clip(path, seconds=2.0, fps=36.0, no_fix=5)
    tel = read_tesla_telemetry(path)
    assert tel is not None and len(tel) == len(truth.video_t) == 72 and tel.dropped == 0
    np.testing.assert_allclose(tel.video_t, truth.video_t, atol=1e-6)
    for name in CHANNELS:
        want = truth.channels[name]
        if name in ("lat", "lon"):
            np.testing.assert_array_equal(tel.has_position(), np.arange(72) >= 5)
            ok = tel.has_position()
            np.testing.assert_array_equal(tel.channels[name][ok], want[ok])
        else:
            np.testing.assert_array_equal(np.nan_to_num(tel.channels[name]), want, err_msg=name)


def test_files_without_tesla_sei(tmp_path):
    assert read_tesla_telemetry(real_clip("handheld-1080p-pan.mp4")) is None
    assert read_tesla_telemetry(tmp_path / "missing.mp4") is None
    assert telemetry_from_samples([(0.0, b"\xff\xff")]) is None
