"""VP9 through libvpx with an externally supplied reference picture (thesis §14.2).

The thesis stored a new drive as the 3D-HEVC "second view" of an older drive's aligned frames
(the *baseline*), which is never re-encoded: both encoder and decoder rebuild it from the archive
and use it as a reference. VP9 gets the same effect: before every frame after the keyframe, the
baseline frame is loaded into the GOLDEN reference buffer of both the encoder and the decoder
(``VP8_SET_REFERENCE``), and the encoder is told never to overwrite GOLDEN (or ALTREF); LAST keeps
the previous frame, so each block can predict from the previous frame or from the older drive.

Bindings are ctypes on the libvpx bundled in the PyAV wheel (1.16) or the system's (Debian 1.12),
whichever loads (``EGOVID_LIBVPX`` forces a path). The encoder's ABI version is looked up from the
library version and confirmed by probing; a self-test (encode with injection, decode with
injection, compare with the encoder's own reconstruction, and check that decoding *without* the
injection differs) runs once per process before any archive is written.

Settings that keep the injected reference intact and the stream reproducible: no look-ahead
(``g_lag_in_frames = 0``), no alt-ref, no frame dropping, no resizing, one thread, a fixed
quantiser (``rc_min_quantizer = rc_max_quantizer``), a single keyframe, and no injection on the
keyframe (after a keyframe the three reference buffers share one memory block). Frames are I420
padded to a multiple of 8 pixels by edge replication.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import glob
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from egovid.core.errors import EgovidError
from egovid.dashcam.codec.settings import EncoderSettings

# Enumerations and flags (vpx_encoder.h, vp8.h, vp8cx.h; stable across 1.12-1.16).
VPX_IMG_FMT_I420 = 0x102
VP8_SET_REFERENCE = 1
VP8_COPY_REFERENCE = 2
VP8_LAST_FRAME, VP8_GOLD_FRAME, VP8_ALTR_FRAME = 1, 2, 4
VP8E_SET_CPUUSED = 13
VP8E_SET_ENABLEAUTOALTREF = 14
VP8E_SET_NOISE_SENSITIVITY = 15
VP8E_SET_STATIC_THRESHOLD = 17
VP9E_SET_TILE_COLUMNS = 33
VP9E_SET_AQ_MODE = 36
VP9E_SET_ROW_MT = 55
VP8_EFLAG_NO_REF_LAST = 1 << 16
VP8_EFLAG_NO_UPD_LAST = 1 << 18
VP8_EFLAG_NO_REF_ARF = 1 << 21
VP8_EFLAG_NO_UPD_GF = 1 << 22
VP8_EFLAG_NO_UPD_ARF = 1 << 23
VPX_EFLAG_FORCE_KF = 1
VPX_DL_GOOD_QUALITY = 1000000
VPX_DL_REALTIME = 1
VPX_Q = 3
VPX_KF_DISABLED = 0
VPX_CODEC_CX_FRAME_PKT = 0
VPX_CODEC_ABI_MISMATCH = 3

# Byte offsets in vpx_codec_enc_cfg_t (checked against the 1.12 headers; the prefix has not
# changed since — the self-test would fail otherwise).
_CFG = {
    "g_threads": 4,
    "g_w": 12,
    "g_h": 16,
    "g_timebase_num": 28,
    "g_timebase_den": 32,
    "g_error_resilient": 36,
    "g_pass": 40,
    "g_lag_in_frames": 44,
    "rc_dropframe_thresh": 48,
    "rc_resize_allowed": 52,
    "rc_end_usage": 72,
    "rc_target_bitrate": 112,
    "rc_min_quantizer": 116,
    "rc_max_quantizer": 120,
    "kf_mode": 160,
    "kf_min_dist": 164,
    "kf_max_dist": 168,
}
#: Known encoder ABI versions by (major, minor); the decoder's has been 12 throughout.
_ENC_ABI = {(1, 12): 25, (1, 13): 27, (1, 14): 34, (1, 15): 37, (1, 16): 39}
_DEC_ABI = 12
_PAD = 8


class VpxImage(ctypes.Structure):
    _fields_ = [
        ("fmt", ctypes.c_int),
        ("cs", ctypes.c_int),
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
        ("planes", ctypes.POINTER(ctypes.c_ubyte) * 4),
        ("stride", ctypes.c_int * 4),
        ("bps", ctypes.c_int),
        ("user_priv", ctypes.c_void_p),
        ("img_data", ctypes.c_void_p),
        ("img_data_owner", ctypes.c_int),
        ("self_allocd", ctypes.c_int),
        ("fb_priv", ctypes.c_void_p),
    ]


class VpxRefFrame(ctypes.Structure):
    _fields_ = [("frame_type", ctypes.c_int), ("img", VpxImage)]


class _FramePkt(ctypes.Structure):
    _fields_ = [
        ("buf", ctypes.c_void_p),
        ("sz", ctypes.c_size_t),
        ("pts", ctypes.c_int64),
        ("duration", ctypes.c_ulong),
        ("flags", ctypes.c_uint32),
    ]


class VpxPacket(ctypes.Structure):
    _fields_ = [("kind", ctypes.c_int), ("frame", _FramePkt)]


@dataclass(frozen=True)
class Library:
    """A loaded libvpx: the ctypes handle, its version and where it came from."""

    lib: ctypes.CDLL
    version: tuple[int, int, int]
    path: str

    @property
    def version_str(self) -> str:
        return ".".join(map(str, self.version))


def _candidates() -> list[str]:
    forced = os.environ.get("EGOVID_LIBVPX")
    if forced:
        return [forced]
    out = []
    try:
        import av

        base = Path(av.__file__).resolve().parent.parent
        out += sorted(glob.glob(str(base / "av.libs" / "libvpx*.so*")))
    except Exception:  # pragma: no cover
        pass
    found = ctypes.util.find_library("vpx")
    if found:
        out.append(found)
    out += ["libvpx.so.9", "libvpx.so.8", "libvpx.so.7", "libvpx.so"]
    return out


def _setup(lib: ctypes.CDLL) -> None:
    vp = ctypes.c_void_p
    lib.vpx_codec_version.restype = ctypes.c_int
    lib.vpx_codec_vp9_cx.restype = vp
    lib.vpx_codec_vp9_dx.restype = vp
    lib.vpx_codec_enc_config_default.argtypes = [vp, vp, ctypes.c_uint]
    lib.vpx_codec_enc_init_ver.argtypes = [vp, vp, vp, ctypes.c_long, ctypes.c_int]
    lib.vpx_codec_dec_init_ver.argtypes = [vp, vp, vp, ctypes.c_long, ctypes.c_int]
    lib.vpx_codec_encode.argtypes = [vp, vp, ctypes.c_int64, ctypes.c_ulong, ctypes.c_long, ctypes.c_ulong]
    lib.vpx_codec_enc_config_set.argtypes = [vp, vp]
    lib.vpx_codec_get_cx_data.argtypes = [vp, ctypes.POINTER(vp)]
    lib.vpx_codec_get_cx_data.restype = ctypes.POINTER(VpxPacket)
    lib.vpx_codec_decode.argtypes = [vp, ctypes.c_char_p, ctypes.c_uint, vp, ctypes.c_long]
    lib.vpx_codec_get_frame.argtypes = [vp, ctypes.POINTER(vp)]
    lib.vpx_codec_get_frame.restype = ctypes.POINTER(VpxImage)
    lib.vpx_codec_destroy.argtypes = [vp]
    lib.vpx_codec_error.argtypes = [vp]
    lib.vpx_codec_error.restype = ctypes.c_char_p
    lib.vpx_codec_error_detail.argtypes = [vp]
    lib.vpx_codec_error_detail.restype = ctypes.c_char_p
    lib.vpx_img_wrap.argtypes = [
        ctypes.POINTER(VpxImage),
        ctypes.c_int,
        ctypes.c_uint,
        ctypes.c_uint,
        ctypes.c_uint,
        vp,
    ]
    lib.vpx_img_wrap.restype = ctypes.POINTER(VpxImage)


@functools.cache
def library() -> Library:
    """Load libvpx (cached); raise :class:`EgovidError` if none can be loaded."""
    tried = []
    for path in _candidates():
        try:
            lib = ctypes.CDLL(path)
            _setup(lib)
        except (OSError, AttributeError) as exc:
            tried.append(f"{path}: {exc}")
            continue
        v = lib.vpx_codec_version()
        return Library(lib, ((v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF), path)
    raise EgovidError(
        "libvpx (VP9) could not be loaded: " + "; ".join(tried[-3:]),
        "reinstall egovid (PyAV bundles libvpx) or install Debian's libvpx, or set EGOVID_LIBVPX",
    )


def _check(lib: Library, ctx, res: int, what: str) -> None:
    if res != 0:
        detail = lib.lib.vpx_codec_error_detail(ctx) if ctx is not None else None
        msg = lib.lib.vpx_codec_error(ctx).decode() if ctx is not None else str(res)
        raise EgovidError(f"libvpx {lib.version_str} failed to {what}: {msg} {detail.decode() if detail else ''}")


def padded_size(width: int, height: int) -> tuple[int, int]:
    """Frame size rounded up to the codec's alignment (8 pixels)."""
    return (width + _PAD - 1) // _PAD * _PAD, (height + _PAD - 1) // _PAD * _PAD


def pad_i420(frame: np.ndarray, width: int, height: int) -> np.ndarray:
    """Edge-pad an I420 image ((h*3/2, w) uint8) to ``width`` x ``height``."""
    h = frame.shape[0] * 2 // 3
    w = frame.shape[1]
    if (w, h) == (width, height):
        return np.ascontiguousarray(frame)
    import cv2

    out = np.empty((height * 3 // 2, width), np.uint8)
    dst = split_i420(out, width, height)
    for src, d in zip(split_i420(frame, w, h), dst, strict=True):
        cv2.copyMakeBorder(src, 0, d.shape[0] - src.shape[0], 0, d.shape[1] - src.shape[1], cv2.BORDER_REPLICATE, d)
    return out


def crop_i420(frame: np.ndarray, width: int, height: int) -> np.ndarray:
    """Cut a padded I420 image back to ``width`` x ``height``."""
    h = frame.shape[0] * 2 // 3
    w = frame.shape[1]
    if (w, h) == (width, height):
        return frame
    y, u, v = split_i420(frame, w, h)
    return join_i420(y[:height, :width], u[: height // 2, : width // 2], v[: height // 2, : width // 2])


def split_i420(frame: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Views of the Y, U, V planes of an (h*3/2, w) I420 array."""
    flat = frame.reshape(-1)
    ys = width * height
    cs = (width // 2) * (height // 2)
    return (
        flat[:ys].reshape(height, width),
        flat[ys : ys + cs].reshape(height // 2, width // 2),
        flat[ys + cs : ys + 2 * cs].reshape(height // 2, width // 2),
    )


def join_i420(y: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Pack planes into one (h*3/2, w) I420 array."""
    h, w = y.shape
    out = np.empty((h * 3 // 2, w), np.uint8)
    flat = out.reshape(-1)
    flat[: h * w] = y.ravel()
    flat[h * w : h * w + u.size] = u.ravel()
    flat[h * w + u.size :] = v.ravel()
    return out


class _Codec:
    def __init__(self, width: int, height: int) -> None:
        if width % _PAD or height % _PAD:
            raise ValueError("codec frames must be padded to a multiple of 8 pixels")
        self.lib = library()
        self.width, self.height = width, height
        self.ctx = ctypes.create_string_buffer(512)
        self._img = VpxImage()
        self._open = False

    def _wrap(self, frame: np.ndarray) -> VpxImage:
        if frame.shape != (self.height * 3 // 2, self.width) or frame.dtype != np.uint8:
            raise ValueError(f"expected an I420 frame of {self.width}x{self.height}")
        img = VpxImage()
        buf = np.ascontiguousarray(frame)
        self.lib.lib.vpx_img_wrap(
            ctypes.byref(img), VPX_IMG_FMT_I420, self.width, self.height, 1, buf.ctypes.data_as(ctypes.c_void_p)
        )
        img._keep = buf  # keep the numpy buffer alive while libvpx reads it
        return img

    def _ref(self, frame: np.ndarray, kind: int = VP8_GOLD_FRAME) -> VpxRefFrame:
        ref = VpxRefFrame()
        ref.frame_type = kind
        img = self._wrap(frame)
        ref.img = img
        ref._keep = img._keep
        return ref

    def _control(self, ctrl: int, value) -> None:
        res = self.lib.lib.vpx_codec_control_(self.ctx, ctypes.c_int(ctrl), value)
        _check(self.lib, self.ctx, res, f"apply control {ctrl}")

    def set_reference(self, frame: np.ndarray, kind: int = VP8_GOLD_FRAME) -> None:
        """Load ``frame`` (padded I420) into a reference buffer (GOLDEN by default)."""
        ref = self._ref(frame, kind)
        self._control(VP8_SET_REFERENCE, ctypes.byref(ref))

    def copy_reference(self, kind: int = VP8_LAST_FRAME) -> np.ndarray:
        """A copy of a reference buffer (LAST = the latest reconstruction) as padded I420."""
        out = np.zeros((self.height * 3 // 2, self.width), np.uint8)
        ref = self._ref(out, kind)
        self._control(VP8_COPY_REFERENCE, ctypes.byref(ref))
        return out

    def close(self) -> None:
        if self._open:
            self.lib.lib.vpx_codec_destroy(self.ctx)
            self._open = False

    def __del__(self) -> None:  # pragma: no cover
        with contextlib.suppress(Exception):
            self.close()


class VP9Encoder(_Codec):
    """VP9 encoder with GOLDEN-frame injection (one packet per frame, no look-ahead)."""

    def __init__(self, width: int, height: int, settings: EncoderSettings) -> None:
        super().__init__(width, height)
        self.settings = settings
        L = self.lib.lib
        iface = L.vpx_codec_vp9_cx()
        cfg = ctypes.create_string_buffer(8192)
        _check(self.lib, None, L.vpx_codec_enc_config_default(iface, cfg, 0), "read the default configuration")
        self._cfg = cfg

        def put(name: str, value: int) -> None:
            ctypes.c_uint.from_buffer(cfg, _CFG[name]).value = value

        put("g_threads", settings.threads)
        put("g_w", width)
        put("g_h", height)
        put("g_timebase_num", 1)
        put("g_timebase_den", settings.fps)
        put("g_error_resilient", 0)
        put("g_pass", 0)
        put("g_lag_in_frames", 0)
        put("rc_dropframe_thresh", 0)
        put("rc_resize_allowed", 0)
        put("rc_end_usage", VPX_Q)
        put("rc_min_quantizer", settings.q)
        put("rc_max_quantizer", settings.q)
        put("kf_mode", VPX_KF_DISABLED)
        put("kf_min_dist", 0)
        put("kf_max_dist", 1 << 30)
        abi = encoder_abi(self.lib)
        _check(self.lib, self.ctx, L.vpx_codec_enc_init_ver(self.ctx, iface, cfg, 0, abi), "start the VP9 encoder")
        self._open = True
        for ctrl, value in (
            (VP8E_SET_CPUUSED, settings.speed),
            (VP8E_SET_ENABLEAUTOALTREF, 0),
            (VP8E_SET_STATIC_THRESHOLD, 0),
            (VP9E_SET_TILE_COLUMNS, settings.tile_columns),
            (VP9E_SET_AQ_MODE, 0),
            (VP9E_SET_ROW_MT, int(settings.row_mt)),
        ):
            self._control(ctrl, ctypes.c_int(value))
        self._pts = 0
        self._q = settings.q
        self._recon_slot = VP8_LAST_FRAME

    def _set_q(self, q: int) -> None:
        if q != self._q:
            for name in ("rc_min_quantizer", "rc_max_quantizer"):
                ctypes.c_uint.from_buffer(self._cfg, _CFG[name]).value = q
            res = self.lib.lib.vpx_codec_enc_config_set(self.ctx, self._cfg)
            _check(self.lib, self.ctx, res, "change the quantiser")
            self._q = q

    def encode_structured(
        self,
        frame: np.ndarray,
        role: str,
        golden: np.ndarray | None = None,
        last: np.ndarray | None = None,
        q: int | None = None,
    ) -> bytes:
        """Encode one padded I420 frame of a hierarchical structure (see :mod:`codec`).

        ``role``: ``"key"``; ``"ra"`` (a random-access point: right after a keyframe, predicted
        from GOLDEN = ``golden`` alone, refreshes LAST); ``"p"`` (from LAST, refreshes LAST; with
        ``golden`` only at low delay — right after a keyframe every reference slot shares one
        buffer, so the load shows in LAST too); ``"anchor"`` (LAST is first loaded with ``last``,
        the previous anchor; the result refreshes ALTREF only); ``"between"`` (from LAST = the
        previous frame and ALTREF = the anchor ahead; refreshes LAST); ``"hold"`` (refreshes no
        reference: it only moves libvpx's frames-since-golden counter off 0, see
        :data:`codec.START_BASELINE_HELD`; its picture is in no slot). ``golden`` is injected into
        GOLDEN, which is never refreshed. The decoder must repeat the same loads in the same order
        (:meth:`VP9Decoder.decode`)."""
        if role == "key":
            flags = VPX_EFLAG_FORCE_KF
        elif role == "ra":
            if golden is None:
                raise ValueError("a random-access frame needs the baseline in GOLDEN")
            flags = VP8_EFLAG_NO_UPD_GF | VP8_EFLAG_NO_UPD_ARF | VP8_EFLAG_NO_REF_LAST | VP8_EFLAG_NO_REF_ARF
        elif role == "p":
            flags = VP8_EFLAG_NO_UPD_GF | VP8_EFLAG_NO_UPD_ARF | VP8_EFLAG_NO_REF_ARF
        elif role == "anchor":
            flags = VP8_EFLAG_NO_UPD_GF | VP8_EFLAG_NO_UPD_LAST | VP8_EFLAG_NO_REF_ARF
        elif role == "between":
            flags = VP8_EFLAG_NO_UPD_GF | VP8_EFLAG_NO_UPD_ARF
        elif role == "hold":
            flags = VP8_EFLAG_NO_UPD_LAST | VP8_EFLAG_NO_UPD_GF | VP8_EFLAG_NO_UPD_ARF
        else:
            raise ValueError(f"unknown frame role {role!r}")
        no_golden, no_last = ("key", "hold"), ("key", "hold", "ra", "p")
        if (role in no_golden and golden is not None) or (role in no_last and last is not None):
            raise ValueError(f"no such reference load on a {role!r} frame")
        if last is not None:
            self.set_reference(last, VP8_LAST_FRAME)
        if golden is not None:
            self.set_reference(golden, VP8_GOLD_FRAME)
        self._set_q(self.settings.q if q is None else q)
        self._recon_slot = VP8_ALTR_FRAME if role == "anchor" else VP8_LAST_FRAME
        start_speed = self.settings.start_speed
        if role != "ra" or start_speed in (0, self.settings.speed):
            return self._encode(frame, flags)
        self._control(VP8E_SET_CPUUSED, ctypes.c_int(start_speed))
        try:
            return self._encode(frame, flags)
        finally:
            self._control(VP8E_SET_CPUUSED, ctypes.c_int(self.settings.speed))

    def encode(self, frame: np.ndarray, golden: np.ndarray | None = None) -> bytes:
        """Encode one padded I420 frame; ``golden`` (padded I420) is injected before it. The first
        frame is the keyframe and must come without ``golden``. Returns the frame's packet.

        This is the low-delay structure; :meth:`encode_structured` codes frames out of order.
        (Right after the keyframe every reference slot points to the keyframe's buffer, and
        ``VP8_SET_REFERENCE`` copies into that buffer: frame 1 therefore sees the baseline in LAST
        too. Both sides do the same, so decoding stays bit-exact.)"""
        return self.encode_structured(frame, "key" if self._pts == 0 else "p", golden)

    def _encode(self, frame: np.ndarray, flags: int) -> bytes:
        L = self.lib.lib
        img = self._wrap(frame)
        deadline = VPX_DL_REALTIME if self.settings.realtime else VPX_DL_GOOD_QUALITY
        _check(
            self.lib,
            self.ctx,
            L.vpx_codec_encode(self.ctx, ctypes.byref(img), self._pts, 1, flags, deadline),
            "encode a frame",
        )
        self._pts += 1
        out = []
        it = ctypes.c_void_p(0)
        while True:
            pkt = L.vpx_codec_get_cx_data(self.ctx, ctypes.byref(it))
            if not pkt:
                break
            if pkt.contents.kind == VPX_CODEC_CX_FRAME_PKT:
                f = pkt.contents.frame
                out.append(ctypes.string_at(f.buf, f.sz))
        if len(out) != 1:
            raise EgovidError(f"libvpx returned {len(out)} packets for one frame (expected 1)")
        return out[0]

    def reconstruction(self) -> np.ndarray:
        """The encoder's reconstruction of the last frame (padded I420), what a decoder must output."""
        return self.copy_reference(self._recon_slot)


class VP9Decoder(_Codec):
    """VP9 decoder that accepts the same GOLDEN-frame injection."""

    def __init__(self, width: int, height: int, threads: int = 1) -> None:
        super().__init__(width, height)
        L = self.lib.lib
        cfg = (ctypes.c_uint * 3)(threads, width, height)
        _check(
            self.lib,
            self.ctx,
            L.vpx_codec_dec_init_ver(self.ctx, L.vpx_codec_vp9_dx(), cfg, 0, _DEC_ABI),
            "start the VP9 decoder",
        )
        self._open = True
        self._n = 0

    def decode(self, packet: bytes, golden: np.ndarray | None = None, last: np.ndarray | None = None) -> np.ndarray:
        """Decode one packet (after loading ``last`` into LAST, then injecting ``golden`` into
        GOLDEN, as the encoder did); returns the padded I420 frame."""
        L = self.lib.lib
        if (golden is not None or last is not None) and self._n == 0:
            raise ValueError("no reference injection before the keyframe")
        if last is not None:
            self.set_reference(last, VP8_LAST_FRAME)
        if golden is not None:
            self.set_reference(golden, VP8_GOLD_FRAME)
        _check(self.lib, self.ctx, L.vpx_codec_decode(self.ctx, packet, len(packet), None, 0), "decode a frame")
        self._n += 1
        it = ctypes.c_void_p(0)
        img = L.vpx_codec_get_frame(self.ctx, ctypes.byref(it))
        if not img:
            raise EgovidError("libvpx decoded no picture from a packet", "the bitstream is damaged")
        im = img.contents
        out = np.empty((self.height * 3 // 2, self.width), np.uint8)
        y, u, v = split_i420(out, self.width, self.height)
        for plane, dst, (w, h) in zip(
            range(3),
            (y, u, v),
            ((self.width, self.height), (self.width // 2, self.height // 2), (self.width // 2, self.height // 2)),
            strict=True,
        ):
            stride = im.stride[plane]
            src = np.ctypeslib.as_array(im.planes[plane], shape=(h * stride,))
            dst[:] = src.reshape(h, stride)[:, :w]
        return out


@functools.cache
def encoder_abi(lib: Library) -> int:
    """The encoder ABI version of ``lib``: from its version, confirmed by probing."""
    L = lib.lib
    known = _ENC_ABI.get(lib.version[:2])
    tries = ([known] if known else []) + [v for v in range(10, 80) if v != known]
    iface = L.vpx_codec_vp9_cx()
    cfg = ctypes.create_string_buffer(8192)
    L.vpx_codec_enc_config_default(iface, cfg, 0)
    ctypes.c_uint.from_buffer(cfg, _CFG["g_w"]).value = 64
    ctypes.c_uint.from_buffer(cfg, _CFG["g_h"]).value = 64
    for abi in tries:
        ctx = ctypes.create_string_buffer(512)
        res = L.vpx_codec_enc_init_ver(ctx, iface, cfg, 0, abi)
        if res == 0:
            L.vpx_codec_destroy(ctx)
            return abi
        if res != VPX_CODEC_ABI_MISMATCH:
            break
    raise EgovidError(
        f"no VP9 encoder ABI version works with libvpx {lib.version_str} at {lib.path}",
        "set EGOVID_LIBVPX to another libvpx",
    )


def _run_repeats(w: int, h: int, settings: EncoderSettings, dummies: tuple[str, ...], frames, golden) -> bool:
    """Self-test of one random-access run: grey ``dummies`` (undisplayed), ``frames[0]`` from the
    injected ``golden`` alone, ``frames[1]`` from the frame before; True if a decoder repeats it."""
    enc = VP9Encoder(w, h, settings)
    grey = np.full_like(frames[0], 128)
    run = [enc.encode_structured(grey, role) for role in dummies]
    run.append(enc.encode_structured(frames[0], "ra", golden))
    r1 = enc.reconstruction()
    run.append(enc.encode_structured(frames[1], "p"))
    r2 = enc.reconstruction()
    enc.close()
    dec = VP9Decoder(w, h)
    for pkt in run[: len(dummies)]:
        dec.decode(pkt)
    ok = np.array_equal(dec.decode(run[-2], golden), r1) and np.array_equal(dec.decode(run[-1]), r2)
    dec.close()
    return ok


@functools.cache
def self_test() -> str:
    """Encode-inject-decode round trip on a small clip; raise :class:`EgovidError` on failure.

    Checks that the decoder with injection reproduces the encoder's reconstruction bit for bit,
    that the injected reference is really used (decoding without it gives other pictures), and that
    it pays (fewer bytes than without it). Returns a one-line description of the library.
    """
    lib = library()
    w, h = 64, 48
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (h * 3 // 2 + 16, w + 16), dtype=np.uint8)
    frames, goldens = [], []
    for k in range(6):
        f = np.ascontiguousarray(base[k % 3 : k % 3 + h * 3 // 2, k : k + w])
        g = np.ascontiguousarray(base[(k + 1) % 3 : (k + 1) % 3 + h * 3 // 2, k + 1 : k + 1 + w])
        frames.append(f)
        goldens.append(g if k else None)
    # Frame k equals the injected golden of frame k shifted by one pixel: cheap only with injection.
    for k in range(1, 6):
        frames[k] = np.roll(goldens[k], 1, axis=1)
    try:
        enc = VP9Encoder(w, h, EncoderSettings(q=20, speed=6))
        packets, recon = [], []
        for f, g in zip(frames, goldens, strict=True):
            packets.append(enc.encode(f, g))
            recon.append(enc.reconstruction())
        enc.close()
        plain = VP9Encoder(w, h, EncoderSettings(q=20, speed=6))
        plain_bytes = sum(len(plain.encode(f)) for f in frames)
        plain.close()
        dec = VP9Decoder(w, h)
        ok = all(np.array_equal(dec.decode(p, g), r) for p, g, r in zip(packets, goldens, recon, strict=True))
        dec.close()
        blind = VP9Decoder(w, h)
        differs = any(not np.array_equal(blind.decode(p), r) for p, r in zip(packets, recon, strict=True))
        blind.close()
        # The out-of-order structure (codec.coding_plan, G = 3): key 0, p 1, anchor 4, between 2, 3.
        plan = [(0, "key", None), (1, "p", None), (4, "anchor", 1), (2, "between", None), (3, "between", None)]
        enc = VP9Encoder(w, h, EncoderSettings(q=20, speed=6))
        held, coded = {}, []
        for k, role, last_k in plan:
            g = goldens[k] if role in ("anchor", "between") else None
            pkt = enc.encode_structured(frames[k], role, g, held.get(last_k), 30 if role == "between" else None)
            rec = enc.reconstruction()
            held[k] = rec
            coded.append((pkt, g, held.get(last_k) if role == "anchor" else None, rec))
        enc.close()
        dec = VP9Decoder(w, h)
        ok = ok and all(np.array_equal(dec.decode(p, g, la), r) for p, g, la, r in coded)
        dec.close()
        # A random-access run of a joint segment: undisplayed grey keyframe, then a frame predicted
        # from the injected baseline alone, then a P frame; and the same at the realtime deadline
        # with a frame that refreshes nothing after the keyframe (codec.START_BASELINE_HELD): the
        # decoder's GOLDEN must still be the encoder's.
        ok = ok and _run_repeats(w, h, EncoderSettings(q=20, speed=6), ("key",), frames[1:3], goldens[1])
        rt = EncoderSettings(q=20, speed=9, realtime=True)
        ok = ok and _run_repeats(w, h, rt, ("key", "hold"), frames[1:3], goldens[1])
    except EgovidError:
        raise
    except Exception as exc:  # pragma: no cover - ctypes failures
        raise EgovidError(
            f"libvpx {lib.version_str} at {lib.path} crashed in the self-test: {exc}",
            "set EGOVID_LIBVPX to another libvpx",
        ) from None
    joint_bytes = sum(len(p) for p in packets)
    if not ok or not differs or joint_bytes >= plain_bytes:
        raise EgovidError(
            f"libvpx {lib.version_str} at {lib.path} failed the reference-injection self-test "
            f"(bit-exact {ok}, injection used {differs}, {joint_bytes} vs {plain_bytes} bytes)",
            "set EGOVID_LIBVPX to another libvpx (e.g. Debian's libvpx.so.7)",
        )
    return f"libvpx {lib.version_str} ({lib.path}), encoder ABI {encoder_abi(lib)}"
