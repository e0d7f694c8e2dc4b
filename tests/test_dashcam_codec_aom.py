"""The libaom backend: AV1 with the older drive injected as a reference. Bit-exact round trips
against the encoder's own pictures (a decoder fed the same references), random access, and the
independent truths that the reference is used (decoding without it gives other pictures) and
pays (fewer bytes than the same frames coded alone)."""

import hashlib

import numpy as np
import pytest

from egovid.dashcam.codec import aom, registry
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
