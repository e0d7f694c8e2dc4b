"""AV1 through libaom with an externally supplied reference picture (thesis §14.2, the design of
:mod:`egovid.dashcam.codec.vpx` on an AV1 encoder).

Before a frame, the older drive's aligned frame (the *baseline*) is copied into one of AV1's eight
reference slots on both the encoder and the decoder (``AV1_SET_REFERENCE``). The encoder is told,
frame by frame, which slots its seven references point to and which slots the frame refreshes
(``AV1E_SET_SVC_REF_FRAME_CONFIG``: libaom's explicit reference structure, honoured in both its
realtime and good-quality modes); the baseline's slot (:data:`BASELINE_SLOT`) is never
refreshed, so every frame may predict from its previous frames and from the older drive. The
decoder needs only the injections: which slots a frame reads and refreshes is in the bitstream.

Bindings are ctypes on the system's libaom (Debian's libaom3, 3.6; ``libaom.so.3``; PyAV's
FFmpeg has no libaom). There are no headers at run time: the structure layouts, control ids and
flags below are those of libaom 3.6.0's ``aom/aom_encoder.h``, ``aom/aomcx.h``, ``aom/aomdx.h``,
``aom/aom_image.h``, ``aom/aom_codec.h`` and ``aom/aom.h``, whose offsets were read from those
headers with ``offsetof`` (the same values as the public libaom 3.x sources; the 3.x series is ABI
compatible). The encoder and decoder ABI versions are looked up from ``aom_codec_version()`` and
confirmed by probing, and a self-test (encode with injection, decode with injection, compare with
the encoder's own pictures, check that decoding *without* the injection differs and that the
injection pays) runs once per process before anything is coded.

What keeps the injected slot intact and the stream reproducible: no look-ahead
(``g_lag_in_frames = 0``; no alt-ref, no temporal filtering), no frame dropping, no resizing or
super-resolution, fixed quantiser (``rc_min_quantizer = rc_max_quantizer``, ``AOM_Q``), no
adaptive quantisation, keyframes only where asked, the 8-bit coding path on both sides. After a
keyframe all eight slots share one buffer (a keyframe refreshes every slot), so the first frame
after it must refresh the slots the previous-frame references use before they are read; the
baseline's slot keeps that shared buffer, and the copy into it changes nothing another reference
reads. Frames are I420 padded to a multiple of 8 pixels (AV1's reference buffers are aligned to 8).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
from dataclasses import dataclass

import numpy as np

from egovid.core.errors import EgovidError
from egovid.dashcam.codec.settings import LAYER_PERIODS

# Control ids and flags (libaom 3.6.0: aom/aom.h, aom/aomcx.h, aom/aom_encoder.h, aom/aom_image.h).
AOM_IMG_FMT_I420 = 0x102
AOM_IMG_FMT_HIGHBITDEPTH = 0x800
AV1_SET_REFERENCE = 231
AV1_COPY_REFERENCE = 232
AV1_GET_NEW_FRAME_IMAGE = 233
AOME_SET_CPUUSED = 13
AOME_SET_ENABLEAUTOALTREF = 14
AOME_SET_STATIC_THRESHOLD = 17
AOME_SET_CQ_LEVEL = 25
AV1E_SET_ROW_MT = 32
AV1E_SET_TILE_COLUMNS = 33
AV1E_SET_ENABLE_TPL_MODEL = 35
AV1E_SET_ENABLE_KEYFRAME_FILTERING = 36
AV1E_SET_AQ_MODE = 40
AV1E_SET_ENABLE_QM = 63
AV1E_SET_ENABLE_REF_FRAME_MVS = 84
AV1E_SET_COEFF_COST_UPD_FREQ = 126
AV1E_SET_MODE_COST_UPD_FREQ = 127
AV1E_SET_MV_COST_UPD_FREQ = 128
COST_UPD_OFF = 3  # the cost-update frequency controls' "turn off"
#: The cost tables :class:`AomSettings` ``fixed_costs`` leaves alone within a frame.
FIXED_COSTS = (AV1E_SET_COEFF_COST_UPD_FREQ, AV1E_SET_MODE_COST_UPD_FREQ, AV1E_SET_MV_COST_UPD_FREQ)
AV1E_SET_DELTAQ_MODE = 107
AV1E_SET_SVC_REF_FRAME_CONFIG = 133
AOM_EFLAG_FORCE_KF = 1
AOM_USAGE_GOOD_QUALITY, AOM_USAGE_REALTIME = 0, 1
AOM_Q = 3
AOM_KF_DISABLED = 0
AOM_CODEC_CX_FRAME_PKT = 0
AOM_CODEC_ABI_MISMATCH = 3
AOM_FRAME_IS_KEY = 1

#: AV1's reference types in the order of ``aom_svc_ref_frame_config_t`` (and its 8 slots).
LAST, LAST2, LAST3, GOLDEN, BWDREF, ALTREF2, ALTREF = range(7)
SLOTS = 8
#: The slot the baseline is injected into; never refreshed after a run's keyframe.
BASELINE_SLOT = 3
#: The slot the top temporal layer's frames refresh and no frame reads (a shown frame that
#: refreshes no slot comes out of libaom 3.6's decoder other than the encoder's picture).
SCRATCH_SLOT = 2

# Byte offsets in aom_codec_enc_cfg_t (904 bytes in 3.6.0; offsetof on its headers).
_CFG = {
    "g_usage": 0,
    "g_threads": 4,
    "g_profile": 8,
    "g_w": 12,
    "g_h": 16,
    "g_bit_depth": 32,
    "g_input_bit_depth": 36,
    "g_timebase_num": 40,
    "g_timebase_den": 44,
    "g_error_resilient": 48,
    "g_pass": 52,
    "g_lag_in_frames": 56,
    "rc_dropframe_thresh": 60,
    "rc_resize_mode": 64,
    "rc_superres_mode": 76,
    "rc_end_usage": 96,
    "rc_min_quantizer": 140,
    "rc_max_quantizer": 144,
    "kf_mode": 184,
    "kf_min_dist": 188,
    "kf_max_dist": 192,
}
_CFG_SIZE = 904
#: Known ABI versions by major version (AOM_ENCODER_ABI_VERSION, AOM_DECODER_ABI_VERSION of 3.x).
_ENC_ABI = {3: 29}
_DEC_ABI = {3: 22}
_PAD = 8


class AomImage(ctypes.Structure):
    """aom_image_t (libaom 3.6.0, 168 bytes)."""

    _fields_ = [
        ("fmt", ctypes.c_int),
        ("cp", ctypes.c_int),
        ("tc", ctypes.c_int),
        ("mc", ctypes.c_int),
        ("monochrome", ctypes.c_int),
        ("csp", ctypes.c_int),
        ("range", ctypes.c_int),
        ("w", ctypes.c_uint),
        ("h", ctypes.c_uint),
        ("bit_depth", ctypes.c_uint),
        ("d_w", ctypes.c_uint),
        ("d_h", ctypes.c_uint),
        ("r_w", ctypes.c_uint),
        ("r_h", ctypes.c_uint),
        ("x_chroma_shift", ctypes.c_uint),
        ("y_chroma_shift", ctypes.c_uint),
        ("planes", ctypes.POINTER(ctypes.c_ubyte) * 3),
        ("stride", ctypes.c_int * 3),
        ("sz", ctypes.c_size_t),
        ("bps", ctypes.c_int),
        ("temporal_id", ctypes.c_int),
        ("spatial_id", ctypes.c_int),
        ("user_priv", ctypes.c_void_p),
        ("img_data", ctypes.c_void_p),
        ("img_data_owner", ctypes.c_int),
        ("self_allocd", ctypes.c_int),
        ("metadata", ctypes.c_void_p),
        ("fb_priv", ctypes.c_void_p),
    ]


class Av1RefFrame(ctypes.Structure):
    """av1_ref_frame_t: the slot (0-7), whether the decoder may use the buffer in place, the image."""

    _fields_ = [("idx", ctypes.c_int), ("use_external_ref", ctypes.c_int), ("img", AomImage)]


class RefConfig(ctypes.Structure):
    """aom_svc_ref_frame_config_t: per reference type whether it is used and its slot; per slot
    whether the frame refreshes it."""

    _fields_ = [("reference", ctypes.c_int * 7), ("ref_idx", ctypes.c_int * 7), ("refresh", ctypes.c_int * 8)]


class _FramePkt(ctypes.Structure):
    _fields_ = [
        ("buf", ctypes.c_void_p),
        ("sz", ctypes.c_size_t),
        ("pts", ctypes.c_int64),
        ("duration", ctypes.c_ulong),
        ("flags", ctypes.c_uint32),
    ]


class AomPacket(ctypes.Structure):
    """aom_codec_cx_pkt_t (168 bytes); only the frame member is read."""

    _fields_ = [("kind", ctypes.c_int), ("frame", _FramePkt), ("_pad", ctypes.c_char * 116)]


for _s, _n in ((AomImage, 168), (Av1RefFrame, 176), (RefConfig, 88), (AomPacket, 168)):
    assert ctypes.sizeof(_s) == _n, _s  # the 3.6.0 layouts (x86-64)


@dataclass(frozen=True)
class Library:
    """A loaded libaom: the ctypes handle, its version and where it came from."""

    lib: ctypes.CDLL
    version: tuple[int, int, int]
    path: str

    @property
    def version_str(self) -> str:
        return ".".join(map(str, self.version))


def _setup(lib: ctypes.CDLL) -> None:
    vp = ctypes.c_void_p
    lib.aom_codec_version.restype = ctypes.c_int
    lib.aom_codec_av1_cx.restype = vp
    lib.aom_codec_av1_dx.restype = vp
    lib.aom_codec_enc_config_default.argtypes = [vp, vp, ctypes.c_uint]
    lib.aom_codec_enc_init_ver.argtypes = [vp, vp, vp, ctypes.c_long, ctypes.c_int]
    lib.aom_codec_enc_config_set.argtypes = [vp, vp]
    lib.aom_codec_dec_init_ver.argtypes = [vp, vp, vp, ctypes.c_long, ctypes.c_int]
    lib.aom_codec_encode.argtypes = [vp, vp, ctypes.c_int64, ctypes.c_ulong, ctypes.c_long]
    lib.aom_codec_get_cx_data.argtypes = [vp, ctypes.POINTER(vp)]
    lib.aom_codec_get_cx_data.restype = ctypes.POINTER(AomPacket)
    lib.aom_codec_decode.argtypes = [vp, ctypes.c_char_p, ctypes.c_size_t, vp]
    lib.aom_codec_get_frame.argtypes = [vp, ctypes.POINTER(vp)]
    lib.aom_codec_get_frame.restype = ctypes.POINTER(AomImage)
    lib.aom_codec_destroy.argtypes = [vp]
    lib.aom_codec_error.argtypes = [vp]
    lib.aom_codec_error.restype = ctypes.c_char_p
    lib.aom_codec_error_detail.argtypes = [vp]
    lib.aom_codec_error_detail.restype = ctypes.c_char_p
    lib.aom_img_wrap.argtypes = [
        ctypes.POINTER(AomImage),
        ctypes.c_int,
        ctypes.c_uint,
        ctypes.c_uint,
        ctypes.c_uint,
        vp,
    ]
    lib.aom_img_wrap.restype = ctypes.POINTER(AomImage)


@functools.cache
def library() -> Library:
    """Load libaom (cached); raise :class:`EgovidError` if it cannot be loaded."""
    tried = []
    for path in filter(None, (ctypes.util.find_library("aom"), "libaom.so.3")):
        try:
            lib = ctypes.CDLL(path)
            _setup(lib)
        except (OSError, AttributeError) as exc:
            tried.append(f"{path}: {exc}")
            continue
        v = lib.aom_codec_version()
        return Library(lib, ((v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF), path)
    raise EgovidError(
        "libaom (AV1 with the older drive as reference) could not be loaded: " + "; ".join(tried[-2:]),
        "install Debian's libaom3 (apt install libaom3)",
    )


def available() -> bool:
    """Whether libaom loads (the backend that needs it is offered only then)."""
    try:
        library()
    except EgovidError:
        return False
    return True


def _check(lib: Library, ctx, res: int, what: str) -> None:
    if res != 0:
        msg = lib.lib.aom_codec_error(ctx).decode() if ctx is not None else str(res)
        detail = lib.lib.aom_codec_error_detail(ctx) if ctx is not None else None
        raise EgovidError(f"libaom {lib.version_str} failed to {what}: {msg} {detail.decode() if detail else ''}")


def _planes(frame: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    flat = frame.reshape(-1)
    ys, cs = width * height, (width // 2) * (height // 2)
    return (
        flat[:ys].reshape(height, width),
        flat[ys : ys + cs].reshape(height // 2, width // 2),
        flat[ys + cs : ys + 2 * cs].reshape(height // 2, width // 2),
    )


def _read_image(img: AomImage, width: int, height: int) -> np.ndarray:
    """A copy of an 8-bit (or 16-bit holding 8-bit values) I420 aom_image_t as an (h*3/2, w) array."""
    out = np.empty((height * 3 // 2, width), np.uint8)
    wide = bool(img.fmt & AOM_IMG_FMT_HIGHBITDEPTH)
    for plane, dst in enumerate(_planes(out, width, height)):
        h, w = dst.shape
        stride = img.stride[plane]
        src = np.ctypeslib.as_array(img.planes[plane], shape=(h * stride,)).reshape(h, stride)
        dst[:] = src.view(np.uint16)[:, :w] if wide else src[:, :w]
    return out


class _Codec:
    def __init__(self, width: int, height: int) -> None:
        if width % _PAD or height % _PAD:
            raise ValueError("codec frames must be padded to a multiple of 8 pixels")
        self.lib = library()
        self.width, self.height = width, height
        self.ctx = ctypes.create_string_buffer(256)  # aom_codec_ctx_t is 56 bytes
        self._open = False

    def _wrap(self, frame: np.ndarray) -> AomImage:
        if frame.shape != (self.height * 3 // 2, self.width) or frame.dtype != np.uint8:
            raise ValueError(f"expected an I420 frame of {self.width}x{self.height}")
        img = AomImage()
        buf = np.ascontiguousarray(frame)
        self.lib.lib.aom_img_wrap(
            ctypes.byref(img), AOM_IMG_FMT_I420, self.width, self.height, 1, buf.ctypes.data_as(ctypes.c_void_p)
        )
        img._keep = buf  # keep the numpy buffer alive while libaom reads it
        return img

    def _control(self, ctrl: int, value) -> None:
        res = self.lib.lib.aom_codec_control(self.ctx, ctypes.c_int(ctrl), value)
        _check(self.lib, self.ctx, res, f"apply control {ctrl}")

    def set_reference(self, frame: np.ndarray, slot: int = BASELINE_SLOT) -> None:
        """Copy ``frame`` (padded I420) into reference slot ``slot`` (0-7)."""
        ref = Av1RefFrame()
        ref.idx, ref.use_external_ref = slot, 0
        img = self._wrap(frame)
        ref.img = img
        self._control(AV1_SET_REFERENCE, ctypes.byref(ref))

    def close(self) -> None:
        if self._open:
            self.lib.lib.aom_codec_destroy(self.ctx)
            self._open = False

    def __del__(self) -> None:  # pragma: no cover
        with contextlib.suppress(Exception):
            self.close()


def ref_config(refs: dict[int, int], refresh: tuple[int, ...], spare: int = 0) -> RefConfig:
    """The explicit reference structure of one frame: ``refs`` maps the reference types it may
    predict from (:data:`LAST`, ..., :data:`ALTREF`) to slots; ``refresh``: the slots its picture
    replaces. Unused reference types point at slot ``spare`` (libaom wants every index valid).

    libaom 3.6's realtime mode refreshes only slots that some reference type points at, used or
    not (``av1_get_refresh_frame_flags``): a refresh of any other slot is silently dropped. With
    ``spare`` 0 (the flat structure of the first libaom archives, kept for their bytes) a run's 2nd
    and 3rd frames are therefore not kept in slots 1 and 2, and its 3rd and 4th frames predict from
    the run's start (the grey frame of a joint run) as LAST; :class:`RunRefs` with
    ``keep_refresh`` and the layered structure pass the refreshed slot as ``spare``."""
    cfg = RefConfig()
    for t in range(7):
        cfg.reference[t] = int(t in refs)
        cfg.ref_idx[t] = refs.get(t, spare)
    for s in range(SLOTS):
        cfg.refresh[s] = int(s in refresh)
    return cfg


@dataclass(frozen=True)
class AomSettings:
    """libaom's settings for one encoder: fixed quantiser ``q`` (0-63), ``speed`` (cpu-used: 0-9 in
    good quality, 0-10 in realtime), ``realtime`` (AOM_USAGE_REALTIME instead of good quality),
    ``threads``, ``row_mt``, ``tile_columns`` (log2), ``fps``; ``fixed_costs``: the coefficient,
    mode and motion-vector cost tables are not updated within a frame (:data:`FIXED_COSTS` off;
    False: libaom's defaults, as the first archives); ``ref_mvs``: False turns off motion-field
    projection from the reference frames' motion vectors (``AV1E_SET_ENABLE_REF_FRAME_MVS`` 0;
    True: libaom's default, the control is not set); ``qm``: quantisation matrices
    (``AV1E_SET_ENABLE_QM`` 1; False: libaom's default, not set). All three are encoder choices
    the bitstream carries: the decoder needs nothing."""

    q: int
    speed: int
    realtime: bool = True
    threads: int = 1
    row_mt: bool = True
    tile_columns: int = 0
    fps: int = 30
    fixed_costs: bool = False
    ref_mvs: bool = True
    qm: bool = False


class AV1Encoder(_Codec):
    """libaom AV1 encoder with reference injection and an explicit reference structure (one
    packet per frame, no look-ahead)."""

    def __init__(self, width: int, height: int, settings: AomSettings) -> None:
        super().__init__(width, height)
        self.settings = settings
        L = self.lib.lib
        iface = L.aom_codec_av1_cx()
        usage = AOM_USAGE_REALTIME if settings.realtime else AOM_USAGE_GOOD_QUALITY
        cfg = ctypes.create_string_buffer(_CFG_SIZE + 256)
        _check(self.lib, None, L.aom_codec_enc_config_default(iface, cfg, usage), "read the default configuration")

        self._cfg = cfg
        self._q = settings.q

        def put(name: str, value: int) -> None:
            ctypes.c_uint.from_buffer(cfg, _CFG[name]).value = value

        for name, value in (
            ("g_usage", usage),
            ("g_threads", settings.threads),
            ("g_w", width),
            ("g_h", height),
            ("g_timebase_num", 1),
            ("g_timebase_den", settings.fps),
            ("g_error_resilient", 0),
            ("g_pass", 0),
            ("g_lag_in_frames", 0),
            ("rc_dropframe_thresh", 0),
            ("rc_resize_mode", 0),
            ("rc_superres_mode", 0),
            ("rc_end_usage", AOM_Q),
            ("rc_min_quantizer", settings.q),
            ("rc_max_quantizer", settings.q),
            ("kf_mode", AOM_KF_DISABLED),
            ("kf_min_dist", 0),
            ("kf_max_dist", 1 << 30),
        ):
            put(name, value)
        abi = encoder_abi(self.lib)
        _check(self.lib, self.ctx, L.aom_codec_enc_init_ver(self.ctx, iface, cfg, 0, abi), "start the AV1 encoder")
        self._open = True
        controls = [
            (AOME_SET_CPUUSED, settings.speed),
            (AOME_SET_CQ_LEVEL, settings.q),
            (AOME_SET_ENABLEAUTOALTREF, 0),
            (AOME_SET_STATIC_THRESHOLD, 0),
            (AV1E_SET_ROW_MT, int(settings.row_mt)),
            (AV1E_SET_TILE_COLUMNS, settings.tile_columns),
            (AV1E_SET_AQ_MODE, 0),
            (AV1E_SET_DELTAQ_MODE, 0),
            (AV1E_SET_ENABLE_TPL_MODEL, 0),
            (AV1E_SET_ENABLE_KEYFRAME_FILTERING, 0),
        ]
        if settings.fixed_costs:
            controls += [(c, COST_UPD_OFF) for c in FIXED_COSTS]
        if not settings.ref_mvs:
            controls.append((AV1E_SET_ENABLE_REF_FRAME_MVS, 0))
        if settings.qm:
            controls.append((AV1E_SET_ENABLE_QM, 1))
        for ctrl, value in controls:
            self._control(ctrl, ctypes.c_int(value))
        self._pts = 0

    def encode(
        self,
        frame: np.ndarray,
        refs: dict[int, int] | None,
        refresh: tuple[int, ...] = (),
        baseline: np.ndarray | None = None,
        q: int | None = None,
        spare: int = 0,
    ) -> bytes:
        """Encode one padded I420 frame. ``refs`` None: a keyframe (refreshes every slot); else
        the reference types -> slots it may predict from and the slots it refreshes
        (:func:`ref_config`). ``baseline`` is first copied into :data:`BASELINE_SLOT`. ``q``: the
        frame's quantiser (0-63), kept for the frames after it (None: the one in force; the
        encoder's configuration is changed only when it differs); ``spare``: the slot unused
        reference types point at (:func:`ref_config`). Returns the frame's packet (a temporal
        unit)."""
        if q is not None and q != self._q:
            self.set_quantizer(q)
        if refs is None:
            if baseline is not None:
                raise ValueError("no reference injection on a keyframe")
            flags = AOM_EFLAG_FORCE_KF
        else:
            if self._pts == 0:
                raise ValueError("the first frame must be a keyframe")
            if baseline is not None:
                self.set_reference(baseline, BASELINE_SLOT)
            cfg = ref_config(refs, refresh, spare)
            self._control(AV1E_SET_SVC_REF_FRAME_CONFIG, ctypes.byref(cfg))
            flags = 0
        return self._encode(frame, flags)

    def set_quantizer(self, q: int) -> None:
        """Code the next frames at fixed quantiser ``q`` (0-63): the configuration's minimum and
        maximum quantiser set to it (``aom_codec_enc_config_set``; libaom 3.6 has no per-frame
        quantiser control)."""
        if not 0 <= q <= 63:
            raise ValueError(f"quantiser {q} is outside 0-63")
        for name in ("rc_min_quantizer", "rc_max_quantizer"):
            ctypes.c_uint.from_buffer(self._cfg, _CFG[name]).value = q
        _check(self.lib, self.ctx, self.lib.lib.aom_codec_enc_config_set(self.ctx, self._cfg), "set the quantiser")
        self._control(AOME_SET_CQ_LEVEL, ctypes.c_int(q))
        self._q = q

    def _encode(self, frame: np.ndarray, flags: int) -> bytes:
        L = self.lib.lib
        img = self._wrap(frame)
        _check(self.lib, self.ctx, L.aom_codec_encode(self.ctx, ctypes.byref(img), self._pts, 1, flags), "encode")
        self._pts += 1
        out = []
        it = ctypes.c_void_p(0)
        while True:
            pkt = L.aom_codec_get_cx_data(self.ctx, ctypes.byref(it))
            if not pkt:
                break
            if pkt.contents.kind == AOM_CODEC_CX_FRAME_PKT:
                f = pkt.contents.frame
                out.append(ctypes.string_at(f.buf, f.sz))
        if len(out) != 1:
            raise EgovidError(f"libaom returned {len(out)} packets for one frame (expected 1)")
        return out[0]

    def reconstruction(self) -> np.ndarray:
        """The encoder's picture of the last frame (padded I420): what a decoder must output."""
        img = AomImage()
        self._control(AV1_GET_NEW_FRAME_IMAGE, ctypes.byref(img))
        return _read_image(img, self.width, self.height)


class AV1Decoder(_Codec):
    """libaom AV1 decoder (8-bit path) that accepts the same injections."""

    def __init__(self, width: int, height: int, threads: int = 1) -> None:
        super().__init__(width, height)
        L = self.lib.lib
        cfg = (ctypes.c_uint * 4)(threads, width, height, 1)  # threads, w, h, allow_lowbitdepth
        abi = decoder_abi(self.lib)
        _check(self.lib, self.ctx, L.aom_codec_dec_init_ver(self.ctx, L.aom_codec_av1_dx(), cfg, 0, abi), "start")
        self._open = True
        self._n = 0

    def decode(self, packet: bytes, baseline: np.ndarray | None = None) -> np.ndarray:
        """Decode one packet after copying ``baseline`` into :data:`BASELINE_SLOT` (as the encoder
        did); returns the padded I420 picture."""
        L = self.lib.lib
        if baseline is not None:
            if self._n == 0:
                raise ValueError("no reference injection before the keyframe")
            self.set_reference(baseline, BASELINE_SLOT)
        _check(self.lib, self.ctx, L.aom_codec_decode(self.ctx, packet, len(packet), None), "decode a frame")
        self._n += 1
        it = ctypes.c_void_p(0)
        img = L.aom_codec_get_frame(self.ctx, ctypes.byref(it))
        if not img:
            raise EgovidError("libaom decoded no picture from a packet", "the bitstream is damaged")
        return _read_image(img.contents, self.width, self.height)


def _probe_abi(lib: Library, known: int | None, init) -> int:
    tries = ([known] if known else []) + [v for v in range(5, 80) if v != known]
    for abi in tries:
        ctx = ctypes.create_string_buffer(256)
        res = init(ctx, abi)
        if res == 0:
            lib.lib.aom_codec_destroy(ctx)
            return abi
        if res != AOM_CODEC_ABI_MISMATCH:
            break
    raise EgovidError(f"no AV1 ABI version works with libaom {lib.version_str} at {lib.path}", "install libaom 3")


@functools.cache
def encoder_abi(lib: Library) -> int:
    """The encoder ABI version of ``lib``: from its version, confirmed by probing."""
    L = lib.lib
    iface = L.aom_codec_av1_cx()
    cfg = ctypes.create_string_buffer(_CFG_SIZE + 256)
    L.aom_codec_enc_config_default(iface, cfg, AOM_USAGE_REALTIME)
    ctypes.c_uint.from_buffer(cfg, _CFG["g_w"]).value = 64
    ctypes.c_uint.from_buffer(cfg, _CFG["g_h"]).value = 64
    return _probe_abi(
        lib, _ENC_ABI.get(lib.version[0]), lambda ctx, abi: L.aom_codec_enc_init_ver(ctx, iface, cfg, 0, abi)
    )


@functools.cache
def decoder_abi(lib: Library) -> int:
    """The decoder ABI version of ``lib``: from its version, confirmed by probing."""
    L = lib.lib
    cfg = (ctypes.c_uint * 4)(1, 64, 64, 1)
    return _probe_abi(
        lib,
        _DEC_ABI.get(lib.version[0]),
        lambda ctx, abi: L.aom_codec_dec_init_ver(ctx, L.aom_codec_av1_dx(), cfg, 0, abi),
    )


def padded_size(width: int, height: int) -> tuple[int, int]:
    """Frame size rounded up to AV1's reference alignment (8 pixels)."""
    return (width + _PAD - 1) // _PAD * _PAD, (height + _PAD - 1) // _PAD * _PAD


def layer_of(j: int, period: int) -> int:
    """The temporal layer (0 = base) of the ``j``-th frame of a random-access run: with period 4,
    frames 0 mod 4 are the base layer, 2 mod 4 layer 1 and odd frames layer 2; with period 2 odd
    frames are layer 1; with period 1 every frame is the base layer."""
    if period <= 1 or j % period == 0:
        return 0
    return 1 if period == 4 and j % 4 == 2 else period.bit_length() - 1


class RunRefs:
    """The reference structure of one random-access run, frame by frame in coding (= display)
    order, as the encoder is told it (the decoder reads it from the bitstream). Its one copy:
    :func:`run_structure` and :mod:`egovid.dashcam.codec.aom_segment` both follow it.

    Flat (``period`` 1): each frame predicts from its three previous frames (LAST, LAST2, LAST3
    in slots 0-2, the oldest refreshed) and, where it has one, the baseline (GOLDEN; LAST for a
    joint run's first frame, which has no previous frame). Temporal layers (``period`` 2 or 4,
    :func:`layer_of`): a base-layer frame predicts from the run's previous base-layer frame, an
    upper-layer frame from the nearest frames of the layers below it before it (LAST the newer,
    ALTREF the older), every frame also from the baseline (GOLDEN); a layer's newest frame is held
    in slot ``layer`` (0 or 1), frames of the top layer refresh :data:`SCRATCH_SLOT`, which no
    frame reads. Low delay either way: no frame is coded out of display order. ``joint``: the run
    starts from the baseline (after two undisplayed grey frames, which leave slot 0 grey) rather
    than from a keyframe. ``keep_refresh``: every refresh is kept in libaom's realtime mode
    (:meth:`spare`; always so in layers); without it a flat run is coded as by the first libaom
    archives, byte for byte."""

    def __init__(self, joint: bool, period: int = 1, keep_refresh: bool = False) -> None:
        if period not in LAYER_PERIODS:
            raise ValueError(f"layer period {period} is not one of {LAYER_PERIODS}")
        self.joint, self.period, self.keep_refresh = joint, period, keep_refresh or period > 1
        self.recent: list[int] = [] if joint else [0]  # flat: after a keyframe every slot holds it
        self.held: dict[int, tuple[int, int]] = {} if joint else {0: (0, 0)}  # layer -> (frame, slot)
        self.j = 0 if joint else 1  # the run's next frame (a standalone run's frame 0 is its keyframe)
        self.top = layer_of(1, period)

    def next(self, with_baseline: bool) -> tuple[dict[int, int], tuple[int, ...], int]:
        """(references type -> slot, refreshed slots, temporal layer) of the run's next frame."""
        j, self.j = self.j, self.j + 1
        if self.period == 1:
            return (*self._flat(with_baseline), 0)
        layer = layer_of(j, self.period)
        below = sorted((f for lay, f in self.held.items() if lay < layer or lay == layer == 0), reverse=True)
        refs = dict(zip((LAST, ALTREF), (slot for _, slot in below), strict=False))
        if with_baseline:
            refs = {**refs, GOLDEN: BASELINE_SLOT} if refs else {LAST: BASELINE_SLOT}
        elif not refs:
            refs = {LAST: 0}  # a joint run's first frame without its baseline: from the grey frame
        if layer == self.top and layer > 0:
            return refs, (SCRATCH_SLOT,), layer
        self.held[layer] = (j, layer)
        return refs, (layer,), layer

    def _flat(self, with_baseline: bool) -> tuple[dict[int, int], tuple[int, ...]]:
        refs = dict(zip((LAST, LAST2, LAST3), self.recent, strict=False))
        if with_baseline:
            refs = {**refs, GOLDEN: BASELINE_SLOT} if refs else {LAST: BASELINE_SLOT}
        elif not refs:
            refs = {LAST: 0}  # a joint run's first frame without its baseline: from the grey frame
        free = [s for s in (0, 1, 2) if s not in self.recent]
        slot = free[0] if free else self.recent[-1]
        self.recent = [slot] + [s for s in self.recent if s != slot]
        return refs, (slot,)

    def spare(self, refresh: tuple[int, ...]) -> int:
        """The slot a frame's unused reference types point at (:func:`ref_config`): the refreshed
        slot with ``keep_refresh`` (else libaom's realtime mode would not refresh it), 0 without
        (as the first libaom archives were coded)."""
        return refresh[0] if self.keep_refresh and refresh else 0

    def q_offset(self, layer: int, top_dq: int) -> int:
        """What a frame of ``layer`` adds to the segment's quantiser: ``top_dq`` on the top layer,
        in equal steps from 0 on the base (period 4, ``top_dq`` 12: 0, +6, +12)."""
        return top_dq * layer // self.top if self.top else 0


def run_structure(
    n: int, joint: bool, with_baseline: list[bool] | None = None, period: int = 1
) -> list[tuple[str, dict, tuple]]:
    """The frames of one random-access run of ``n`` frames as libaom codes them: (role, references
    type -> slot, refreshed slots) per packet, in coding (= display) order (:class:`RunRefs`).

    Standalone: ``key``, then ``p`` frames. Joint: two undisplayed grey frames (``dummy``: a
    keyframe, then a frame that refreshes slot 0 — libaom's good-quality mode uses no reference on
    the first frame after a keyframe), ``ra``: the run's first frame from the baseline alone (LAST
    -> the baseline's slot), then ``p`` frames from earlier frames and the baseline (GOLDEN). A
    frame whose ``with_baseline`` is False (no baseline for it) does not refer to the baseline's
    slot."""
    out: list[tuple[str, dict, tuple]] = []
    if joint:
        out += [("dummy", {}, tuple(range(SLOTS))), ("dummy", {LAST: 0}, (0,))]
    else:
        out.append(("key", {}, tuple(range(SLOTS))))
    run = RunRefs(joint, period)
    for k in range(0 if joint else 1, n):
        refs, refresh, _ = run.next(joint and (with_baseline is None or with_baseline[k]))
        out.append(("ra" if joint and k == 0 else "p", refs, refresh))
    return out


@functools.cache
def self_test() -> str:
    """Encode-inject-decode round trips on a small clip, in both modes; raise :class:`EgovidError`
    on failure. Checks that the decoder with the same injections reproduces the encoder's pictures
    bit for bit, that the injected reference is used (decoding without it gives other pictures)
    and that it pays (fewer bytes than the same frames without it). Returns a one-line
    description of the library."""
    lib = library()
    w, h = 32, 32
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (h * 3 // 2 + 16, w + 16), dtype=np.uint8)
    goldens = [np.ascontiguousarray(base[(k + 1) % 3 : (k + 1) % 3 + h * 3 // 2, k + 1 : k + 1 + w]) for k in range(4)]
    frames = [np.roll(g, 1, axis=1) for g in goldens]  # cheap only with the baseline
    grey = np.full_like(frames[0], 128)
    report = []
    try:
        for st in (AomSettings(q=20, speed=9, realtime=True), AomSettings(q=20, speed=6, realtime=False)):
            sizes, ok, used = {}, True, False
            for joint in (True, False):
                enc = AV1Encoder(w, h, st)
                coded = []
                plan = run_structure(len(frames), joint)
                pics = iter(frames)
                for role, refs, refresh in plan:
                    frame = grey if role == "dummy" else next(pics)
                    g = goldens[len(coded) - 2] if role in ("ra", "p") and joint else None
                    if role in ("key", "dummy") and not refs:
                        pkt = enc.encode(frame, None)
                    else:
                        pkt = enc.encode(frame, refs, refresh, g)
                    coded.append((pkt, g, enc.reconstruction()))
                enc.close()
                sizes[joint] = sum(len(p) for p, _, _ in coded)
                dec = AV1Decoder(w, h)
                ok = ok and all(np.array_equal(dec.decode(p, g), r) for p, g, r in coded)
                dec.close()
                if joint:
                    blind = AV1Decoder(w, h)
                    used = any(not np.array_equal(blind.decode(p), r) for p, _, r in coded)
                    blind.close()
            report.append((st.realtime, ok, used, sizes[True], sizes[False]))
    except EgovidError:
        raise
    except Exception as exc:  # pragma: no cover - ctypes failures
        raise EgovidError(
            f"libaom {lib.version_str} at {lib.path} crashed in the self-test: {exc}", "reinstall libaom3"
        ) from None
    for realtime, ok, used, joint_bytes, plain_bytes in report:
        if not ok or not used or joint_bytes >= plain_bytes:
            mode = "realtime" if realtime else "good-quality"
            raise EgovidError(
                f"libaom {lib.version_str} at {lib.path} failed the reference-injection self-test in {mode} mode "
                f"(bit-exact {ok}, injection used {used}, {joint_bytes} vs {plain_bytes} bytes)",
                "reinstall libaom3 (egovid binds libaom 3.x)",
            )
    return f"libaom {lib.version_str} ({lib.path}), encoder ABI {encoder_abi(lib)}, decoder ABI {decoder_abi(lib)}"
