"""The path the frame can afford (issue 13 item 6): dynamic zoom under --max-zoom, the plan
followed where it fits, smooth detours where it does not, pans followed without lag. Coverage is
checked by warping an all-white frame with the rendering's own homographies, independently of the
programme's linearised corners."""

import cv2
import numpy as np
import pytest

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.metrics.jitter import high_pass_rms
from egovid.core.rotations import matrix_from_euler
from egovid.fpv.stabilize.path import PathWeights, bspline_basis, fit_path, pull_within_budget, required_keep
from egovid.fpv.stabilize.render import homographies, zoom_about_centre

INTR = Intrinsics.from_hfov(640, 360, 94.4)
FPS = 30.0


def _covered(original: np.ndarray, path: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Share of each output frame with source content (rendered masks, nearest neighbour)."""
    R = matrix_from_euler(*original.T)
    Rn = matrix_from_euler(*path.T)
    H = zoom_about_centre(keep, INTR.width, INTR.height) @ homographies(R, Rn, INTR)
    ones = np.full((INTR.height, INTR.width), 255, np.uint8)
    return np.array(
        [(cv2.warpPerspective(ones, h, (INTR.width, INTR.height), flags=cv2.INTER_NEAREST) > 0).mean() for h in H]
    )


def _shaky(n: int, seed: int = 0, amp: float = 0.4) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FPS
    a = np.stack([2 * np.sin(2 * np.pi * 0.4 * t), 0.8 * np.sin(2 * np.pi * 0.7 * t), 0.3 * np.sin(t)], axis=1)
    return a + rng.normal(0, amp, (n, 3)) * [1, 1, 0.5]


def test_zoom_stays_under_the_cap_and_the_frame_stays_covered():
    a = _shaky(150)
    plan = np.zeros_like(a)  # a tripod: far more than 10 % of crop would show it
    fp = fit_path(a, plan, INTR, FPS, max_zoom=1.10)
    assert fp.zoom.max() <= 1.10 + 1e-9 and fp.zoom.min() >= 1.0
    assert _covered(a, fp.path, fp.keep).min() > 0.9999
    # The path is smooth although the corridor it lives in shakes: high-frequency content of the
    # rendered view direction is a small fraction of the recorded one.
    assert high_pass_rms(fp.path, FPS, 3.0) < 0.1 * high_pass_rms(a, FPS, 3.0)
    with pytest.raises(EgovidError, match="maximum zoom"):
        fit_path(a, plan, INTR, FPS, max_zoom=0.9)


def test_the_plan_is_kept_where_it_fits_and_the_zoom_is_dynamic():
    n = 240
    a = np.zeros((n, 3))
    a[100:130, 0] = np.linspace(0, 3.0, 30)  # a 3° jolt and back, in one second
    a[130:160, 0] = np.linspace(3.0, 0, 30)
    plan = np.zeros_like(a)  # the plan ignores the jolt: needs about 3° of margin there
    # Crop made cheap against leaving the plan, so that the jolt is worth zooming for.
    fp = fit_path(a, plan, INTR, FPS, max_zoom=1.10, weights=PathWeights(zoom=0.1, z1=1.0, z2=3.0, z3=10.0))
    assert _covered(a, fp.path, fp.keep).min() > 0.9999
    quiet = np.r_[0:60, 200:240]
    np.testing.assert_allclose(fp.path[quiet], plan[quiet], atol=1e-6)  # the plan, exactly, where it fits
    assert np.all(fp.zoom[quiet] < 1.002)
    # The zoom rises around the jolt only (a fixed crop would hold the peak all clip long), and
    # by default (crop dearer) less of the jolt is removed for less zoom.
    assert fp.zoom[100:160].max() > 1.03
    default = fit_path(a, plan, INTR, FPS, max_zoom=1.10)
    assert default.zoom.max() < fp.zoom.max()
    assert fp.zoom.mean() - 1 < 0.5 * (fp.zoom.max() - 1)
    # Compared with the worst-case fixed crop the plan would need, the dynamic crop is smaller.
    assert fp.zoom.max() < 1.0 / required_keep(a, plan, INTR).min()


def test_a_fast_pan_is_followed_without_lag():
    n = 150
    t = np.arange(n) / FPS
    a = np.zeros((n, 3))
    a[:, 0] = 60.0 * np.clip((t - 2.0) / 1.0, 0, 1)  # a 60° pan in 1 s (60°/s), starting at 2 s
    a += np.random.default_rng(3).normal(0, 0.2, a.shape) * [1, 1, 0]
    # A plan that lags the pan by 0.3 s (as a smoother that rounds its corners would).
    plan = np.zeros_like(a)
    plan[:, 0] = 60.0 * np.clip((t - 2.3) / 1.0, 0, 1)
    fp = fit_path(a, plan, INTR, FPS, max_zoom=1.10)
    assert _covered(a, fp.path, fp.keep).min() > 0.9999
    # The rendered view stays within the crop margin of the recorded one: a few degrees, i.e. at
    # most a few frames behind a 2°/frame pan (a 0.3 s lag would be 18°).
    assert np.abs(fp.path[:, 0] - a[:, 0]).max() < 6.0
    lag = np.argmax(fp.path[:, 0] > 30.0) - np.argmax(a[:, 0] > 30.0)
    assert abs(lag) <= 3


def test_bspline_basis_is_a_partition_of_unity():
    B = bspline_basis(101, 3.0)
    np.testing.assert_allclose(np.asarray(B.sum(axis=1)).ravel(), 1.0)
    assert B.shape == (101, 37) and B.getnnz(axis=1).max() == 4


def test_a_path_the_budget_cannot_cover_is_pulled_towards_the_recorded_one_not_zoomed_past_it():
    # A path that leaves the recorded one by 6° of yaw for a second (about 14 % of crop at 94°
    # hfov): the zoom budget of 1.10 cannot cover it, so those frames must be moved back towards
    # the recorded view, smoothly, and every frame covered at the budget's zoom (rendered masks).
    n = 120
    a = _shaky(n, seed=3, amp=0.1)
    path = a.copy()
    path[40:70, 0] += 6.0
    path[30:40, 0] += np.linspace(0.0, 6.0, 10)
    path[70:80, 0] += np.linspace(6.0, 0.0, 10)
    min_keep = 1 / 1.10
    assert required_keep(a, path, INTR).min() < min_keep - 0.01  # the premise
    pulled, moved = pull_within_budget(a, path, INTR, min_keep, FPS)
    assert moved > 0
    np.testing.assert_array_equal(pulled[:15], path[:15])  # untouched far from the excursion
    np.testing.assert_array_equal(pulled[95:], path[95:])
    assert _covered(a, pulled, np.full(n, min_keep + 1e-6)).min() > 0.9999
    dev = pulled[:, 0] - a[:, 0]
    # Pulled no further than the budget needs: mid-excursion the whole budget is used.
    assert dev[55] > 2.0 and required_keep(a, pulled, INTR)[45:65].min() < min_keep + 0.002
    assert np.abs(np.diff(dev, 2)).max() < 1.0  # no jerk where the pull starts and ends
