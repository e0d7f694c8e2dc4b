"""Synthetic content: the named motions of `egovid synth fpv`."""

from __future__ import annotations

import numpy as np
import pytest

from egovid.core.errors import EgovidError
from egovid.synth import motions


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
