"""The path programme's zoom budget through a fisheye lens (`pipeline.lens_budget`).

The programme checks the crop's corners through a pinhole; through a fisheye a turn of yaw or
pitch costs less zoom, and the budget is raised until the lens itself needs ``max_zoom``."""

from __future__ import annotations

import numpy as np
import pytest

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.lens import PINHOLE, Lens
from egovid.core.rotations import matrix_from_euler
from egovid.fpv.stabilize.path import PathWeights, fit_path
from egovid.fpv.stabilize.pipeline import lens_budget, lens_need
from egovid.fpv.stabilize.warp import MeshWarp

FISHEYE = Lens("fisheye", (0.0, 0.0, 0.0, 0.0))


def _need_of(rate: float):
    """A lens that needs ``1 + rate * (budget - 1)`` for the path planned at ``budget``."""
    return lambda budget: np.array([1.0, 1.0 + rate * (budget - 1.0)])


def _at_budget(budget: float) -> np.ndarray:
    """A planned zoom that reaches its budget."""
    return np.array([1.0, budget])


def test_a_budget_that_does_not_bind_is_left_alone():
    tried = []

    def fit(budget: float) -> float:
        tried.append(budget)
        return budget

    _, budget = lens_budget(fit, _need_of(0.5), lambda b: np.array([1.0, 1.05]), 1.10)
    assert tried == [1.10] and budget == pytest.approx(1.10)


def test_a_lens_that_needs_less_gets_a_larger_budget_that_it_covers():
    tried = []

    def fit(budget: float) -> float:
        tried.append(budget)
        return budget

    best, budget = lens_budget(fit, _need_of(0.5), _at_budget, 1.10)
    assert tried[0] == pytest.approx(1.10)
    assert budget == pytest.approx(1.20) and best == pytest.approx(1.20)  # 1 + 0.1² / 0.05
    assert 1.0 + 0.5 * (budget - 1.0) <= 1.10 + 1e-9


def test_the_budget_falls_back_half_way_then_to_max_zoom():
    # needs more than the pinhole beyond 1.12: the far budget (1.2) fails, half way (1.15) fails too
    def need(b: float) -> np.ndarray:
        return np.array([1.0 + 0.5 * (b - 1.0) if b <= 1.12 else b])

    best, budget = lens_budget(lambda b: b, need, _at_budget, 1.10)
    assert budget == pytest.approx(1.10) and best == pytest.approx(1.10)

    def need_half(b: float) -> np.ndarray:  # 1.15 is covered, 1.2 is not
        return np.array([1.0 + 0.5 * (b - 1.0) if b <= 1.16 else b])

    assert lens_budget(lambda b: b, need_half, _at_budget, 1.10)[1] == pytest.approx(1.15)


def test_a_lens_at_its_budget_or_a_path_needing_no_zoom_keeps_max_zoom():
    assert lens_budget(lambda b: b, _need_of(1.0), _at_budget, 1.10)[1] == pytest.approx(1.10)
    assert lens_budget(lambda b: b, _need_of(0.95), _at_budget, 1.10)[1] == pytest.approx(1.10)  # 5 % unused
    assert lens_budget(lambda b: b, lambda b: np.ones(3), _at_budget, 1.10)[1] == pytest.approx(1.10)


def test_through_a_fisheye_a_yaw_detour_needs_less_zoom_than_the_pinhole_plan():
    """The premise, on real geometry: a path that leaves the recorded yaw by a few degrees, fitted
    by the path programme (pinhole corners) at 1.10, needs less zoom through an equidistant fisheye
    of the same focal length, and the same through a pinhole."""
    intr = Intrinsics.from_focal(640, 360, 300.0)
    n = 60
    original = np.zeros((n, 3))
    original[:, 0] = 2.0 * np.sin(np.linspace(0, 2 * np.pi, n))  # yaw swing the plan removes
    plan = np.zeros((n, 3))
    hold = PathWeights(plan=100.0, zoom=0.01)  # keep to the plan, zoom instead
    fitted = fit_path(original, plan, intr, 30.0, max_zoom=1.10, weights=hold)
    planned = float(np.max(1.0 / fitted.keep))
    R_rows = _rows(original)
    pin = float(np.max(lens_need(MeshWarp(intr, 0, lens=PINHOLE), fitted.path, R_rows)))
    fish = float(np.max(lens_need(MeshWarp(intr, 0, lens=FISHEYE), fitted.path, R_rows)))
    assert planned > 1.05  # the crop is needed
    assert pin == pytest.approx(planned, abs=0.01)
    assert fish < pin - 0.01


def _rows(angles: np.ndarray) -> np.ndarray:
    return matrix_from_euler(angles[:, 0], angles[:, 1], angles[:, 2])[:, None]
