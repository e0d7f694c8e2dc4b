"""What a camera records beside the pictures: the audio track and the raw telemetry tracks.

:func:`archive_streams` reads them from a drive's files (one, or the files of a trip in order) and
returns one small MP4 (the archive stores it as a blob next to the drive's bitstreams):

* the audio, re-encoded once as **Opus** (libopus, ``kbps_per_channel`` per channel, 48 kHz), on the
  drive's media clock (the frames of a trip's files back to back, as ``extract`` writes them: the
  parts' audio is cut or padded with silence at the joins so that it stays in step with the frames);
* the **telemetry** tracks (GoPro GPMF ``gpmd``, CAMM, NMEA text tracks, …) packet for packet,
  bytes unchanged, on the same clock. Tracks the MP4 muxer cannot hold (a QuickTime timecode
  track) are listed in :attr:`StreamsInfo.skipped`, not dropped silently.

:func:`concat_streams` joins two such MP4s on one clock without decoding them (a file appended to
a drive: its own MP4 placed after the drive's, packets copied). :func:`copy_streams` puts a
stretch of them into an output container (``extract``, ``clip``): the
Opus packets as they are, or re-encoded (e.g. to AAC for an MP4 that every phone plays), and the
telemetry packets unchanged. An MP4 is a standard file, so ExifTool and camera tools read the GPS
and IMU of the archived telemetry directly.
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from fractions import Fraction

import av
import numpy as np

from egovid.core.video.passthrough import muxable

OPUS_RATE = 48000
#: Output formats (FFmpeg muxer names) that hold raw telemetry tracks (GPMF, CAMM) as data streams.
DATA_FORMATS = ("mp4", "mov")


@dataclass
class StreamsInfo:
    """What :func:`archive_streams` kept: the audio (None if there was none) and each telemetry
    track (its tag and handler name, packet count), and what it could not keep, with why."""

    audio: dict | None = None
    telemetry: list[dict] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"audio": self.audio, "telemetry": self.telemetry, "skipped": self.skipped}


def _video_start(c: av.container.InputContainer) -> float:
    v = c.streams.video[0]
    return float(v.start_time * v.time_base) if v.start_time is not None else 0.0


def _unmuxable(path, index: int) -> str | None:
    """Why track ``index`` of ``path`` cannot go into an MP4 (None if it can)."""
    with av.open(str(path)) as c:
        s = c.streams[index]
        pkt = next((p for p in c.demux(s) if p.size and p.pts is not None), None)
        if pkt is None:
            return "no samples"
        return None if muxable(s, "mp4", pkt) else "the MP4 muxer cannot carry it"


def _outputs_of_first(
    c: av.container.InputContainer, path, out, info: StreamsInfo, kbps_per_channel: int
) -> tuple[dict[int, av.stream.Stream], av.stream.Stream | None, av.AudioResampler | None]:
    """The output streams of a drive's tracks, from its first file ``c`` (at ``path``): one per
    data or subtitle track the MP4 muxer can carry (by the track's index; the others named in
    ``info.skipped``), and an Opus stream with its resampler for the first audio track
    (described in ``info.audio``), or None."""
    data_out = {}
    for s in c.streams:
        if s.type not in ("data", "subtitle"):
            continue
        why = _unmuxable(path, s.index)
        if why:
            info.skipped.append(f"track {s.index} ({s.metadata.get('handler_name', '').strip()}): {why}")
        else:
            data_out[s.index] = out.add_stream_from_template(s)
    if not c.streams.audio:
        return data_out, None, None
    a = c.streams.audio[0]
    channels = max(1, min(2, a.codec_context.channels or 1))
    layout = "stereo" if channels == 2 else "mono"
    audio_out = out.add_stream("libopus", rate=OPUS_RATE, layout=layout)
    audio_out.bit_rate = kbps_per_channel * 1000 * channels
    resampler = av.AudioResampler(format="s16", layout=layout, rate=OPUS_RATE)
    info.audio = {
        "codec": "opus",
        "source_codec": a.codec_context.name,
        "channels": channels,
        "bit_rate": audio_out.bit_rate,
        "sample_rate": OPUS_RATE,
    }
    return data_out, audio_out, resampler


def _copy_track(c, s, dst, offset: float, duration: float, v0: float, out, last_pts: dict[int, int]) -> int:
    """Copy the packets of track ``s`` of file ``c`` to ``dst``, moved onto the drive's media clock
    (the file's first frame, at ``v0`` s on its own clock, lands at ``offset`` s; packets from
    ``offset + duration`` on and any not after the track's last one, ``last_pts``, are left out);
    returns how many were copied."""
    c.seek(0)
    shift = round((offset - v0) / s.time_base) if s.time_base else 0
    end = round((offset + duration) / s.time_base) if s.time_base else None
    copied = 0
    for pkt in c.demux(s):
        if pkt.size == 0 or pkt.pts is None:
            continue
        pts = pkt.pts + shift
        if pts <= last_pts.get(s.index, -(2**62)) or (end is not None and pts >= end):
            continue
        pkt.pts = pkt.dts = pts
        pkt.stream = dst
        out.mux(pkt)
        last_pts[s.index] = pts
        copied += 1
    return copied


def archive_streams(
    parts: Sequence[tuple[str | os.PathLike, float, float]], *, kbps_per_channel: int = 32
) -> tuple[bytes | None, StreamsInfo]:
    """The audio (as Opus) and telemetry tracks of a drive's files as one MP4, or None if the files
    have neither. ``parts``: (file, offset, duration) of each file on the drive's media clock, in
    seconds: where its first frame lands and how long its frames last."""
    info = StreamsInfo()
    buf = io.BytesIO()
    out = av.open(buf, "w", format="mp4")
    audio_out = None
    resampler = None
    written = 0  # audio samples written (48 kHz)
    data_out: dict[int, av.stream.Stream] = {}  # index of the track in the first file -> output stream
    last_pts: dict[int, int] = {}
    counts: dict[int, int] = {}
    try:
        for k, (path, offset, duration) in enumerate(parts):
            with av.open(str(path)) as c:
                v0 = _video_start(c)
                if k == 0:
                    data_out, audio_out, resampler = _outputs_of_first(c, path, out, info, kbps_per_channel)
                if audio_out is not None and c.streams.audio:
                    written = _encode_audio(c, v0, offset, duration, resampler, audio_out, out, written)
                elif audio_out is not None:  # a part without audio: silence keeps the rest in step
                    written = _silence_to(round((offset + duration) * OPUS_RATE), written, audio_out, out)
                for s in c.streams:
                    if s.index in data_out:
                        copied = _copy_track(c, s, data_out[s.index], offset, duration, v0, out, last_pts)
                        counts[s.index] = counts.get(s.index, 0) + copied
        if audio_out is not None:
            for p in audio_out.encode(None):
                out.mux(p)
        for idx, dst in data_out.items():
            info.telemetry.append(
                {"handler": dst.metadata.get("handler_name", "").strip(), "packets": counts.get(idx, 0)}
            )
        info.telemetry = [t for t in info.telemetry if t["packets"]]
        out.close()
    except BaseException:
        out.close()
        raise
    if info.audio is None and not info.telemetry:
        return None, info
    return buf.getvalue(), info


def concat_streams(first: bytes | None, second: bytes | None, offset: float) -> bytes | None:
    """The streams MP4 of a drive after a file is appended to it: ``first`` (the drive's so far,
    None if it had none) and ``second`` (the appended file's own, from :func:`archive_streams`,
    its clock from 0), placed ``offset`` seconds on (where the file's first frame lands on the
    drive's media clock). Packets are copied, never re-encoded: the audio stays one Opus track
    (decoded back to back, the appended part is late by its encoder delay, 312 samples, plus what
    the drive's trimmed last Opus frame still holds: 21.3 ms measured on the GoPro clip, under the
    ~45 ms at which late sound is noticed; cutting it would need a re-encode of the join),
    each telemetry track (matched by kind, codec and handler) one track. None when neither has any."""
    if second is None:
        return first
    if first is None and offset == 0:
        return second
    sources = [(x, shift) for x, shift in ((first, 0.0), (second, float(offset))) if x is not None]
    buf = io.BytesIO()
    out = av.open(buf, "w", format="mp4")
    opened = []
    try:
        keyed: dict[tuple, av.stream.Stream] = {}
        plan = []
        for data, shift in sources:
            c = av.open(io.BytesIO(data))
            opened.append(c)
            seen: dict[tuple, int] = {}
            for st in c.streams:
                codec_name = st.codec_context.name if st.codec_context is not None else getattr(st, "name", "")
                k = (st.type, codec_name, st.metadata.get("handler_name", "").strip())
                key = (*k, seen.get(k, 0))
                seen[k] = seen.get(k, 0) + 1
                if key not in keyed:
                    keyed[key] = out.add_stream_from_template(st)
                plan.append((c, st, keyed[key], shift))
        ends: dict[int, float] = {}  # output stream index -> end of its last packet (seconds)
        for c, st, dst, shift in plan:
            c.seek(0)
            tb = st.time_base
            base = round(Fraction(shift) / tb)
            extra = None
            for pkt in c.demux(st):
                if pkt.size == 0 or pkt.pts is None:
                    continue
                pts = pkt.pts + base
                if extra is None:  # the first packet: after what the stream holds already (which
                    # ends at ``shift``: a last packet's nominal duration may reach past it)
                    if dst.index in ends:
                        ends[dst.index] = min(ends[dst.index], float(shift))
                        extra = max(0, -(-(Fraction(ends[dst.index]) - pts * tb) // tb))
                    else:
                        extra = 0
                pts += extra
                if dst.index in ends and pts * tb < ends[dst.index] - Fraction(1, 10**6):
                    continue
                dur = pkt.duration or 0
                pkt.pts = pkt.dts = pts
                pkt.stream = dst
                out.mux(pkt)
                ends[dst.index] = float((pts + max(dur, 1)) * tb)
        out.close()
    except BaseException:
        out.close()
        raise
    finally:
        for c in opened:
            c.close()
    return buf.getvalue()


def _silence_to(target: int, written: int, stream, out) -> int:
    while written < target:
        n = min(960 * 50, target - written)
        channels = stream.codec_context.channels or 1
        frame = av.AudioFrame.from_ndarray(
            np.zeros((1, n * channels), np.int16), format="s16", layout="stereo" if channels == 2 else "mono"
        )
        frame.sample_rate, frame.pts = OPUS_RATE, written
        for p in stream.encode(frame):
            out.mux(p)
        written += n
    return written


def _encode_audio(c, v0: float, offset: float, duration: float, resampler, stream, out, written: int) -> int:
    """Encode a file's audio placed at ``offset`` (its first video frame) up to offset + duration:
    samples before what was written already are cut, a gap is filled with silence."""
    a = c.streams.audio[0]
    c.seek(0)
    end = round((offset + duration) * OPUS_RATE)
    channels = stream.codec_context.channels or 1
    for frame in c.decode(a):
        t = float(frame.pts * frame.time_base) - v0 if frame.pts is not None else None
        for r in resampler.resample(frame):
            pcm = r.to_ndarray().reshape(-1, channels)
            start = round((offset + t) * OPUS_RATE) if t is not None else written
            t = None  # later chunks of one decoded frame follow on directly
            if start > written:
                written = _silence_to(min(start, end), written, stream, out)
            cut = written - start if start < written else 0
            pcm = pcm[cut : max(cut, end - start)]
            if len(pcm) == 0:
                continue
            f = av.AudioFrame.from_ndarray(
                np.ascontiguousarray(pcm.reshape(1, -1)), format="s16", layout="stereo" if channels == 2 else "mono"
            )
            f.sample_rate, f.pts = OPUS_RATE, written
            for p in stream.encode(f):
                out.mux(p)
            written += len(pcm)
    return _silence_to(end, written, stream, out)


class StreamCopier:
    """Copies a stretch [t0, t1) (seconds on the drive's media clock) of the archived audio and
    telemetry into an output container, shifted to start at 0: the streams are added to ``out`` at
    construction (before the first packet is muxed), the packets on :meth:`write` (after the video).
    ``audio_codec``: None copies the Opus packets unchanged, else the encoder to re-encode with
    (``aac`` for an MP4 that every phone plays). Telemetry tracks the output format cannot hold
    (Matroska holds no GPMF track) are left out: :attr:`left_out` counts them."""

    def __init__(self, blob, out, t0, t1, *, audio_codec=None, audio_kbps=128) -> None:
        self.src = av.open(io.BytesIO(blob))
        self.out = out
        self.t0, self.t1 = t0, t1
        self.map: dict[int, av.stream.Stream] = {}
        self.audio_codec = audio_codec
        self.left_out = 0
        for s in self.src.streams:
            if s.type == "audio":
                if audio_codec is None:
                    self.map[s.index] = out.add_stream_from_template(s)
                else:
                    dst = out.add_stream(
                        audio_codec, rate=s.codec_context.sample_rate, layout=s.codec_context.layout.name
                    )
                    dst.bit_rate = audio_kbps * 1000
                    self.map[s.index] = dst
            elif out.format.name.split(",")[0] not in DATA_FORMATS:
                self.left_out += 1  # accepted here, but the header could not be written
            else:
                try:
                    self.map[s.index] = out.add_stream_from_template(s)
                except (ValueError, av.error.FFmpegError):
                    self.left_out += 1

    @property
    def kinds(self) -> list[str]:
        return sorted({s.type for s in self.map.values()})

    def write(self) -> None:
        for s, dst in self.map.items():
            src = self.src.streams[s]
            self.src.seek(0)
            if src.type == "audio" and self.audio_codec is not None:
                self._transcode(src, dst)
                continue
            a, b = round(Fraction(self.t0) / src.time_base), round(Fraction(self.t1) / src.time_base)
            for pkt in self.src.demux(src):
                if pkt.size == 0 or pkt.pts is None or pkt.pts < a or pkt.pts >= b:
                    continue
                pkt.pts = pkt.dts = pkt.pts - a
                pkt.stream = dst
                self.out.mux(pkt)

    def _transcode(self, src, dst) -> None:
        rate = src.codec_context.sample_rate
        a, b = round(self.t0 * rate), round(self.t1 * rate)
        resampler = av.AudioResampler(
            format=dst.codec_context.format.name,
            layout=dst.codec_context.layout.name,
            rate=dst.codec_context.sample_rate,
        )
        for frame in self.src.decode(src):
            start = round(float(frame.pts * frame.time_base) * rate)
            pcm = frame.to_ndarray()
            lo, hi = max(a, start), min(b, start + frame.samples)
            if hi <= lo:
                if start >= b:
                    break
                continue
            if frame.format.is_planar:
                part = pcm[:, lo - start : hi - start]
            else:
                ch = len(frame.layout.channels)
                part = pcm.reshape(-1, ch)[lo - start : hi - start].reshape(1, -1)
            f = av.AudioFrame.from_ndarray(
                np.ascontiguousarray(part), format=frame.format.name, layout=frame.layout.name
            )
            f.sample_rate = rate
            f.pts = lo - a
            for r in resampler.resample(f):
                for p in dst.encode(r):
                    self.out.mux(p)
        for p in dst.encode(None):
            self.out.mux(p)

    def close(self) -> None:
        self.src.close()
