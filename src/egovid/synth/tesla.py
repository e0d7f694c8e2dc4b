"""Synthetic Tesla dashcam clips: per-frame SEI telemetry as Tesla's public description lays it out.

A clip is an H.264 MP4 (PyAV, libx264) whose every frame is preceded by an SEI NAL unit with one
``user_data_unregistered`` message: a run of ``0x42`` bytes, ``0x69``, and a ``SeiMetadata``
protobuf message (see :mod:`egovid.core.camera.tesla` for the fields), emulation-prevention
bytes inserted as H.264 requires. The car drives a known path (:class:`TeslaTruth`).
"""

from __future__ import annotations

import fractions
import math
import os
import struct
from dataclasses import dataclass

import numpy as np

from egovid.core.camera.tesla import CHANNELS, FIELDS

EARTH_R = 6371008.8


def _varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def encode_sei_metadata(values: dict[str, float]) -> bytes:
    """A ``SeiMetadata`` protobuf message of ``values`` (field names of :data:`FIELDS`); zero
    numbers are left out, as proto3 does."""
    out = bytearray()
    for number, (name, kind) in FIELDS.items():
        if name not in values:
            continue
        v = values[name]
        if kind == "int":
            if int(v) == 0:
                continue
            out += _varint(number << 3 | 0) + _varint(int(v))
        elif kind == "float":
            if v == 0:
                continue
            out += _varint(number << 3 | 5) + struct.pack("<f", v)
        else:
            if v == 0:
                continue
            out += _varint(number << 3 | 1) + struct.pack("<d", v)
    return bytes(out)


def escape(rbsp: bytes) -> bytes:
    """Insert H.264 emulation-prevention bytes (``00 00 0x`` with x <= 3 → ``00 00 03 0x``)."""
    out = bytearray()
    zeros = 0
    for b in rbsp:
        if zeros >= 2 and b <= 3:
            out.append(3)
            zeros = 0
        out.append(b)
        zeros = zeros + 1 if b == 0 else 0
    return bytes(out)


def sei_nal(message: bytes) -> bytes:
    """An H.264 SEI NAL unit (type 6) with one Tesla ``user_data_unregistered`` payload."""
    body = b"\x42" * 15 + b"\x69" + message
    size = bytearray()
    n = len(body)
    while n >= 255:
        size.append(255)
        n -= 255
    size.append(n)
    return b"\x06" + escape(b"\x05" + bytes(size) + body + b"\x80")


@dataclass
class TeslaTruth:
    """What a synthetic clip holds per frame: ``video_t`` (s) and each channel of
    :data:`~egovid.core.camera.tesla.CHANNELS` as written (float32 channels rounded as stored)."""

    video_t: np.ndarray
    channels: dict[str, np.ndarray]


def drive_samples(
    n: int, fps: float, *, origin=(37.3935, -122.1503), speed: float = 12.0, start_seq: int = 1000, no_fix: int = 0
) -> TeslaTruth:
    """Telemetry of ``n`` frames: a car at ``speed`` m/s on a gentle curve, accelerating a little,
    the first ``no_fix`` frames without a position (0, 0)."""
    t = np.arange(n) / fps
    v = speed + 0.5 * t
    heading = 75.0 + 4.0 * t
    h = np.radians(heading)
    dx = np.cumsum(np.concatenate([[0.0], np.diff(t)]) * v * np.sin(h))
    dy = np.cumsum(np.concatenate([[0.0], np.diff(t)]) * v * np.cos(h))
    lat = origin[0] + np.degrees(dy / EARTH_R)
    lon = origin[1] + np.degrees(dx / (EARTH_R * math.cos(math.radians(origin[0]))))
    lat[:no_fix] = 0.0
    lon[:no_fix] = 0.0
    ch = {
        "version": np.ones(n),
        "gear": np.ones(n),
        "frame_seq_no": start_seq + np.arange(n, dtype=float),
        "speed_mps": np.float32(v).astype(float),
        "accelerator": np.float32(np.full(n, 0.18)).astype(float),
        "steering_deg": np.float32(12.0 * np.sin(t)).astype(float),
        "blinker_left": (np.arange(n) % 40 < 20).astype(float),
        "blinker_right": np.zeros(n),
        "brake": np.zeros(n),
        "autopilot": np.full(n, 2.0),
        "lat": lat,
        "lon": lon,
        "heading_deg": heading % 360.0,
        "accel_x": np.full(n, 0.5),
        "accel_y": v * np.radians(4.0),  # v times the yaw rate (4 deg/s)
        "accel_z": np.full(n, 9.81),
    }
    assert set(ch) == set(CHANNELS)
    return TeslaTruth(t, ch)


def write_tesla_clip(
    path: str | os.PathLike, *, seconds: float = 2.0, fps: float = 36.0, size: tuple[int, int] = (160, 120), **drive
) -> TeslaTruth:
    """Write a Tesla-like clip with per-frame SEI telemetry; returns what it holds."""
    import av

    n = round(seconds * fps)
    truth = drive_samples(n, fps, **drive)
    rng = np.random.default_rng(1)
    with av.open(str(path), "w", format="mp4") as c:
        v = c.add_stream("libx264", rate=fractions.Fraction(round(fps * 1000), 1000))
        v.width, v.height, v.pix_fmt = size[0], size[1], "yuv420p"
        v.options = {"preset": "ultrafast", "bf": "0"}

        def mux(packets):
            for pkt in packets:
                k = round(float(pkt.pts * pkt.time_base) * fps)
                values = {name: float(truth.channels[name][k]) for name in CHANNELS}
                nal = b"\x00\x00\x00\x01" + sei_nal(encode_sei_metadata(values))
                out = av.Packet(nal + bytes(pkt))
                out.pts, out.dts, out.time_base, out.stream = pkt.pts, pkt.dts, pkt.time_base, v
                out.is_keyframe = pkt.is_keyframe
                c.mux(out)

        for i in range(n):
            img = rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
            frame = av.VideoFrame.from_ndarray(img, format="rgb24")
            frame.pts = i
            mux(v.encode(frame))
        mux(v.encode())
    return truth
