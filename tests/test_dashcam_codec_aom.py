"""The libaom backend: AV1 with the older drive injected as a reference. Bit-exact round trips
against the encoder's own pictures (a decoder fed the same references), random access, and the
independent truths that the reference is used (decoding without it gives other pictures) and
pays (fewer bytes than the same frames coded alone)."""

import ctypes
import hashlib

import numpy as np
import pytest

from egovid.dashcam.codec import aom, registry, vpx
from egovid.dashcam.codec import segment as codec
from egovid.dashcam.codec.settings import EncoderSettings

W, H = 96, 64


def _scene(n: int, seed: int) -> list[np.ndarray]:
    """A textured I420 scene panning by 2 pixels a frame."""
    rng = np.random.default_rng(seed)
    big = rng.integers(0, 256, (H * 3 // 2, W + 2 * n + 4), dtype=np.uint8)
    return [np.ascontiguousarray(big[:, 2 * k : 2 * k + W]) for k in range(n)]


def _pair(n: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The new drive's frames and their baselines: the older drive saw the same scene one pixel
    to the side, with a little noise of its own."""
    old = _scene(n + 1, 5)
    rng = np.random.default_rng(6)
    new = []
    for f in old[:n]:
        g = np.roll(f, 1, axis=1).astype(np.int16) + rng.integers(-2, 3, f.shape)
        new.append(np.clip(g, 0, 255).astype(np.uint8))
    return new, old[:n]


def _settings(realtime: bool) -> EncoderSettings:
    return EncoderSettings(q=32, speed=9 if realtime else 6, codec="aom", realtime=realtime, refresh=6)


def test_the_binding_names_libaom_3_and_passes_its_self_test():
    lib = aom.library()
    assert lib.version[0] == 3
    assert aom.encoder_abi(lib) == 29 and aom.decoder_abi(lib) == 22  # libaom 3.x's
    assert "libaom 3." in aom.self_test()
    assert registry.BACKENDS["aom"].joint


@pytest.mark.parametrize("realtime", [True, False])
def test_a_joint_segment_decodes_bit_exactly_with_its_baselines_and_seeks(realtime):
    new, base = _pair(15)
    # frames 12-14 form a run whose first frame has no baseline: a plain AV1 run in the segment
    have = lambda k: base[k] if k < 12 else None  # noqa: E731
    recon: list = []
    enc = registry.encode_segment(iter(new), W, H, _settings(realtime), baselines=have, keep_recon=recon, verify=True)
    lay, _ = codec.parse_header(enc.blob)
    assert enc.blob[:4] == b"EGAM" and lay.codec == "aom"
    assert lay.starts == (codec.START_BASELINE_HELD, codec.START_BASELINE_HELD, codec.START_KEY)
    assert lay.n_packets == 15 + 4 and enc.frames == 15 == len(recon)
    out = list(registry.decode_segment(enc.blob, have))
    assert len(out) == 15 and all(np.array_equal(a, b) for a, b in zip(out, recon, strict=True))
    whole = hashlib.sha256()
    for f in out:
        codec.digest_update(whole, f)
    assert whole.hexdigest() == enc.recon_digest
    # From frame 8: its run (6-11) decodes alone, from the byte range of runs 1-2.
    offsets = codec.run_offsets(enc.blob)
    packets = codec.iter_packets(enc.blob[offsets[1] :], 0, lay.n_packets - lay.run_packets()[1][0])
    tail = list(registry.decode_runs(lay, packets, 1, have, 8))
    assert len(tail) == 7 and all(np.array_equal(a, b) for a, b in zip(tail, recon[8:], strict=True))
    # The baseline is used: without it (other pictures in the slot) the frames come out otherwise.
    wrong = list(registry.decode_segment(enc.blob, lambda k: base[(k + 3) % 12] if k < 12 else None))
    assert not np.array_equal(wrong[3], recon[3]) and np.array_equal(wrong[13], recon[13])
    with pytest.raises(ValueError, match="needs its baselines"):
        list(registry.decode_segment(enc.blob))
    # and it pays: the same frames coded alone take more bytes at the same quantiser.
    alone = registry.encode_segment(iter(new), W, H, _settings(realtime))
    assert codec.parse_header(alone.blob)[0].starts == (codec.START_KEY,) * 3
    assert enc.nbytes < alone.nbytes
    assert enc.psnr_y > alone.psnr_y - 0.5  # and no worse for it


def test_libaom_settings_are_checked():
    with pytest.raises(Exception, match="realtime mode"):
        EncoderSettings(q=32, speed=10, codec="aom")
    EncoderSettings(q=32, speed=10, codec="aom", realtime=True)


#: The reference structure of the first libaom archives (flat: every frame from its three previous
#: frames in slots 0-2, the newest written over the oldest, and the baseline in slot 3 as GOLDEN),
#: written out as that code produced it for a joint run of 6 frames: a flat segment must still be
#: coded so, byte for byte, or the segments stored before layers would no longer be reproduced.
FLAT_JOINT_RUN = [
    ("dummy", {}, (0, 1, 2, 3, 4, 5, 6, 7)),
    ("dummy", {0: 0}, (0,)),
    ("ra", {0: 3}, (0,)),
    ("p", {0: 0, 3: 3}, (1,)),
    ("p", {0: 1, 1: 0, 3: 3}, (2,)),
    ("p", {0: 2, 1: 1, 2: 0, 3: 3}, (0,)),
    ("p", {0: 0, 1: 2, 2: 1, 3: 3}, (1,)),
    ("p", {0: 1, 1: 0, 2: 2, 3: 3}, (2,)),
]


def test_a_flat_segment_is_coded_as_before_layers():
    """gop 1: the structure of the first libaom archives, and the segment's packets are those of
    libaom driven frame by frame through that structure at one quantiser."""
    assert aom.run_structure(6, True) == FLAT_JOINT_RUN
    new, base = _pair(6)
    st = EncoderSettings(q=32, speed=7, codec="aom", realtime=True, refresh=6, gop=1)
    enc = registry.encode_segment(iter(new), W, H, st, baselines=lambda k: base[k])
    lay, off = codec.parse_header(enc.blob)
    assert lay.gop == 1
    pw, ph = aom.padded_size(W, H)
    coder = aom.AV1Encoder(pw, ph, aom.AomSettings(q=32, speed=7, realtime=True, threads=1, row_mt=False))
    grey = np.full_like(new[0], 128)
    want = []
    for i, (role, refs, refresh) in enumerate(FLAT_JOINT_RUN):
        if role == "dummy":
            want.append(coder.encode(grey, refs or None, refresh))
        else:
            want.append(coder.encode(new[i - 2], refs, refresh, base[i - 2]))
    coder.close()
    assert list(codec.iter_packets(enc.blob, off, lay.n_packets)) == want


def test_temporal_layers_decode_bit_exactly_and_the_top_layer_is_left_out():
    """gop 4: frames 0 mod 4 the base layer, 2 mod 4 layer 1, odd frames layer 2 at quantisers
    +0/+6/+12. Decoded with the same baselines, the pictures are the encoder's, from the start and
    from a later run; no frame refers to the top layer, so a decoder given every packet but the
    top layer's reproduces the other frames bit for bit (the independent truth of the structure);
    the top layer is coarser (its pictures further from the source than the base layer's)."""
    n, refresh = 20, 8
    new, base = _pair(n)
    have = lambda k: base[k] if k < 16 else None  # noqa: E731  (run 16-19: plain AV1, no baseline)
    recon: list = []
    st = EncoderSettings(q=30, speed=7, codec="aom", realtime=True, refresh=refresh, gop=4)
    enc = registry.encode_segment(iter(new), W, H, st, baselines=have, keep_recon=recon, verify=True)
    lay, off = codec.parse_header(enc.blob)
    assert lay.gop == 1 and lay.starts == (codec.START_BASELINE_HELD,) * 2 + (codec.START_KEY,)
    out = list(registry.decode_segment(enc.blob, have))
    assert len(out) == n and all(np.array_equal(a, b) for a, b in zip(out, recon, strict=True))
    tail = list(registry.decode_segment(enc.blob, have, start=11))
    assert all(np.array_equal(a, b) for a, b in zip(tail, recon[11:], strict=True)) and len(tail) == n - 11
    # which packet is which frame: the plan of the header (dummies before each joint run)
    plan = lay.plan()
    packets = list(codec.iter_packets(enc.blob, off, lay.n_packets))
    j_of = lambda k: k % refresh  # noqa: E731
    dec = aom.AV1Decoder(*aom.padded_size(W, H))
    kept, err = {}, {0: [], 2: []}
    for (k, role, _), pkt in zip(plan, packets, strict=True):
        layer = aom.layer_of(j_of(k), 4)
        if role != "dummy" and layer in err:
            err[layer].append(np.mean((recon[k][:H].astype(float) - new[k][:H]) ** 2))
        if role != "dummy" and layer == 2:
            continue  # left out
        joint = k < 16 and role != "key"
        pic = dec.decode(pkt, vpx.pad_i420(base[k], *aom.padded_size(W, H)) if joint and role != "dummy" else None)
        if role != "dummy":
            kept[k] = pic
    dec.close()
    assert sorted(kept) == [k for k in range(n) if aom.layer_of(j_of(k), 4) < 2]
    for k, pic in kept.items():
        assert np.array_equal(vpx.crop_i420(pic, W, H), recon[k]), k
    assert np.mean(err[2]) > 1.5 * np.mean(err[0])
    # flat, the same frames: other packets (the layers change the coding, not the container)
    flat = registry.encode_segment(iter(new), W, H, EncoderSettings(**{**st.__dict__, "gop": 1}), baselines=have)
    assert flat.blob != enc.blob and codec.parse_header(flat.blob)[0].n_packets == lay.n_packets


def test_a_libaom_layer_period_other_than_1_2_4_is_refused():
    with pytest.raises(Exception, match="layer period"):
        EncoderSettings(q=32, speed=7, codec="aom", realtime=True, gop=8)
    with pytest.raises(Exception, match="realtime mode"):
        EncoderSettings(q=32, speed=6, codec="aom", gop=4)
    EncoderSettings(q=32, speed=7, codec="vp9", gop=8)  # VP9's anchor spacing is another matter


def _slot(dec: aom.AV1Decoder, s: int) -> np.ndarray:
    """The picture the decoder holds in reference slot ``s``."""
    buf = np.zeros((H * 3 // 2, W), np.uint8)
    ref = aom.Av1RefFrame()
    ref.idx, ref.img = s, dec._wrap(buf)
    dec._control(aom.AV1_COPY_REFERENCE, ctypes.byref(ref))
    return buf


@pytest.mark.parametrize("keep", [True, False])
def test_keep_refresh_keeps_every_frame_the_structure_refreshes(keep):
    """The decoder's reference slots after each frame of a flat joint run (the bitstream's own
    account of what was kept): with ``keep_refresh`` every frame is in the slot the structure
    refreshes; without it (the flat structure of the first libaom archives) libaom's realtime
    mode dropped the refreshes of the run's 2nd and 3rd frames (slots no reference type pointed
    at), which is why the default preset keeps them."""
    n = 8
    new, base = _pair(n)
    recon: list = []
    st = EncoderSettings(q=30, speed=7, codec="aom", realtime=True, refresh=n, keep_refresh=keep)
    enc = registry.encode_segment(iter(new), W, H, st, baselines=lambda k: base[k], keep_recon=recon)
    lay, off = codec.parse_header(enc.blob)
    structure = aom.run_structure(n, True)
    dec = aom.AV1Decoder(W, H)
    kept = []
    packets = codec.iter_packets(enc.blob, off, lay.n_packets)
    for (_, _, refresh), pkt, k in zip(structure, packets, range(-2, n), strict=True):
        pic = dec.decode(pkt, base[k] if k >= 0 else None)
        if k >= 0:
            assert np.array_equal(pic, recon[k])
            kept.append(all(np.array_equal(_slot(dec, s), pic) for s in refresh))
    dec.close()
    assert kept == ([True] * n if keep else [True, False, False] + [True] * (n - 3))
    legacy = registry.encode_segment(
        iter(new), W, H, EncoderSettings(**{**st.__dict__, "keep_refresh": False}), lambda k: base[k]
    )
    assert (legacy.blob == enc.blob) == (not keep)


@pytest.mark.parametrize("fixed", [True, False])
def test_fixed_costs_reach_libaom_and_decode_bit_exactly(fixed, monkeypatch):
    """``fixed_costs`` (the realtime preset's joint candidate): libaom is told to leave its
    cost tables alone within a frame (cheaper; the decoder needs nothing), and
    only then; the segment decodes to the encoder's pictures with the same baselines either way."""
    told: list[tuple[int, int]] = []
    real = aom._Codec._control

    def spy(self, ctrl, value):
        told.append((ctrl, getattr(value, "value", None)))
        return real(self, ctrl, value)

    monkeypatch.setattr(aom._Codec, "_control", spy)
    n = 8
    new, base = _pair(n)
    recon: list = []
    st = EncoderSettings(
        q=30, speed=7, codec="aom", realtime=True, refresh=n, keep_refresh=True, fixed_costs=fixed, threads=2
    )
    enc = registry.encode_segment(iter(new), W, H, st, baselines=lambda k: base[k], keep_recon=recon, verify=True)
    off = {(c, aom.COST_UPD_OFF) for c in aom.FIXED_COSTS}
    assert aom.AV1E_SET_COEFF_COST_UPD_FREQ in aom.FIXED_COSTS
    assert off <= set(told) if fixed else not off & set(told)
    out = list(registry.decode_segment(enc.blob, lambda k: base[k]))
    assert len(out) == n and all(np.array_equal(a, b) for a, b in zip(out, recon, strict=True))


def _obus(packet: bytes) -> dict[int, bytes]:
    """The OBUs of a temporal unit by type (AV1 spec 5.3: header, LEB128 size, payload)."""
    out, i = {}, 0
    while i < len(packet):
        head = packet[i]
        assert head & 2, "OBUs carry their sizes"
        i += 1 + ((head >> 2) & 1)
        size = shift = 0
        while True:
            b = packet[i]
            size |= (b & 0x7F) << shift
            i, shift = i + 1, shift + 7
            if not b & 0x80:
                break
        out[(head >> 3) & 15] = packet[i : i + size]
        i += size
    return out


def _seq_header_flags(packet: bytes) -> dict:
    """The maximum frame size (pixels), ``enable_order_hint`` and ``enable_ref_frame_mvs`` of the
    sequence header OBU (type 1) in a keyframe's temporal unit (AV1 spec 5.5; the path libaom takes
    here: no reduced still-picture header, no timing info)."""
    bits = "".join(f"{b:08b}" for b in _obus(packet)[1])
    pos = 0

    def f(n: int) -> int:
        nonlocal pos
        pos += n
        return int(bits[pos - n : pos], 2) if n else 0

    f(3)  # seq_profile
    f(1)  # still_picture
    assert f(1) == 0 and f(1) == 0  # reduced_still_picture_header, timing_info_present_flag
    display_delay = f(1)
    for _ in range(f(5) + 1):  # operating points
        f(12)
        if f(5) > 7:
            f(1)
        if display_delay and f(1):
            f(4)
    wb, hb = f(4) + 1, f(4) + 1
    size = (f(wb) + 1, f(hb) + 1)  # max_frame_width_minus_1, max_frame_height_minus_1
    if f(1):  # frame_id_numbers_present_flag
        f(7)
    f(3)  # use_128x128_superblock, enable_filter_intra, enable_intra_edge_filter
    f(4)  # enable_interintra_compound, enable_masked_compound, enable_warped_motion, enable_dual_filter
    order_hint = f(1)
    if order_hint:
        f(1)  # enable_jnt_comp
    return {"size": size, "enable_order_hint": order_hint, "enable_ref_frame_mvs": f(1) if order_hint else 0}


def test_ref_mvs_off_and_qm_on_reach_libaom_and_decode_bit_exactly(monkeypatch):
    """``ref_mvs`` False and ``qm`` True (the realtime preset's joint candidate): the bitstream's
    own sequence header says motion-field projection is off, quantisation matrices change the
    packets (and libaom's matrix-level range, ``AV1E_SET_QM_MIN``/``MAX`` 64/65, matters only with
    them: the control id is the matrices'), and the segment decodes to the encoder's pictures."""
    n = 8
    new, base = _pair(n)
    st = EncoderSettings(q=30, speed=7, codec="aom", realtime=True, refresh=n, keep_refresh=True, fixed_costs=True)

    def coded(s: EncoderSettings, recon=None) -> tuple[bytes, list[bytes]]:
        enc = registry.encode_segment(iter(new), W, H, s, baselines=lambda k: base[k], keep_recon=recon, verify=True)
        lay, off = codec.parse_header(enc.blob)
        return enc.blob, list(codec.iter_packets(enc.blob, off, lay.n_packets))

    plain, plain_pk = coded(st)
    assert _seq_header_flags(plain_pk[0]) == {"size": (W, H), "enable_order_hint": 1, "enable_ref_frame_mvs": 1}
    recon: list = []
    both, both_pk = coded(EncoderSettings(**{**st.__dict__, "ref_mvs": False, "qm": True}), recon)
    assert _seq_header_flags(both_pk[0]) == {"size": (W, H), "enable_order_hint": 1, "enable_ref_frame_mvs": 0}
    assert both != plain
    out = list(registry.decode_segment(both, lambda k: base[k]))
    assert len(out) == n and all(np.array_equal(a, b) for a, b in zip(out, recon, strict=True))
    qm_only, qm_pk = coded(EncoderSettings(**{**st.__dict__, "qm": True}))
    assert qm_only != plain and _seq_header_flags(qm_pk[0])["enable_ref_frame_mvs"] == 1
    # the matrices' level range: a change with them on, none without them
    real = aom.AV1Encoder.__init__

    def steep(self, *args, **kwargs) -> None:
        real(self, *args, **kwargs)
        for ctrl in (64, 65):  # AV1E_SET_QM_MIN, AV1E_SET_QM_MAX (libaom 3.6's aomcx.h)
            self._control(ctrl, ctypes.c_int(0))

    monkeypatch.setattr(aom.AV1Encoder, "__init__", steep)
    assert coded(EncoderSettings(**{**st.__dict__, "qm": True}))[0] != qm_only
    assert coded(st)[0] == plain


def test_without_ref_mvs_and_qm_a_segment_is_coded_as_before(monkeypatch):
    """The defaults (``ref_mvs`` True, ``qm`` False; every preset but realtime's, and the segments
    coded before them) leave both controls unset, and the packets are those of libaom told its
    own defaults explicitly (motion-field projection on, no matrices): coded as before, byte for
    byte."""
    told: list[int] = []
    real_control = aom._Codec._control

    def spy(self, ctrl, value):
        told.append(ctrl)
        return real_control(self, ctrl, value)

    monkeypatch.setattr(aom._Codec, "_control", spy)
    n = 8
    new, base = _pair(n)
    st = EncoderSettings(q=30, speed=7, codec="aom", realtime=True, refresh=n, keep_refresh=True, fixed_costs=True)
    assert (st.ref_mvs, st.qm) == (True, False)
    enc = registry.encode_segment(iter(new), W, H, st, baselines=lambda k: base[k])
    assert told and not {aom.AV1E_SET_ENABLE_REF_FRAME_MVS, aom.AV1E_SET_ENABLE_QM} & set(told)
    real_init = aom.AV1Encoder.__init__

    def explicit(self, *args, **kwargs) -> None:
        real_init(self, *args, **kwargs)
        self._control(aom.AV1E_SET_ENABLE_REF_FRAME_MVS, ctypes.c_int(1))
        self._control(aom.AV1E_SET_ENABLE_QM, ctypes.c_int(0))

    monkeypatch.setattr(aom.AV1Encoder, "__init__", explicit)
    told.clear()
    again = registry.encode_segment(iter(new), W, H, st, baselines=lambda k: base[k])
    assert {aom.AV1E_SET_ENABLE_REF_FRAME_MVS, aom.AV1E_SET_ENABLE_QM} <= set(told)
    assert again.blob == enc.blob
