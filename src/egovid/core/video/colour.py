"""How a video's pixel values are to be read: its colour tags (primaries, transfer, Y'CbCr matrix,
range) by FFmpeg's names, its HDR mastering-display and content-light metadata, the bits per
sample of a pixel format, and the writer's BGR -> I420 conversion with that matrix and range."""

from __future__ import annotations

import struct
from dataclasses import dataclass

import av
import cv2
import numpy as np

# FFmpeg's enum values (libavutil/pixfmt.h) by the names ffprobe prints.
# fmt: off
_PRIMARIES = {"bt709": 1, "bt470m": 4, "bt470bg": 5, "smpte170m": 6, "smpte240m": 7, "film": 8, "bt2020": 9,
              "smpte428": 10, "smpte431": 11, "smpte432": 12, "ebu3213": 22}
_TRANSFER = {"bt709": 1, "gamma22": 4, "gamma28": 5, "smpte170m": 6, "smpte240m": 7, "linear": 8, "log100": 9,
             "log316": 10, "iec61966-2-4": 11, "bt1361e": 12, "iec61966-2-1": 13, "bt2020-10": 14,
             "bt2020-12": 15, "smpte2084": 16, "smpte428": 17, "arib-std-b67": 18}
_MATRIX = {"gbr": 0, "bt709": 1, "fcc": 4, "bt470bg": 5, "smpte170m": 6, "smpte240m": 7, "ycgco": 8,
           "bt2020nc": 9, "bt2020c": 10, "smpte2085": 11, "chroma-derived-nc": 12, "chroma-derived-c": 13,
           "ictcp": 14}
_RANGE = {"tv": 1, "pc": 2}
# Luma weights (Kr, Kb) of the Y'CbCr matrices, for the writer's BGR -> YUV conversion.
_KR_KB = {"bt709": (0.2126, 0.0722), "bt2020nc": (0.2627, 0.0593), "bt2020c": (0.2627, 0.0593),
          "smpte240m": (0.212, 0.087), "fcc": (0.30, 0.11)}
# fmt: on


def _name_of(table: dict[str, int], value) -> str | None:
    """The name of FFmpeg's enum ``value`` in ``table`` (None when unknown)."""
    for name, v in table.items():
        if v == int(value or 0):
            return name
    return None


@dataclass(frozen=True)
class ColourTags:
    """How a video's pixel values are to be read: FFmpeg's names (as ffprobe prints them), ``None``
    where the file does not say.

    ``primaries`` (e.g. ``bt709``), ``transfer`` (``bt709``, ``smpte2084`` for HDR10 PQ,
    ``arib-std-b67`` for HLG), ``matrix`` (the Y'CbCr matrix: ``bt709``, ``smpte170m``, ``bt2020nc``)
    and ``range``: ``tv`` (limited, luma 16-235) or ``pc`` (full, 0-255; GoPro and many phones).
    """

    primaries: str | None = None
    transfer: str | None = None
    matrix: str | None = None
    range: str | None = None

    @classmethod
    def of(cls, obj) -> ColourTags:
        """The tags of a PyAV codec context or frame (anything with ``color_primaries``, ``color_trc``,
        ``colorspace`` and ``color_range``)."""
        rng = _name_of(_RANGE, obj.color_range)
        fmt = getattr(getattr(obj, "format", None), "name", None) or getattr(obj, "pix_fmt", None) or ""
        if rng is None and str(fmt).startswith("yuvj"):
            rng = "pc"  # the deprecated yuvj formats are full range by definition
        return cls(
            _name_of(_PRIMARIES, obj.color_primaries),
            _name_of(_TRANSFER, obj.color_trc),
            _name_of(_MATRIX, obj.colorspace),
            rng,
        )

    @property
    def full_range(self) -> bool:
        """True when luma spans 0-255 (``range == "pc"``)."""
        return self.range == "pc"

    def apply(self, target) -> None:
        """Write the known tags into a PyAV codec context or frame (unknown ones stay unspecified)."""
        for attr, table, name in (
            ("color_primaries", _PRIMARIES, self.primaries),
            ("color_trc", _TRANSFER, self.transfer),
            ("colorspace", _MATRIX, self.matrix),
            ("color_range", _RANGE, self.range),
        ):
            if name in table:
                setattr(target, attr, table[name])

    def to_dict(self) -> dict[str, str | None]:
        """JSON-ready form."""
        return {"primaries": self.primaries, "transfer": self.transfer, "matrix": self.matrix, "range": self.range}


def bgr_to_i420(image: np.ndarray, colour: ColourTags) -> np.ndarray:
    """BGR uint8 -> one (H*3/2, W) I420 array with the Y'CbCr matrix and range of ``colour``
    (BT.601 limited range where the tags do not say, as FFmpeg assumes)."""
    kr_kb = _KR_KB.get(colour.matrix or "")
    if kr_kb is None and not colour.full_range:
        # OpenCV's BT.601 limited-range conversion matches swscale's to ±1 and is ~10x faster.
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2YUV_I420)
    kr, kb = kr_kb or (0.299, 0.114)
    kg = 1.0 - kr - kb
    ys, cs, off = (255.0, 255.0, 0.0) if colour.full_range else (219.0, 224.0, 16.0)
    y = np.array([kb, kg, kr]) * ys / 255.0
    cb = (np.array([1.0, 0.0, 0.0]) - np.array([kb, kg, kr])) / (2 * (1 - kb)) * cs / 255.0
    cr = (np.array([0.0, 0.0, 1.0]) - np.array([kb, kg, kr])) / (2 * (1 - kr)) * cs / 255.0
    m = np.array([[*y, off], [*cb, 128.0], [*cr, 128.0]], np.float32)
    ycc = cv2.transform(np.ascontiguousarray(image), m)  # uint8, rounded and saturated
    h, w = image.shape[:2]
    out = np.empty((h * 3 // 2, w), np.uint8)
    out[:h] = ycc[..., 0]
    half = cv2.resize(ycc, (w // 2, h // 2), interpolation=cv2.INTER_AREA)  # 2x2 means
    flat = out[h:].reshape(-1)
    flat[: half.shape[0] * half.shape[1]] = half[..., 1].ravel()
    flat[half.shape[0] * half.shape[1] :] = half[..., 2].ravel()
    return out


def sample_bits(pix_fmt: str) -> int:
    """Bits per sample of FFmpeg's pixel format ``pix_fmt`` (8 for ``yuv420p``, 10 for
    ``yuv420p10le``; 8 where the format is unknown)."""
    try:
        return max(c.bits for c in av.VideoFormat(pix_fmt).components)
    except (ValueError, TypeError):
        return 8


@dataclass(frozen=True)
class HdrMetadata:
    """An HDR10 video's static metadata, as its frames carry it (HEVC SEI, FFmpeg's frame side data).

    ``display``: the mastering display's chromaticities as ``(Gx, Gy, Bx, By, Rx, Ry, WPx, WPy)`` in
    units of 0.00002 (CIE 1931 xy) and its ``(max, min)`` luminance in units of 0.0001 cd/m²
    (None where the frames carry none); ``light``: ``(MaxCLL, MaxFALL)`` in cd/m² (None likewise).
    The units are those of x265's ``master-display`` and ``max-cll`` (:meth:`x265_params`).
    """

    display: tuple[tuple[int, ...], tuple[int, int]] | None = None
    light: tuple[int, int] | None = None

    @classmethod
    def of(cls, frame: av.VideoFrame) -> HdrMetadata | None:
        """The metadata of a decoded PyAV frame; None when it has neither kind."""
        display = light = None
        for entry in frame.side_data:
            # PyAV 18.1.0 iterates the SideData themselves, 18.1.1 their types (a mapping)
            data = entry if isinstance(entry, av.sidedata.sidedata.SideData) else frame.side_data[entry]
            kind, raw = data.type, bytes(data)
            if kind == av.sidedata.sidedata.Type.MASTERING_DISPLAY_METADATA and len(raw) >= 88:
                # AVMasteringDisplayMetadata: 10 rationals (R, G, B, white xy; min, max luminance),
                # then has_primaries, has_luminance.
                v = struct.unpack("<20i2i", raw[:88])
                if v[20] and v[21]:
                    xy = [round(50000 * v[2 * i] / v[2 * i + 1]) if v[2 * i + 1] else 0 for i in range(8)]
                    r, g, b, wp = xy[0:2], xy[2:4], xy[4:6], xy[6:8]
                    lo = round(10000 * v[16] / v[17]) if v[17] else 0
                    hi = round(10000 * v[18] / v[19]) if v[19] else 0
                    display = ((*g, *b, *r, *wp), (hi, lo))
            elif kind == av.sidedata.sidedata.Type.CONTENT_LIGHT_LEVEL and len(raw) >= 8:
                light = struct.unpack("<2I", raw[:8])
        if display is None and light is None:
            return None
        return cls(display, light)

    def x265_params(self) -> str:
        """The metadata as x265 parameters (``master-display=...:max-cll=...``), which x265 writes
        as SEI messages into every keyframe."""
        parts = []
        if self.display is not None:
            (gx, gy, bx, by, rx, ry, wx, wy), (hi, lo) = self.display
            parts.append(f"master-display=G({gx},{gy})B({bx},{by})R({rx},{ry})WP({wx},{wy})L({hi},{lo})")
        if self.light is not None:
            parts.append(f"max-cll={self.light[0]},{self.light[1]}")
        return ":".join(parts)

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {"display": self.display, "light": self.light}
