"""Synthetic content: the named motions of `egovid synth fpv`."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from egovid.core.errors import EgovidError
from egovid.core.video import iter_frames
from egovid.synth import motions
from egovid.synth.drive import DriveSpec, Light, render_drive


def test_named_synthetic_motion_is_its_parts():
    """`synth fpv --motion NAME` builds the same angles as composing the motion functions by hand."""
    spec = motions.MotionSpec("running", 90, 8.0, 2.0, 24.0, 1.5, jitter_deg=(0.15, 0.15, 0.1), seed=3)
    by_hand = motions.running(90, 8.0, 2.0, 24.0, 1.5) + motions.jitter(90, (0.15, 0.15, 0.1), seed=3)
    assert np.array_equal(spec.angles(), by_hand)
    pan = motions.MotionSpec("pan", 40, pan_deg=30.0, roll_amp=1.0, period=20.0, jitter_deg=0.0).angles()
    assert np.array_equal(pan[:, 0], motions.pan(40, 30.0)[:, 0])
    assert np.allclose(pan[:, 2], np.sin(2 * np.pi * np.arange(40) / 20.0))
    assert not np.any(motions.MotionSpec("still", 10, jitter_deg=0.0).angles())
    with pytest.raises(EgovidError, match="unknown motion"):
        motions.MotionSpec("moonwalk", 10).angles()


def test_a_drive_rendered_twice_with_one_seed_decodes_to_the_same_pictures(tmp_path):
    """Same seed, same pictures: the encoder's output repeats too (PyAV's libx264 with its
    macroblock tree gave 2-5 different streams in 5 renders of this drive; X264_REPEATABLE)."""
    spec = DriveSpec(legs=[("main", 390.0, 430.0)], cruise=10.0, seed=3, light=Light.preset("noon"))
    digests = set()
    for k in range(4):
        video, _, _ = render_drive(spec, tmp_path / f"r{k}.mp4", width=192, height=108)
        h = hashlib.sha256()
        for f in iter_frames(video):
            h.update(f.image.tobytes())
        digests.add(h.hexdigest())
    assert len(digests) == 1
