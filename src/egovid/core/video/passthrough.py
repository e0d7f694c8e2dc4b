"""Copying the streams of a source file that the writer does not encode: audio, and the data
(telemetry) streams the output container can carry, packet by packet, interleaved by time."""

from __future__ import annotations

import io
import os

import av


def muxable(stream: av.stream.Stream, fmt: str, packet: av.Packet | None) -> bool:
    """Whether a container of format ``fmt`` can carry a copy of ``stream`` (tried in memory)."""
    buf = io.BytesIO()
    try:
        with av.open(buf, "w", format=fmt) as out:
            o = out.add_stream_from_template(stream)
            if packet is not None:
                packet.stream = o
                out.mux(packet)
        return True
    except Exception:
        return False


class Passthrough:
    """Copies the audio (and, with ``data=True``, the data) packets of a source file into an output
    container, interleaved by time and shifted by the source video's start time."""

    def __init__(self, source: str | os.PathLike, out: av.container.OutputContainer, *, data: bool) -> None:
        self.kept: list[str] = []
        self.dropped: list[str] = []
        self._src = av.open(str(source))
        self._out = out
        self._map: dict[int, av.stream.Stream] = {}
        fmt = out.format.name.split(",")[0]
        for s in self._src.streams:
            if s.type == "audio":
                self._map[s.index] = out.add_stream_from_template(s)
                self.kept.append(f"audio ({s.codec_context.name})")
            elif s.type == "data" and data:
                what = (s.metadata.get("handler_name") or "").strip() or getattr(s, "name", None) or "data"
                first = next((p for p in self._src.demux(s) if p.size), None)
                self._src.seek(0)
                if first is not None and muxable(s, fmt, first):
                    o = out.add_stream_from_template(s)
                    for k, v in s.metadata.items():
                        o.metadata[k] = v
                    self._map[s.index] = o
                    self.kept.append(f"data stream {what!r}")
                elif not s.metadata.get("timecode"):  # a timecode track is rewritten from the video's tag
                    self.dropped.append(f"data stream {what!r} ({fmt} cannot carry it)" if first else f"empty {what!r}")
        streams = [s for s in self._src.streams if s.index in self._map]
        self._packets = self._src.demux(*streams) if streams else iter(())
        self._pending: av.Packet | None = None
        self._done = not streams
        self._t0 = 0.0
        vs = self._src.streams.video
        if vs and vs[0].start_time is not None and vs[0].time_base is not None:
            self._t0 = float(vs[0].start_time * vs[0].time_base)

    def feed_until(self, t: float) -> None:
        """Mux source packets up to ``t`` + 0.5 seconds (output time)."""
        while not self._done:
            pkt = self._pending
            self._pending = None
            if pkt is None:
                try:
                    pkt = next(self._packets)
                except StopIteration:
                    self._done = True
                    return
            if (pkt.dts is None and pkt.pts is None) or pkt.stream.index not in self._map:
                continue
            pts = pkt.pts if pkt.pts is not None else pkt.dts
            if float(pts * pkt.time_base) - self._t0 > t + 0.5:
                self._pending = pkt
                return
            shift = round(self._t0 / pkt.time_base)
            if shift:
                if pkt.pts is not None:
                    pkt.pts -= shift
                if pkt.dts is not None:
                    pkt.dts -= shift
            pkt.stream = self._map[pkt.stream.index]
            self._out.mux(pkt)

    def close(self) -> None:
        """Close the source file."""
        self._src.close()
