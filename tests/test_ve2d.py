"""2D-VE (thesis §8.4): the saccade bookkeeping on hand-made flows, and whole videos."""

import numpy as np
import pytest

from egovid.core.camera.intrinsics import Intrinsics
from egovid.fpv.perception.model import ViewingModel
from egovid.fpv.perception.ve2d import _Segments, grid_centres, ve2d_video


def _run(flows, n, intr):
    model = ViewingModel.model_2d()
    segs = _Segments(intr, model, 30.0, n, 1, 1)
    segs.begin()
    for f in flows:
        segs.advance(f, 1.0)
        if len(segs.done):
            break
    return segs.done[0]


def test_a_jerk_costs_exactly_one_saccade():
    intr = Intrinsics.from_focal(200, 100, 150.0)
    n = 12
    zero = np.zeros((100, 200, 2), np.float32)
    jerk = zero.copy()
    jerk[..., 0] = 8.0  # the whole image jumps 8 px between frames 3 and 4
    flows = [zero, zero, zero, jerk] + [zero] * 10
    # Tracked: frames 0-3; the jump fails at frame 4, whose saccade blanks frames 4-8 ("1011111"
    # -> "1000001", 5 frames); frames 9-11 are tracked again: 7 of 12.
    assert _run(flows, n, intr) == pytest.approx(7 / 12)
    # No jerk: every frame tracked.
    assert _run([zero] * 12, n, intr) == pytest.approx(1.0)


def test_target_leaving_the_frame_is_lost():
    intr = Intrinsics.from_focal(200, 100, 150.0)
    pan = np.zeros((100, 200, 2), np.float32)
    pan[..., 0] = 30.0  # a fast, steady pan: the centre target leaves after ~3 frames
    frac = _run([pan] * 12, 12, intr)
    assert frac < 0.5


def test_grid_centres():
    c = grid_centres(200, 100, 10, 20)
    assert c.shape == (200, 2)
    assert c[0] == pytest.approx([4.5, 4.5])
    assert c[-1] == pytest.approx([194.5, 94.5])


def test_still_video_is_one_and_shaky_is_lower(still_clip, shaky_clip):
    still = ve2d_video(still_clip, model=ViewingModel.model_2d().with_(window_frames=10))
    assert still.score == pytest.approx(1.0)
    assert len(still.segments) == 20 - 10 + 1
    shaky = ve2d_video(shaky_clip)
    assert 0.0 < shaky.score < 0.9
    assert len(shaky.segments) == 90 - 30 + 1
