"""Gyro integration, gyro-to-video sync and the focal-length fit, against known truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from egovid.core.camera.telemetry import CameraTelemetry, ImuSamples, OrientationSamples
from egovid.core.errors import EgovidError
from egovid.core.motion import gyro
from egovid.core.motion.source import REQUESTS, SOURCES, choose_source
from egovid.core.rotations import angle_deg, so3_exp


def _smooth_rates(t: np.ndarray, seed: int) -> np.ndarray:
    """Angular rates (rad/s) like a handheld camera: a few sines per axis, mostly yaw."""
    rng = np.random.default_rng(seed)
    w = np.zeros((len(t), 3))
    for axis, amp in enumerate((0.3, 1.0, 0.2)):
        for _ in range(4):
            f, ph = rng.uniform(0.2, 3.0), rng.uniform(0, 2 * np.pi)
            w[:, axis] += amp * rng.uniform(0.2, 1.0) * np.sin(2 * np.pi * f * t + ph)
    return w


def test_integration_matches_exact_product():
    t = np.arange(0, 2.0, 1 / 400)
    w = _smooth_rates(t, 0)
    track = gyro.integrate(ImuSamples(t, w))
    # Reference: the same midpoint rule, multiplied out one sample at a time with SciPy.
    R = Rotation.identity()
    for k in range(len(t) - 1):
        R = R * Rotation.from_rotvec(0.5 * (w[k] + w[k + 1]) * (t[k + 1] - t[k]))
    assert angle_deg(track.R[-1].T @ R.as_matrix()) < 1e-9
    # A constant rate turns by rate x time.
    const = gyro.integrate(ImuSamples(t, np.tile([0.0, 0.5, 0.0], (len(t), 1))))
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(const.R[-1]).as_rotvec())) == pytest.approx(
        np.degrees(0.5 * t[-1]), rel=1e-9
    )


def _vision_of(track: gyro.GyroTrack, M: np.ndarray, offset: float, frame_t: np.ndarray, noise: float, seed: int):
    """What vision would measure: the gyro's rotations at frame time + offset, in camera axes."""
    R = track.rotations_at(frame_t + offset)
    R = M[None] @ (R[0].T[None] @ R) @ M.T[None]
    rng = np.random.default_rng(seed)
    R = R @ so3_exp(rng.normal(0, noise, (len(R), 3)))
    return R


def test_sync_recovers_offset_axes_and_bias():
    t = np.arange(0, 12.0, 1 / 400)
    w = _smooth_rates(t, 1)
    M = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # the HERO5's mapping
    truth = gyro.integrate(ImuSamples(t, w))
    bias = np.array([0.002, 0.015, -0.004])  # rad/s, like the HERO5's
    frame_t = np.arange(0.5, 11.5, 1 / 29.97)
    R_vis = _vision_of(truth, M, -0.0372, frame_t, np.radians(0.02), 2)
    biased = gyro.integrate(ImuSamples(t, w + bias))
    s = gyro.sync_gyro(biased, frame_t, gyro.frame_rates(frame_t, R_vis))
    assert s.offset_s == pytest.approx(-0.0372, abs=0.001)
    assert s.snapped and np.array_equal(s.axes, M)
    assert s.r_vector > 0.99 and s.trusted
    np.testing.assert_allclose(s.bias, bias, atol=0.001)
    R_g = gyro.frame_rotations(gyro.integrate(ImuSamples(t, w + bias), bias=s.bias), s, frame_t)
    c = gyro.compare_rotations(R_vis, R_g)
    assert c.r > 0.99 and c.ratio == pytest.approx(1.0, abs=0.02)


def test_sync_times_a_steady_turn_by_its_direction_and_caps_the_bias():
    """A walk (the HERO6 clip's kind): a steady 30°/s turn with a 2 Hz bob and a 1 Hz sway, so
    the angular speed barely changes while the rate's direction does; vision 30 ms ahead, with a
    per-frame error of 0.05° per axis and reading 10 °/s less turn than the gyro (a lens model
    that misses a fisheye). The offset is found within 3 ms (the rate vectors refine the speed's
    estimate), and the bias stays a gyro's (at most MAX_BIAS_DEG_S): before, it took vision's
    missing 10 °/s, and every comparison against the synced gyro hid that error."""
    t = np.arange(0, 3.0, 1 / 200)
    w = np.column_stack(
        [0.12 * np.sin(2 * np.pi * 2.0 * t + 0.4), np.radians(30.0) + 0.03 * np.sin(2 * np.pi * t),
         0.10 * np.sin(2 * np.pi * 1.0 * t + 1.1)]
    )  # fmt: skip
    track = gyro.integrate(ImuSamples(t, w))
    frame_t = np.arange(0.3, 2.4, 1 / 30)
    R_vis = _vision_of(track, np.eye(3), -0.030, frame_t, np.radians(0.05), 6)
    rates = gyro.frame_rates(frame_t, R_vis) - np.array([0.0, np.radians(10.0), 0.0])
    s = gyro.sync_gyro(track, frame_t, rates)
    assert s.offset_s == pytest.approx(-0.030, abs=0.003)
    assert np.degrees(np.linalg.norm(s.bias)) == pytest.approx(gyro.MAX_BIAS_DEG_S, abs=1e-6)


def test_unrelated_gyro_is_not_trusted():
    t = np.arange(0, 10.0, 1 / 200)
    frame_t = np.arange(0.5, 9.5, 1 / 30)
    R_vis = _vision_of(gyro.integrate(ImuSamples(t, _smooth_rates(t, 3))), np.eye(3), 0.0, frame_t, 1e-4, 4)
    other = gyro.integrate(ImuSamples(t, _smooth_rates(t, 5)))
    assert not gyro.sync_gyro(other, frame_t, gyro.frame_rates(frame_t, R_vis)).trusted


def test_focal_fit_recovers_the_focal_length():
    """Points seen by a 640x360 camera of focal length 410 px turning by known rotations; vision
    fits them assuming 300 px; the gyro's rotations give back 410 px in two steps (fit, re-fit)."""
    from egovid.core.motion.pairwise import rotation_from_correspondences

    rng = np.random.default_rng(7)
    f_true, w, h = 410.0, 640, 360
    c = np.array([(w - 1) / 2, (h - 1) / 2])
    R = so3_exp(np.cumsum(rng.normal(0, np.radians(0.8), (40, 3)), axis=0))
    matches = []
    for i in range(39):
        Q = R[i].T @ R[i + 1]
        pj = rng.uniform([20, 20], [w - 20, h - 20], (300, 2))
        x = np.column_stack([(pj - c) / f_true, np.ones(300)]) @ Q.T
        pi = f_true * x[:, :2] / x[:, 2:3] + c + rng.normal(0, 0.05, (300, 2))
        matches.append((i, i + 1, pi, pj))

    def vision(f: float):
        K = np.array([[f, 0, c[0]], [0, f, c[1]], [0, 0, 1]])
        return [(i, j, rotation_from_correspondences(pi, pj, K).Q) for i, j, pi, pj in matches]

    fit = gyro.fit_focal(vision(300.0), R, 300.0)
    assert fit.well_posed and fit.pairs >= 20 and fit.scale > 1.2
    assert fit.focal_px == pytest.approx(f_true, rel=0.03)
    again = gyro.fit_focal(vision(fit.focal_px), R, fit.focal_px)
    assert again.focal_px == pytest.approx(f_true, rel=0.005)


def test_camera_orientation_track_is_relative_to_the_first_sample():
    t = np.linspace(0, 1, 31)
    R = so3_exp(np.outer(t, [0.0, 0.4, 0.1]))
    q = Rotation.from_matrix(np.array([Rotation.from_rotvec([0.3, 0, 0]).as_matrix() @ r for r in R])).as_quat()
    track = gyro.orientation_track(OrientationSamples(t, q[:, [3, 0, 1, 2]]))
    assert angle_deg(track.R[-1].T @ R[-1]) < 1e-9


def test_auto_source_follows_what_the_camera_recorded():
    imu = ImuSamples(np.arange(0, 1, 0.0025), np.zeros((400, 3)))
    gopro = CameraTelemetry(make="GoPro", model="HERO5 Black", imu=imu, stabilization="N")
    assert choose_source("auto", gopro)[0] == "gyro"
    hs = CameraTelemetry(make="GoPro", model="HERO9 Black", imu=imu, stabilization="HS High")
    src, why = choose_source("auto", hs)
    assert src == "vision" and "stabilised the picture itself" in why
    quat = OrientationSamples(np.arange(10) / 30, np.tile([1.0, 0, 0, 0], (10, 1)))
    hs_iori = CameraTelemetry(
        make="GoPro", model="HERO9 Black", imu=imu, stabilization="HS High", image_orientation=quat
    )
    assert choose_source("auto", hs_iori)[0] == "camera-orientation"
    assert choose_source("auto", CameraTelemetry()) == ("vision", "the file records no gyro")
    for src in ("gyro", "fused"):
        with pytest.raises(EgovidError, match="needs a gyro"):
            choose_source(src, CameraTelemetry())
    with pytest.raises(EgovidError, match="unknown motion source"):
        choose_source("magic", gopro)


def test_source_registry_says_what_each_source_needs():
    """--source takes auto and the sources a user may name; camera-orientation only comes from auto."""
    assert REQUESTS == ("auto", "vision", "gyro", "fused")
    assert [n for n, s in SOURCES.items() if s.needs_gyro] == ["gyro", "fused"]
    assert [n for n, s in SOURCES.items() if s.whole_vision] == ["vision", "fused"]
    assert [n for n, s in SOURCES.items() if s.sensor] == ["gyro", "fused", "camera-orientation"]
    imu = ImuSamples(np.arange(0, 1, 0.0025), np.zeros((400, 3)))
    gopro = CameraTelemetry(make="GoPro", model="HERO5 Black", imu=imu, stabilization="N")
    assert choose_source("gyro", gopro) == ("gyro", "asked for (GoPro HERO5 Black gyro, 400 Hz)")
    with pytest.raises(EgovidError, match="unknown motion source"):
        choose_source("camera-orientation", gopro)


def test_camera_orientation_source_end_to_end(shaky_clip, monkeypatch):
    """A camera that stabilised its picture and recorded the picture's orientation (GoPro IORI):
    no such clip is ours to ship, so the synthetic clip's ground truth plays the recorded
    orientation, in other axes and 40 ms late; `auto` must pick it and sync it."""
    from egovid.core.motion import source as source_mod
    from egovid.core.trajectory import read_motion_csv

    truth = read_motion_csv(shaky_clip.with_name("shaky.gt.csv")).relative_to_first()
    M = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera = M · recorded
    t_rec = truth.times + 0.040
    R_rec = M.T[None] @ truth.R @ M[None]
    quat = Rotation.from_matrix(R_rec).as_quat()[:, [3, 0, 1, 2]]
    imu = ImuSamples(np.arange(0, 3.0, 0.0025), np.zeros((1200, 3)))
    tel = CameraTelemetry(
        make="GoPro",
        model="HERO9 Black",
        imu=imu,
        stabilization="HS High",
        image_orientation=OrientationSamples(t_rec, quat),
    )
    monkeypatch.setattr(source_mod, "read_camera_telemetry", lambda path: tel)
    cm = source_mod.camera_motion(shaky_clip, "auto")
    assert cm.source == "camera-orientation" and "stabilised the picture itself" in cm.reason
    assert cm.sync.offset_s == pytest.approx(0.040, abs=0.003)
    assert np.array_equal(cm.sync.axes, M) and not np.any(cm.sync.bias)
    err = angle_deg(np.swapaxes(cm.trajectory.R, 1, 2) @ truth.R)
    assert err.max() < 0.05, err.max()
