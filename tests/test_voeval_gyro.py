"""The gyro reference of ``voeval run --sequence gyro:VIDEO``: the bias of the gyro's still parts.
(The run on the real GoPro HERO5 clip is in tests/test_cli_real_clips.py, which measures that
clip's vision pairs once for every command it runs on it.)"""

from __future__ import annotations

import numpy as np


def test_still_bias_comes_from_the_parts_at_rest():
    from egovid.voeval.gyro_reference import still_bias

    rng = np.random.default_rng(4)
    t = np.arange(0, 5.0, 1 / 400)
    b = np.radians([0.3, -0.9, 0.5])
    gyro = b + rng.normal(0, np.radians(0.1), (len(t), 3))
    moving = t >= 2.0  # at rest for 2 s, then shaken like a hand-held camera (±5°/s at 8 Hz)
    gyro[moving] += np.radians(5.0) * np.sin(2 * np.pi * 8 * t[moving])[:, None]
    est, still = still_bias(t, gyro)
    assert 1.9 < still < 2.1
    np.testing.assert_allclose(np.degrees(est), np.degrees(b), atol=0.02)
    est, still = still_bias(t[moving], gyro[moving])  # never at rest: no bias is removed
    assert still < 1.0 and not est.any()
