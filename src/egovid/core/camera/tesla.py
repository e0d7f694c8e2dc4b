"""Tesla's dashcam telemetry: one protobuf message per frame in the video's SEI (firmware 2025.44.25+).

Tesla's public description (github.com/teslamotors/dashcam: ``dashcam.proto``, ``sei_extractor.py``):
every frame of a dashcam clip (HW3 and later, while driving) is preceded by an SEI NAL unit
(H.264 type 6, H.265 types 39/40) holding one ``user_data_unregistered`` message (payload type 5)
whose payload is a run of ``0x42`` bytes, ``0x69``, then a ``SeiMetadata`` protobuf message:

====  =========================  ============  ==========================================
 no.  field                      wire type     meaning
====  =========================  ============  ==========================================
  1   version                    varint
  2   gear_state                 varint        0 park, 1 drive, 2 reverse, 3 neutral
  3   frame_seq_no               varint        the frame's running number
  4   vehicle_speed_mps          fixed32 float m/s
  5   accelerator_pedal_position fixed32 float 0..1
  6   steering_wheel_angle       fixed32 float degrees
  7-9 blinker left/right, brake  varint        booleans
 10   autopilot_state            varint        0 none, 1 FSD, 2 autosteer, 3 TACC
 11   latitude_deg               fixed64       degrees
 12   longitude_deg              fixed64       degrees
 13   heading_deg                fixed64       degrees
 14-16 linear_acceleration_mps2 x, y, z  fixed64  m/s²
====  =========================  ============  ==========================================

The message has no time of day: a sample's time is its frame's presentation time in the file
(seconds from the first frame); the clip's start is the time in its file name
(``2025-11-20_14-03-12-front.mp4``, the car's local time). The protobuf wire format is decoded
here directly (a handful of scalar fields; unknown fields are skipped), the NAL units come from
PyAV's demuxer without decoding any picture.
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass, field

import numpy as np

#: Field number → (name, kind) of ``SeiMetadata``.
FIELDS = {
    1: ("version", "int"),
    2: ("gear", "int"),
    3: ("frame_seq_no", "int"),
    4: ("speed_mps", "float"),
    5: ("accelerator", "float"),
    6: ("steering_deg", "float"),
    7: ("blinker_left", "int"),
    8: ("blinker_right", "int"),
    9: ("brake", "int"),
    10: ("autopilot", "int"),
    11: ("lat", "double"),
    12: ("lon", "double"),
    13: ("heading_deg", "double"),
    14: ("accel_x", "double"),
    15: ("accel_y", "double"),
    16: ("accel_z", "double"),
}
#: Numeric channels of :class:`TeslaTelemetry`, in this order.
CHANNELS = tuple(name for name, _ in FIELDS.values())
#: Packets looked at before deciding a file has no Tesla SEI.
PROBE_PACKETS = 48


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if pos >= len(buf) or shift > 63:
            raise ValueError("truncated varint")
        b = buf[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        if not b & 0x80:
            return value, pos
        shift += 7


def decode_sei_metadata(buf: bytes) -> dict[str, float]:
    """The fields of one ``SeiMetadata`` protobuf message (names of :data:`FIELDS`; absent fields
    are absent, proto3's defaults are the caller's business). Raises ``ValueError`` when the
    bytes are not a well-formed message."""
    out: dict[str, float] = {}
    pos = 0
    while pos < len(buf):
        key, pos = _varint(buf, pos)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise ValueError("field number 0")
        if wire == 0:
            value, pos = _varint(buf, pos)
        elif wire == 1:
            if pos + 8 > len(buf):
                raise ValueError("truncated 64-bit field")
            value = buf[pos : pos + 8]
            pos += 8
        elif wire == 5:
            if pos + 4 > len(buf):
                raise ValueError("truncated 32-bit field")
            value = buf[pos : pos + 4]
            pos += 4
        elif wire == 2:
            length, pos = _varint(buf, pos)
            if pos + length > len(buf):
                raise ValueError("truncated length-delimited field")
            pos += length
            continue
        else:
            raise ValueError(f"wire type {wire}")
        spec = FIELDS.get(number)
        if spec is None:
            continue
        name, kind = spec
        if kind == "int" and wire == 0:
            out[name] = float(value)
        elif kind == "float" and wire == 5:
            out[name] = struct.unpack("<f", value)[0]
        elif kind == "double" and wire == 1:
            out[name] = struct.unpack("<d", value)[0]
        else:
            raise ValueError(f"field {number} has wire type {wire}")
    return out


def unescape(rbsp: bytes) -> bytes:
    """A NAL unit without its emulation-prevention bytes (``00 00 03`` → ``00 00``)."""
    if b"\x00\x00\x03" not in rbsp:
        return rbsp
    out = bytearray()
    zeros = 0
    for b in rbsp:
        if zeros >= 2 and b == 3:
            zeros = 0
            continue
        out.append(b)
        zeros = zeros + 1 if b == 0 else 0
    return bytes(out)


def sei_payloads(nal: bytes, hevc: bool) -> list[bytes]:
    """The Tesla protobuf payloads of one SEI NAL unit (raw, with its header), possibly none."""
    header = 2 if hevc else 1
    if len(nal) < header + 3:
        return []
    kind = (nal[0] >> 1) & 0x3F if hevc else nal[0] & 0x1F
    if kind not in ((39, 40) if hevc else (6,)):
        return []
    data = unescape(nal[header:])
    out, pos = [], 0
    while pos + 2 <= len(data) and data[pos] != 0x80:
        ptype = psize = 0
        while pos < len(data) and data[pos] == 0xFF:
            ptype += 255
            pos += 1
        if pos >= len(data):
            break
        ptype += data[pos]
        pos += 1
        while pos < len(data) and data[pos] == 0xFF:
            psize += 255
            pos += 1
        if pos >= len(data):
            break
        psize += data[pos]
        pos += 1
        body = data[pos : pos + psize]
        pos += psize
        if ptype != 5 or len(body) < 3:
            continue
        i = 0
        while i < len(body) and body[i] == 0x42:
            i += 1
        if i == 0 or i >= len(body) or body[i] != 0x69:
            continue
        out.append(body[i + 1 :])
    return out


def nal_units(packet: bytes, length_size: int = 4) -> list[bytes]:
    """The NAL units of one video packet: length-prefixed (MP4) or with Annex B start codes."""
    if packet[:4] == b"\x00\x00\x00\x01" or packet[:3] == b"\x00\x00\x01":
        parts = packet.replace(b"\x00\x00\x00\x01", b"\x00\x00\x01").split(b"\x00\x00\x01")
        return [p for p in parts if p]
    out, pos = [], 0
    while pos + length_size <= len(packet):
        n = int.from_bytes(packet[pos : pos + length_size], "big")
        pos += length_size
        if n <= 0 or pos + n > len(packet):
            break
        out.append(packet[pos : pos + n])
        pos += n
    return out


@dataclass
class TeslaTelemetry:
    """Per-frame telemetry of a Tesla clip: ``video_t`` (N,) seconds from the first frame and one
    (N,) array per channel of :data:`CHANNELS` (NaN where a frame's message lacks it; units as
    in the module docstring); ``dropped`` counts messages that could not be decoded."""

    video_t: np.ndarray
    channels: dict[str, np.ndarray]
    dropped: int = 0
    notes: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.video_t)

    def has_position(self) -> np.ndarray:
        """(N,) True where the sample carries a position (Tesla writes 0, 0 before a fix)."""
        lat, lon = self.channels["lat"], self.channels["lon"]
        return np.isfinite(lat) & np.isfinite(lon) & ~((np.abs(lat) < 1e-9) & (np.abs(lon) < 1e-9))


def telemetry_from_samples(samples: list[tuple[float, bytes]]) -> TeslaTelemetry | None:
    """Telemetry from (presentation time, protobuf payload) pairs, ordered by time; None when no
    payload decodes. proto3 omits fields at their default: within a message that decodes, an absent
    numeric field is 0 (a car at rest reports no speed), except the position (absent: no fix)."""
    rows: list[tuple[float, dict[str, float]]] = []
    dropped = 0
    for t, payload in samples:
        try:
            rows.append((t, decode_sei_metadata(payload)))
        except ValueError:
            dropped += 1
    if not rows:
        return None
    rows.sort(key=lambda r: r[0])
    video_t = np.array([t for t, _ in rows])
    channels = {}
    for name in CHANNELS:
        default = math.nan if name in ("lat", "lon", "heading_deg") else 0.0
        channels[name] = np.array([r.get(name, default) for _, r in rows], float)
    return TeslaTelemetry(video_t, channels, dropped)


# -- I/O edge ----------------------------------------------------------------------------------
def read_tesla_telemetry(video: str | os.PathLike, *, probe_packets: int = PROBE_PACKETS) -> TeslaTelemetry | None:
    """The Tesla SEI telemetry of ``video``; None when its first ``probe_packets`` video packets
    hold no Tesla SEI message (not a Tesla clip, or one recorded parked or before 2025.44.25)."""
    import av

    try:
        container = av.open(str(video))
    except (av.error.FFmpegError, OSError):
        return None
    samples: list[tuple[float, bytes]] = []
    with container as c:
        if not c.streams.video:
            return None
        v = c.streams.video[0]
        codec = v.codec_context.name
        if codec not in ("h264", "hevc"):
            return None
        hevc = codec == "hevc"
        extra = bytes(v.codec_context.extradata or b"")
        length_size = 4
        if extra and extra[0] == 1 and not hevc and len(extra) > 4:
            length_size = (extra[4] & 3) + 1
        elif extra and hevc and len(extra) > 21 and extra[0] == 1:
            length_size = (extra[21] & 3) + 1
        tb = float(v.time_base)
        t0 = None
        seen = 0
        try:
            for pkt in c.demux(v):
                if pkt.size == 0 or pkt.pts is None:
                    continue
                seen += 1
                t = pkt.pts * tb
                t0 = t if t0 is None else min(t0, t)
                for nal in nal_units(bytes(pkt), length_size):
                    for payload in sei_payloads(nal, hevc):
                        samples.append((t, payload))
                if not samples and seen >= probe_packets:
                    return None
        except (av.error.FFmpegError, OSError):
            pass  # a damaged tail: the samples read so far
    if not samples:
        return None
    start = t0 or 0.0
    return telemetry_from_samples([(t - start, p) for t, p in samples])
