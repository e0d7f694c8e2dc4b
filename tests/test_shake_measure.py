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


def test_gravity_down_from_the_accelerometer_through_the_gyros_axes_and_turn():
    """A camera that turns 30° in roll during the clip, its IMU mounted with other axes: the
    accelerometer's gravity, taken through the sync's axis map and the gyro's own orientation
    at each sample, is the world's down of the trajectory's frame (frame 0 = identity)."""
    from egovid.core.camera.intrinsics import Intrinsics
    from egovid.core.camera.resolve import CameraModel
    from egovid.core.camera.telemetry import CameraTelemetry, ImuSamples
    from egovid.core.motion.gyro import GyroSync
    from egovid.core.motion.source import CameraMotion
    from egovid.core.rotations import matrix_from_euler
    from egovid.core.trajectory import Trajectory
    from egovid.fpv.stabilize.run import gravity_down

    M = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])  # IMU -> camera axes
    t = np.linspace(0.0, 2.0, 401)
    rate = np.radians(15.0)  # camera roll rate (about its z axis), rad/s
    gyro = np.tile(M.T @ np.array([0.0, 0.0, rate]), (len(t), 1))
    roll = np.degrees(rate * t)
    R_cam = matrix_from_euler(np.zeros_like(t), np.zeros_like(t), roll)
    down_world = np.array([0.0, 1.0, 0.0])  # the camera starts level: its y axis points down
    f_cam = -9.81 * np.einsum("nji,j->ni", R_cam, down_world)  # specific force at rest, camera axes
    imu = ImuSamples(t, gyro, f_cam @ M, t)  # accel in IMU axes (f_imu = Mᵀ f_cam)
    sync = GyroSync(0.0, M, True, 1.0, 1.0, 60, np.zeros(3))
    frames = np.arange(0.0, 2.0, 1 / 30)
    zero = np.zeros_like(frames)
    traj = Trajectory(frames, matrix_from_euler(zero, zero, np.degrees(rate * frames)))
    cam = CameraModel(Intrinsics.from_focal(320, 180, 200.0), "flag", "test")
    cm = CameraMotion(traj, np.ones(len(frames)), "gyro", "auto", "test", cam, CameraTelemetry(imu=imu), sync=sync)
    assert np.allclose(gravity_down(cm), down_world, atol=1e-3)
