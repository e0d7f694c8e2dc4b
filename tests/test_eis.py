"""In-camera-stabilised input told from the picture: the share of the body gyro's shake it keeps.

Truths are independent of the measure: a one-pole filter's analytic gain; rendered clips whose
gyro is made from the rendered motion, with or without a shake the picture does not have (its
share from band-passed variances of the known signals, not from Welch); the real GoPro clips,
whose cameras did not stabilise the picture (HERO5 on a gimbal, HERO6 handheld).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from egovid.core.camera.telemetry import CameraTelemetry, ImuSamples, OrientationSamples
from egovid.core.motion import eis
from egovid.core.motion import source as source_mod
from egovid.core.rotations import so3_log
from egovid.core.trajectory import read_motion_csv
from egovid.synth import motions
from egovid.synth.fpv import render_fpv

from conftest import real_clip

FPS = 30.0
GYRO_HZ = 400.0
#: The IMU's axes in the camera's: camera = M · IMU (the HERO5's mapping).
M = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def _one_pole_gain(a: float, f: np.ndarray, fps: float) -> np.ndarray:
    """|H(f)| of y[n] = a y[n-1] + (1 - a) x[n]."""
    return np.abs((1 - a) / (1 - a * np.exp(-2j * np.pi * f / fps)))


@pytest.mark.parametrize("cutoff_hz", [1.5, 3.0])
def test_share_of_a_low_passed_gyro_is_the_filter_gain(cutoff_hz):
    """Vision = the gyro through a one-pole low-pass (a camera that filtered its shake), plus
    vision's own noise: the share is the filter's gain averaged over the band (white gyro: flat
    weight), the RMS the white noise's band power."""
    rng = np.random.default_rng(7)
    sigma = 5.0  # deg/s per axis, white
    g = np.radians(rng.normal(0.0, sigma, (6000, 3)))
    a = np.exp(-2 * np.pi * cutoff_hz / FPS)
    v = signal.lfilter([1 - a], [1, -a], g, axis=0) + np.radians(rng.normal(0.0, 0.3 * sigma, g.shape))
    f = np.linspace(*eis.BAND_HZ, 4001)
    truth = float(np.mean(_one_pole_gain(a, f, FPS)))
    got = eis.picture_share(v, g, FPS)
    assert got.share == pytest.approx(truth, rel=0.03), (got.share, truth)
    band = eis.BAND_HZ[1] - eis.BAND_HZ[0]
    assert got.gyro_rms_deg_s == pytest.approx(sigma * np.sqrt(3 * band / (FPS / 2)), rel=0.05)
    assert got.measured == 1.0
    assert got.verdict == (eis.STABILISED if truth < eis.MAX_SHARE else eis.KEPT)


def test_verdict_needs_shake_and_measured_steps():
    assert eis.verdict(0.3, 5.0, 0.95) == eis.STABILISED
    assert eis.verdict(0.6, 5.0, 0.95) == eis.KEPT
    assert eis.verdict(0.3, 1.0, 0.95) == eis.CANNOT_TELL  # too little shake
    assert eis.verdict(0.3, 5.0, 0.8) == eis.CANNOT_TELL  # vision measured too few steps
    assert eis.verdict(float("nan"), 5.0, 1.0) == eis.CANNOT_TELL
    # No frequency in the band (a 6 fps time lapse reaches 3 Hz only) or too short a series.
    assert np.isnan(eis.band_gain(np.ones((100, 3)), np.ones((100, 3)), 3.0)[0])
    assert eis.picture_share(np.zeros((10, 3)), np.zeros((10, 3)), FPS).verdict == eis.CANNOT_TELL


# ------------------------------------------------------------------------------------------
# Rendered clips: the picture's motion is known, the gyro is made from it. Every call of
# camera_motion on the clip measures the same frame pairs (the gyro differs, not the pictures):
# shared_vision_pairs measures them once for the module.


@pytest.fixture(scope="module")
def bob_clip(tmp_path_factory):
    """480x270, 6 s: a slow look around with a 2.5 Hz head bob (in the shake band) and white
    shake; returns the clip and its true orientations."""
    out = tmp_path_factory.mktemp("eis") / "bob.mp4"
    n = 180
    angles = motions.running(n, 8.0, 0.5, 60.0) + motions.jitter(n, (0.05, 0.05, 0.03), seed=4)
    angles[:, 1] += 0.5 * np.sin(2 * np.pi * 2.5 * np.arange(n) / FPS)  # the bob: ~5.6 deg/s RMS
    render_fpv(out, angles, width=480, height=270, fps=FPS, noise_std=1.0, seed=2)
    return out, read_motion_csv(out.with_name("bob.gt.csv")).relative_to_first()


def _picture_rates(truth) -> np.ndarray:
    """(N-1, 3) rad/s of the picture between frames, camera axes."""
    R = truth.R
    return so3_log(np.swapaxes(R[:-1], 1, 2) @ R[1:]) * FPS


def _shake(n: int, rms_deg_s: float, seed: int) -> np.ndarray:
    """(n,) rad/s: band-limited (2-8 Hz) noise at the gyro rate."""
    sos = signal.butter(4, eis.BAND_HZ, "bandpass", fs=GYRO_HZ, output="sos")
    x = signal.sosfiltfilt(sos, np.random.default_rng(seed).normal(size=n))
    return np.radians(rms_deg_s) * x / x.std()


def _telemetry(truth, extra_yaw: np.ndarray | None = None, orientation=None) -> CameraTelemetry:
    """A gyro that turns as the picture does (each frame step's rate held over the step), plus
    ``extra_yaw`` rad/s about the camera's y axis; in IMU axes, 10 ms late; no EIS tag."""
    rates = _picture_rates(truth)
    t = np.arange(0.0, truth.times[-1], 1 / GYRO_HZ)
    w_cam = rates[np.minimum((t * FPS).astype(int), len(rates) - 1)]
    if extra_yaw is not None:
        w_cam[:, 1] += extra_yaw[: len(t)]
    imu = ImuSamples(t + 0.010, w_cam @ M)  # IMU = Mᵀ camera; rows: w @ M
    return CameraTelemetry(make="Test", model="EIS-less", imu=imu, image_orientation=orientation)


def _band_share_truth(truth, extra_yaw: np.ndarray) -> float:
    """The picture's share of the gyro's band power, from band-passed variances of the known
    picture rates and the shake (averaged over each frame step), which are independent."""
    pic = _picture_rates(truth)
    t = np.arange(len(extra_yaw)) / GYRO_HZ
    k = np.minimum((t * FPS).astype(int), len(pic) - 1)
    shake = np.bincount(k, extra_yaw, len(pic)) / np.maximum(np.bincount(k, None, len(pic)), 1)
    sos = signal.butter(4, eis.BAND_HZ, "bandpass", fs=FPS, output="sos")
    p_pic = float(np.sum(signal.sosfiltfilt(sos, pic, axis=0) ** 2))
    p_shake = float(np.sum(signal.sosfiltfilt(sos, shake) ** 2))
    return p_pic / (p_pic + p_shake)


def test_gyro_that_turns_with_the_picture_is_kept(bob_clip, monkeypatch, shared_vision_pairs):
    clip, truth = bob_clip
    monkeypatch.setattr(source_mod, "read_camera_telemetry", lambda path: _telemetry(truth))
    cm = source_mod.camera_motion(clip, "auto")
    assert cm.source == "gyro", cm.reason
    pic = cm.picture_share
    assert pic.verdict == eis.KEPT and pic.share == pytest.approx(1.0, abs=0.15), pic
    assert pic.gyro_rms_deg_s > 2 * eis.MIN_GYRO_RMS_DEG_S
    assert "not stabilised in the camera" in cm.reason
    assert cm.to_dict()["picture_vs_body_gyro"]["verdict"] == eis.KEPT


def test_gyro_with_shake_the_picture_lacks_is_set_aside(bob_clip, monkeypatch, shared_vision_pairs):
    """A camera that stabilised the picture and lost the tag: its body gyro carries an 11 deg/s
    shake the picture does not have. ``auto`` must not use the gyro; with the picture's
    orientation recorded it uses that, else vision."""
    clip, truth = bob_clip
    extra = _shake(int(truth.times[-1] * GYRO_HZ) + 1, 11.0, seed=5)
    expected = _band_share_truth(truth, extra)
    assert 0.15 < expected < 0.45  # the case is what it claims to be
    monkeypatch.setattr(source_mod, "read_camera_telemetry", lambda path: _telemetry(truth, extra))
    cm = source_mod.camera_motion(clip, "auto")
    assert cm.source == "vision" and "stabilised the picture itself" in cm.reason, cm.reason
    pic = cm.picture_share
    assert pic.verdict == eis.STABILISED and pic.share == pytest.approx(expected, abs=0.1), (pic, expected)
    assert cm.sync is None and cm.body_sync is not None and cm.body_sync.trusted
    doc = cm.source_dict()
    assert doc["picture_vs_body_gyro"]["verdict"] == eis.STABILISED and "gyro_sync" in doc["picture_vs_body_gyro"]
    # The vision answer follows the picture, not the shaken gyro.
    err = np.degrees(np.linalg.norm(so3_log(np.swapaxes(cm.trajectory.R, 1, 2) @ truth.R), axis=1))
    assert err.max() < 0.3, err.max()

    # The same camera recorded the picture's orientation (GoPro CORI): that is used.
    from scipy.spatial.transform import Rotation

    quat = Rotation.from_matrix(truth.R).as_quat()[:, [3, 0, 1, 2]]
    orient = OrientationSamples(truth.times, quat)
    monkeypatch.setattr(source_mod, "read_camera_telemetry", lambda path: _telemetry(truth, extra, orient))
    cm = source_mod.camera_motion(clip, "auto")
    assert cm.source == "camera-orientation" and "recorded image orientation is used" in cm.reason, cm.reason
    # Asked for by name, the gyro is used, with a note.
    monkeypatch.setattr(source_mod, "read_camera_telemetry", lambda path: _telemetry(truth, extra))
    cm = source_mod.camera_motion(clip, "gyro")
    assert cm.source == "gyro" and "seems to have stabilised" in cm.reason
    # Vision asked for by name does not lean on that gyro (no bridges, no focal fit from it).
    cm = source_mod.camera_motion(clip, "vision")
    assert cm.source == "vision" and cm.sync is None and cm.focal_fit is None and cm.body_sync is not None


# ------------------------------------------------------------------------------------------
# Real clips: cameras that did not stabilise the picture keep their gyro.


def test_real_handheld_gopro_keeps_its_gyro():
    """HERO6 handheld, no EIS tag in the file. (The HERO5 on its gimbal, with too little shake to
    tell, is checked by tests/test_cli_real_clips.py on its JSON.)"""
    cm = source_mod.camera_motion(real_clip("gopro-hero6-2s.mp4"), "auto")
    assert cm.source == "gyro", cm.reason
    assert cm.picture_share.verdict == eis.KEPT, cm.picture_share
