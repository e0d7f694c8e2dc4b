"""How a segment is encoded: the one definition of the encoder settings every codec backend
reads (:mod:`egovid.dashcam.codec.registry`). The named presets that fill them in live in one
place, :data:`egovid.dashcam.ingest.options.PRESETS`."""

from __future__ import annotations

from dataclasses import dataclass

from egovid.core.errors import EgovidError

#: Speed ranges per codec: libvpx cpu-used, SVT-AV1 preset, libaom cpu-used (higher = faster in
#: all; libaom's good-quality mode stops at 9 and codes 7-9 as 6, its realtime mode goes to 10).
SPEEDS = {"vp9": (0, 9), "av1": (0, 13), "aom": (0, 10)}

#: Temporal-layer periods of a libaom segment (its ``gop``): 1 = flat (every frame from the one
#: before, the structure of the first libaom archives), 2 or 4 = temporal layers
#: (:func:`egovid.dashcam.codec.aom.layer_of`).
LAYER_PERIODS = (1, 2, 4)

#: The archive's coding defaults, their one copy: :class:`~egovid.dashcam.ingest.options.IngestOptions`
#: takes them, and ``egovid dashcam ingest --help`` shows them without importing the ingest (OpenCV,
#: SciPy): quantiser ``q`` (libvpx's 0-63 scale), VP9 anchor spacing ``gop`` and random-access
#: period ``refresh``, in frames (the thesis' 3D-HEVC configuration: GOP 8, intra period 24).
ARCHIVE_DEFAULTS = {"q": 32, "gop": 8, "refresh": 24}


@dataclass(frozen=True)
class EncoderSettings:
    """``codec``: ``vp9`` (libvpx; can code against the older drive), ``av1`` (SVT-AV1, decoded
    with dav1d; standalone only) or ``aom`` (AV1 by libaom; can code against the older drive);
    fixed quantiser ``q`` (0-63: libvpx's and libaom's quantiser, SVT-AV1's CRF); ``speed``: libvpx
    cpu-used (0-9), SVT-AV1 preset (0-13) or libaom cpu-used (0-10); ``realtime``: libvpx's
    realtime deadline, libaom's realtime mode; ``threads``: encoder threads (SVT-AV1: its logical
    processors); ``tile_columns`` (log2) and ``row_mt``: libvpx's and libaom's multi-threading (the
    bitstream decodes to the same pictures whatever the threads); coding structure ``gop`` (libaom: the temporal-layer
    period, 1 flat, 2 or 4 layers in realtime mode only, the top layer at ``q + gop_dq``,
    :class:`~egovid.dashcam.codec.aom.RunRefs`; VP9: 1 = low delay; G > 1 = every G-th
    frame an *anchor* predicted from the anchor before it, the frames between coded after it from
    the previous frame and the anchor ahead, at quantiser ``q + gop_dq``; see
    :mod:`egovid.dashcam.codec.segment`; SVT-AV1 chooses its own hierarchical structure) and
    ``refresh``, the random-access period in frames (0 = only the first frame; the keyframe
    spacing of an AV1 segment); ``start_speed``: VP9 cpu-used for the first frame of a joint run,
    the one predicted from the baseline alone (0 = ``speed``); ``keep_refresh`` (libaom): every
    slot refresh of the structure is kept in libaom's realtime mode, which otherwise drops those
    of slots no reference type points at (:class:`~egovid.dashcam.codec.aom.RunRefs`; False: the
    flat structure of the first libaom archives, byte for byte; layers always keep theirs);
    ``fixed_costs`` (libaom): no updates of the coefficient, mode and motion-vector cost tables
    within a frame (:class:`~egovid.dashcam.codec.aom.AomSettings`; an encoder setting only, the
    decoder needs nothing; False: libaom's defaults, as the first libaom archives); ``ref_mvs``
    (libaom): False turns off motion-field projection (temporal motion-vector candidates
    projected from the reference frames' motion vectors); ``qm`` (libaom): quantisation matrices
    (both encoder settings only, the decoder reads them from the bitstream; True and False are
    libaom's defaults, as the first libaom archives, and leave its controls unset)."""

    q: int
    speed: int
    codec: str = "vp9"
    realtime: bool = False
    fps: int = 30
    gop: int = 1
    gop_dq: int = 12
    refresh: int = 0
    threads: int = 1
    tile_columns: int = 0
    row_mt: bool = False
    start_speed: int = 0
    keep_refresh: bool = False
    fixed_costs: bool = False
    ref_mvs: bool = True
    qm: bool = False

    def __post_init__(self) -> None:
        if self.codec not in SPEEDS:
            raise EgovidError(f"unknown codec {self.codec!r}", f"choose one of {', '.join(SPEEDS)}")
        if not 0 <= self.q <= 63:
            raise EgovidError(f"quantiser {self.q} is outside 0-63", "use e.g. --q 32")
        lo, hi = SPEEDS[self.codec]
        if not lo <= self.speed <= hi:
            raise EgovidError(f"--speed {self.speed} is outside {lo}-{hi} for {self.codec}", "use the preset's")
        if self.codec == "aom" and not self.realtime and self.speed > 9:
            raise EgovidError(f"libaom cpu-used {self.speed} needs its realtime mode", "use 0-9 (6 is its fastest)")
        if not 0 <= self.start_speed <= 9:
            raise EgovidError(f"run-start cpu-used {self.start_speed} is outside 0-9", "use 0 (= speed) or e.g. 5")
        if not 1 <= self.threads <= 64:
            raise EgovidError(f"{self.threads} encoder threads is outside 1-64", "use e.g. 2")
        if not 0 <= self.tile_columns <= 6:
            raise EgovidError(f"tile columns 2^{self.tile_columns} is outside 2^0-2^6", "use e.g. 1")
        if self.refresh != 0 and not 2 <= self.refresh <= 65535:
            raise EgovidError(
                f"random-access period {self.refresh} frames is outside 2-65535", "use 0 (none) or e.g. 24"
            )
        if not 1 <= self.gop <= 64:
            raise EgovidError(f"GOP length {self.gop} is outside 1-64", "use 1 (low delay) or 8")
        if self.codec == "aom" and self.gop not in LAYER_PERIODS:
            raise EgovidError(
                f"libaom temporal-layer period {self.gop} is not one of {LAYER_PERIODS}", "use 1 (flat) or 4"
            )
        if self.codec == "aom" and self.gop > 1 and not self.realtime:
            # good quality does not keep to the explicit structure (a decoder given all but the
            # top layer fails on the frames after it)
            raise EgovidError("libaom temporal layers need its realtime mode", "use layer period 1 (flat)")
        if not 0 <= self.gop_dq <= 63:
            raise EgovidError(f"quantiser offset {self.gop_dq} is outside 0-63", "use e.g. 12")
