"""How drives are ingested: encoder and alignment settings."""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass

from egovid.core.errors import EgovidError
from egovid.dashcam.align import ALIGNERS
from egovid.dashcam.codec import registry
from egovid.dashcam.codec.settings import ARCHIVE_DEFAULTS, LAYER_PERIODS, EncoderSettings

BASELINE_ALIGN = ("none", "gain", "similarity")
CODECS = ("av1", "vp9")  # what standalone pieces can be stored in

#: Named settings (``--preset``), the one copy of them: :class:`IngestOptions` takes its defaults
#: from :data:`DEFAULT_PRESET`'s, and explicit options override a preset. Measured in
#: benchmarks/dashcam_ingest_speed.py (speed) and benchmarks/dashcam_bdrate.py (savings).
#: ``codec``/``av1_speed``: the codec of pieces stored standalone (first drives, pieces with no
#: older drive of their path and light, and joint pieces where the standalone encode is smaller);
#: the VP9 settings (``realtime``, ``speed``, ...) code VP9 joint candidates and VP9 pieces.
#: ``joint_codec``: the codec of the joint candidate (``vp9``: libvpx at ``speed``; ``aom``: AV1 by
#: libaom at cpu-used ``aom_speed``, its realtime mode where ``realtime``, else good quality, at
#: quantiser ``--q`` + ``aom_dq``, in temporal layers of period ``aom_gop`` (1: flat), every
#: reference refresh kept where ``aom_keep_refresh``, its cost tables fixed within a frame where
#: ``aom_fixed_costs``, motion-field projection off where not ``aom_ref_mvs``, quantisation
#: matrices where ``aom_qm``, in ``2^aom_tile_columns`` tile columns).
PRESETS: dict[str, dict] = {
    # SVT-AV1 preset 10 for standalone pieces; the joint candidate in AV1 by libaom's realtime
    # mode at cpu-used 7, flat (each frame from the ones before it and the older drive), every
    # reference refresh kept, at --q + 10 (about SVT-AV1's PSNR-Y at --q + 14), two threads
    # sharing rows in one tile column, its coefficient, mode and motion-vector cost tables fixed
    # within a frame, motion-field projection off and quantisation matrices on: new drives of the
    # day set -32.9 % BD-rate (PSNR-Y) against plain SVT-AV1 preset 10 through `egovid dashcam
    # ingest` (-27.3 % without the last two, 2026-12-07, the same drives; -25.9 % with two tile
    # columns and libaom's cost updates; VP9 joint: +0.3 %, it lost every piece), the whole archive
    # -41.9 % against the VP9 archive of before (docs/dashcam.md, "Codecs"). Speed, 720p joint
    # drive, 2 cores: 34.1-35.6 fps against 29.7-31.0 before (2026-12-05 09:41-09:44 UTC, load
    # 4.7-8.7, benchmarks/dashcam_ingest_speed.py, docs/dashcam.md "Faster since"); 1080p
    # 17.4 fps against 17.2. Temporal layers (aom_gop 4, base at --q + 5) measured -19.6 %: not taken.
    # The VP9 settings (libvpx realtime at its fastest, first frame of a joint run at cpu-used 5)
    # serve --joint-codec vp9 and --codec vp9. One set of ORB key points per frame shared by the
    # search and the refinement, which measure every 2nd frame (the others interpolated).
    "realtime": {
        "codec": "av1",
        "av1_speed": 10,
        "realtime": True,
        "speed": 9,
        "start_speed": 5,
        "threads": 2,
        "row_mt": True,
        "tile_columns": 1,
        "refine_radius": 2,
        "refine_features": 0,
        "align_every": 2,
        "verify_share": 0.25,
        "joint_codec": "aom",
        "aom_speed": 7,
        "aom_dq": 10,
        "aom_gop": 1,
        "aom_keep_refresh": True,
        "aom_fixed_costs": True,
        "aom_ref_mvs": False,
        "aom_qm": True,
        "aom_tile_columns": 0,
    },
    # SVT-AV1 preset 8; libvpx's good-quality deadline at its fastest speed, two threads sharing
    # rows and two tile columns: the different-day saving of the archive preset's deadline
    # (libvpx's realtime mode never searches ALTREF and skips GOLDEN, the older drive, in much of
    # the frame; see docs/dashcam.md) at about twice its speed.
    "balanced": {
        "codec": "av1",
        "av1_speed": 8,
        "realtime": False,
        "speed": 5,
        "start_speed": 0,
        "threads": 2,
        "row_mt": True,
        "tile_columns": 1,
        "refine_radius": 3,
        "refine_features": 1000,
        "align_every": 1,
        "verify_share": 1.0,
        "joint_codec": "vp9",
        "aom_speed": 6,
        "aom_dq": registry.BACKENDS["aom"].q_offset,
        "aom_gop": 1,
        "aom_keep_refresh": False,
        "aom_fixed_costs": False,
        "aom_ref_mvs": True,
        "aom_qm": False,
        "aom_tile_columns": 1,
    },
    # SVT-AV1 preset 6; the joint candidate in AV1 by libaom's good-quality mode at cpu-used 6 (its
    # fastest), one thread: the smallest files (docs/dashcam.md, "Codecs").
    "archive": {
        "codec": "av1",
        "av1_speed": 6,
        "realtime": False,
        "speed": 5,
        "start_speed": 0,
        "threads": 1,
        "row_mt": False,
        "tile_columns": 0,
        "refine_radius": 3,
        "refine_features": 1000,
        "align_every": 1,
        "verify_share": 1.0,
        "joint_codec": "aom",
        "aom_speed": 6,
        "aom_dq": registry.BACKENDS["aom"].q_offset,
        "aom_gop": 1,
        "aom_keep_refresh": False,
        "aom_fixed_costs": False,
        "aom_ref_mvs": True,
        "aom_qm": False,
        "aom_tile_columns": 0,
    },
}
DEFAULT_PRESET = "realtime"
_D = PRESETS[DEFAULT_PRESET]
#: SVT-AV1's CRF of equal PSNR-Y to libvpx's quantiser q is about q + 14 over q 28-44
#: (640x360 different-day drive, VP9 realtime preset q 32: 34.1 dB; SVT-AV1 preset 10 CRF 46:
#: 34.2 dB; docs/dashcam.md "Codecs"), so one ``--q`` sets both.
AV1_DQ = 14


@dataclass(frozen=True)
class IngestOptions:
    """How a drive is ingested (the defaults are those of :data:`DEFAULT_PRESET`).

    ``q``: the archive's quantiser on libvpx's 0-63 scale (lower = better quality; VP9 frames
    between anchors use ``q + 12``; AV1 pieces are coded at SVT-AV1 CRF ``q + AV1_DQ``, the same
    PSNR-Y); ``codec``: what standalone pieces are stored in (av1 | vp9); ``av1_speed``: SVT-AV1
    preset (0-13); ``speed``: libvpx cpu-used; ``realtime``: realtime instead of good-quality
    deadline; ``gop``: VP9 anchor spacing in frames (8, the default; 1 = low delay, every frame
    from the one before); ``refresh``: random-access period in frames (a drive can be decoded from
    every ``refresh``-th frame on: a keyframe for a standalone piece, a frame predicted from the
    older drive alone for a joint one; 0 = from the start only);
    ``aligner``: orb (thesis' ORB search, smoothed and refined by vertical image scale; the default) |
    orb-plain (the thesis' search alone) | seqslam | gps;
    ``baseline_align``: none | gain | similarity (global alignment of the baseline);
    ``measure_savings``: report each joint piece's saving against its standalone encode (the
    standalone encode runs for every piece with an older drive anyway: the smaller is kept);
    ``verify``: a decoder follows the encoder packet by packet and must reproduce its pictures;
    ``verify_share``: the share of a segment's random-access runs it follows besides the first and
    the last (a seeded sample, :func:`verified_runs`; 1: all). Every run's digest is taken from the
    encoder's pictures either way and checked by every extract;
    ``threads``, ``row_mt``, ``tile_columns``: the encoders' threading (``tile_columns``: libvpx's,
    log2);
    ``start_speed``: cpu-used of the first frame of a joint random-access run (0 = ``speed``);
    ``refine_radius``: reference frames either side of a match measured by the vertical-scale
    refinement; ``refine_features``: its ORB key points per frame (0: the search's own, 500);
    ``align_every``: the ORB aligners search and refine every n-th frame, the matches of the
    frames between interpolated (1: every frame);
    ``joint_codec``: the codec of a piece's joint candidate, coded against the older drive
    (``vp9`` | ``aom``: AV1 by libaom); ``aom_speed``: its libaom cpu-used (0-9 in good quality,
    0-10 with ``realtime``); ``aom_dq``: what its libaom quantiser adds to ``q`` (the base layer's,
    with temporal layers); ``aom_gop``: its temporal-layer period (1 flat; 2 or 4 layers, the top
    layer at ``+12`` over the base, :class:`~egovid.dashcam.codec.aom.RunRefs`);
    ``aom_keep_refresh``: its flat structure keeps every reference refresh in libaom's realtime
    mode (:class:`~egovid.dashcam.codec.settings.EncoderSettings` ``keep_refresh``; False: coded as
    the first libaom archives); ``aom_fixed_costs``: its coefficient, mode and motion-vector cost
    tables are not updated within a frame (:class:`~egovid.dashcam.codec.settings.EncoderSettings`
    ``fixed_costs``; False: libaom's defaults); ``aom_ref_mvs``: False turns off its motion-field
    projection and ``aom_qm`` turns on its quantisation matrices (``ref_mvs``, ``qm``; True and
    False: libaom's defaults, as the first libaom archives); ``aom_tile_columns``: its tile columns
    (log2; ``tile_columns`` is libvpx's);
    ``preset``: the name of the preset these came from (recorded with each segment).
    """

    q: int = ARCHIVE_DEFAULTS["q"]
    codec: str = _D["codec"]
    av1_speed: int = _D["av1_speed"]
    speed: int = _D["speed"]
    realtime: bool = _D["realtime"]
    gop: int = ARCHIVE_DEFAULTS["gop"]
    refresh: int = ARCHIVE_DEFAULTS["refresh"]
    aligner: str = "orb"
    baseline_align: str = "none"
    measure_savings: bool = False
    verify: bool = True
    verify_share: float = _D["verify_share"]
    threads: int = _D["threads"]
    row_mt: bool = _D["row_mt"]
    tile_columns: int = _D["tile_columns"]
    start_speed: int = _D["start_speed"]
    refine_radius: int = _D["refine_radius"]
    refine_features: int = _D["refine_features"]
    align_every: int = _D["align_every"]
    joint_codec: str = _D["joint_codec"]
    aom_speed: int = _D["aom_speed"]
    aom_dq: int = _D["aom_dq"]
    aom_gop: int = _D["aom_gop"]
    aom_keep_refresh: bool = _D["aom_keep_refresh"]
    aom_fixed_costs: bool = _D["aom_fixed_costs"]
    aom_ref_mvs: bool = _D["aom_ref_mvs"]
    aom_qm: bool = _D["aom_qm"]
    aom_tile_columns: int = _D["aom_tile_columns"]
    preset: str | None = DEFAULT_PRESET

    @classmethod
    def from_preset(cls, preset: str | None = None, **overrides) -> IngestOptions:
        """The options of a named preset (:data:`PRESETS`; default :data:`DEFAULT_PRESET`), with
        ``overrides`` (those that are not None) on top."""
        name = preset or DEFAULT_PRESET
        if name not in PRESETS:
            raise EgovidError(f"unknown preset {name!r}", f"choose one of {', '.join(PRESETS)}")
        given = {k: v for k, v in overrides.items() if v is not None}
        return cls(**{**PRESETS[name], **given, "preset": name})

    def check(self) -> IngestOptions:
        """Raise :class:`EgovidError` for settings that cannot work (before any work starts)."""
        self.encoder_settings(30.0)  # EncoderSettings checks the ranges: q, speed, gop, random access, ...
        if self.codec not in CODECS:
            raise EgovidError(f"unknown codec {self.codec!r}", f"choose one of {', '.join(CODECS)}")
        if self.joint_codec not in registry.joint_codecs():
            raise EgovidError(
                f"{self.joint_codec!r} cannot code against the older drive",
                f"choose one of {', '.join(registry.joint_codecs())}",
            )
        self.joint_settings(30.0)
        self.standalone_settings(30.0)
        if self.aligner not in ALIGNERS:
            raise EgovidError(f"unknown aligner {self.aligner!r}", f"choose one of {', '.join(ALIGNERS)}")
        if self.refine_features != 0 and not 100 <= self.refine_features <= 5000:
            raise EgovidError(f"{self.refine_features} refinement features is outside 100-5000", "use 0 or 1000")
        if not 1 <= self.align_every <= 4:
            raise EgovidError(f"aligning every {self.align_every}th frame is outside 1-4", "use 1 or 2")
        if not 0 <= self.aom_dq <= 30:
            raise EgovidError(f"libaom quantiser offset {self.aom_dq} is outside 0-30", "use the preset's")
        if self.aom_gop not in LAYER_PERIODS:
            raise EgovidError(f"libaom layer period {self.aom_gop} is not one of {LAYER_PERIODS}", "use 1 or 4")
        if not 0.0 < self.verify_share <= 1.0:
            raise EgovidError(f"verifying a share of {self.verify_share} of the runs is outside (0, 1]", "use 1")
        if not 1 <= self.refine_radius <= 10:
            raise EgovidError(f"refinement radius {self.refine_radius} is outside 1-10", "use 2 or 3")
        if self.baseline_align not in BASELINE_ALIGN:
            raise EgovidError(
                f"unknown baseline alignment {self.baseline_align!r}", f"choose one of {', '.join(BASELINE_ALIGN)}"
            )
        return self

    def verified_runs(self, n_runs: int, seed: int = 0) -> Callable[[int], bool]:
        """Which of a segment's ``n_runs`` random-access runs the verifying decoder follows: the
        first, the last and a random ``verify_share`` of the others (seeded by ``seed``, e.g. the
        segment's first frame, so an ingest repeated verifies the same runs); ask in run order."""
        rng = random.Random(f"egovid-verify-{seed}")
        share = self.verify_share
        return lambda i: share >= 1.0 or i in (0, n_runs - 1) or rng.random() < share

    def encoder_settings(self, fps: float) -> EncoderSettings:
        """The VP9 settings: the joint candidate's with ``joint_codec`` vp9 (:meth:`joint_settings`)
        and standalone pieces' with ``codec`` vp9."""
        return EncoderSettings(
            q=self.q,
            speed=self.speed,
            codec="vp9",
            realtime=self.realtime,
            fps=round(fps) or 30,
            gop=self.gop,
            refresh=self.refresh,
            threads=self.threads,
            tile_columns=self.tile_columns,
            row_mt=self.row_mt,
            start_speed=self.start_speed,
        )

    def joint_settings(self, fps: float) -> EncoderSettings:
        """The settings of a piece's joint candidate (``joint_codec``): :meth:`encoder_settings`
        for VP9; libaom at ``q + aom_dq``, cpu-used ``aom_speed``, layer period ``aom_gop``, the
        same threading and random-access period otherwise (low delay: nothing coded out of
        order)."""
        vp9 = self.encoder_settings(fps)
        b = registry.backend(self.joint_codec)
        if b.name == vp9.codec:
            return vp9
        return EncoderSettings(
            q=min(63, self.q + self.aom_dq),
            speed=self.aom_speed,
            codec=b.name,
            realtime=self.realtime,
            fps=vp9.fps,
            gop=self.aom_gop,
            keep_refresh=self.aom_keep_refresh,
            fixed_costs=self.aom_fixed_costs,
            ref_mvs=self.aom_ref_mvs,
            qm=self.aom_qm,
            refresh=self.refresh,
            threads=self.threads,
            tile_columns=self.aom_tile_columns,
            row_mt=self.row_mt,
        )

    def standalone_settings(self, fps: float) -> EncoderSettings:
        """The settings of a piece stored standalone (``codec``)."""
        if self.codec == "vp9":
            return self.encoder_settings(fps)
        return EncoderSettings(
            q=min(63, self.q + AV1_DQ),
            speed=self.av1_speed,
            codec=self.codec,
            fps=round(fps) or 30,
            refresh=self.refresh,
            threads=self.threads,
        )
