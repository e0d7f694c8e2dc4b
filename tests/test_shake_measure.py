"""The visible-shake figure the stabiliser reports (shake.py's formula) and its warning."""

from __future__ import annotations

import numpy as np

from egovid.core.metrics.jitter import shake_rms, unzoomed
from egovid.fpv.stabilize.measure import VideoMeasures
from egovid.fpv.stabilize.pipeline import shake_warnings


def _shake_py(path: np.ndarray) -> float:
    """shake.py's own loop (tools/shake.py), x + y."""
    k = 15
    pad = np.pad(path, ((k // 2, k // 2), (0, 0)), mode="edge")
    ma = np.array([pad[i : i + k].mean(0) for i in range(len(path))])
    return float(np.sqrt(np.mean((path - ma) ** 2, 0)).sum())


def test_shake_rms_is_shake_py_formula():
    rng = np.random.default_rng(3)
    for n in (5, 40, 301):
        p = np.cumsum(rng.normal(size=(n, 2)), axis=0)
        assert np.isclose(shake_rms(p), _shake_py(p), rtol=1e-12, atol=1e-12)


def test_unzoomed_divides_each_shift_by_its_frames_zoom():
    p = np.array([[0.0, 0.0], [2.0, 4.0], [6.0, 4.0]])
    assert np.allclose(unzoomed(p, np.array([1.0, 2.0, 4.0])), [[0, 0], [1, 2], [2, 2]])
    assert np.allclose(unzoomed(p, 1.0), p)


def _m(shake: float) -> VideoMeasures:
    return VideoMeasures(0.9, 0.9, 0.9, 0.9, 20.0, 0.1, shake)


def test_warning_when_the_output_shakes_more_and_what_to_change():
    assert shake_warnings(_m(1.0), _m(0.5), 1.05, {"max_zoom": 1.1}) == []
    (w,) = shake_warnings(_m(1.0), _m(1.2), 1.1, {"max_zoom": 1.1})
    assert "1.000 → 1.200" in w and "--max-zoom 1.20" in w
    (w,) = shake_warnings(_m(1.0), _m(1.2), 1.02, {"max_zoom": 1.1})
    assert "--hfov" in w
    assert shake_warnings(None, None, 1.0, {}) == []
