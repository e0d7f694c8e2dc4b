"""A stabiliser test bed: many real-like shaky clips whose truth is known.

Each :class:`Case` is a camera motion made of two known parts, rendered on the panorama sphere of
:mod:`egovid.synth.render`:

* the **intended** motion (what a stabiliser should keep): walking (head bob and sway, a slow
  look around), running (the thesis' running stride), driving (a slow turn, a gentle road
  pitch), panning (a 40° eased pan between still stretches);
* the **shake** (what it should remove): hand shake (band-limited noise, 1.5–8 Hz), a real
  camera's gyro log replayed (the GoPro HERO5 and HERO6 clips' own GPMF gyros in
  ``../shared/data/real``, band 0.7–12 Hz, scaled to the case's amplitude with the log's own axis
  ratios and spectrum), road vibration (6–15 Hz), or the small high-frequency residual that an
  in-camera stabiliser leaves (5–15 Hz, a few hundredths of a degree).

Cases vary what a stabiliser meets in the wild: 24/25/30/50/60 fps, action-cam (98°) and phone
(68°) fields of view, global and rolling shutter (rows read out top to bottom over ``readout_s``,
rendered band by band at their own time), landscape, portrait, and landscape-coded files with a
90° rotation flag (a phone held upright; its sensor rows are then display columns), H.264 and
HEVC. Angles are degrees, yaw/pitch/roll as in :mod:`egovid.core.rotations`; times in seconds.

The truth is exact: :meth:`CaseTruth.orientation` gives the camera orientation at any time (any
row), :attr:`CaseTruth.intended` and :attr:`CaseTruth.shake` the two parts at the frame times
(frame k starts its readout at ``k / fps``; the per-frame orientation is that of the centre row).
Cases with ``has_gyro`` come with a 200 Hz "gyro" (the true orientation sampled; an in-camera
stabilised picture has none that describes it).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.camera.telemetry import read_camera_telemetry
from egovid.core.errors import EgovidError
from egovid.core.rotations import matrix_from_euler
from egovid.core.trajectory import Trajectory
from egovid.core.video import VideoWriter
from egovid.synth.fpv import scene_panorama
from egovid.synth.render import SphereRenderer

MOTIONS = ("walk", "run", "drive", "pan")
SHAKES = ("hand", "gyro-hero5", "gyro-hero6", "vibration", "eis-residual")
#: Real clips whose gyro logs are replayed (file names in ../shared/data/real).
GYRO_LOGS = {"gyro-hero5": "gopro-hero5-karma.mp4", "gyro-hero6": "gopro-hero6-2s.mp4"}
#: Rate of the test bed's "gyro" (Hz).
GYRO_RATE_HZ = 200.0
#: Frequency bands (Hz) of each kind of shake.
_BANDS = {
    "hand": (1.5, 8.0),
    "gyro-hero5": (0.7, 12.0),
    "gyro-hero6": (0.7, 12.0),
    "vibration": (6.0, 15.0),
    "eis-residual": (5.0, 15.0),
}
#: Per-axis share of the shake amplitude (yaw, pitch, roll) for the synthetic kinds.
_AXIS_SHARE = np.array([1.0, 1.0, 0.6])
#: Angular speed (°/s, below 0.7 Hz) above which a gyro log is moving on purpose, not shaking.
_STEADY_DEG_S = 10.0
#: Grid on which shake is defined before interpolation to frame and row times (Hz).
_SHAKE_GRID_HZ = 1000.0


@dataclass(frozen=True)
class Case:
    """One test-bed clip (see the module docstring). ``width``/``height`` are the display size in
    pixels; ``rotation`` the file's rotation flag (0 or 90: coded landscape, shown portrait);
    ``hfov_deg`` the field of view across the long side; ``readout_s`` the rolling-shutter
    readout time (0 = global shutter); ``shake_deg`` the RMS amplitude of the shake per axis
    (degrees, yaw scale); ``seconds`` the clip length."""

    name: str
    motion: str
    shake: str
    fps: float = 30.0
    width: int = 640
    height: int = 360
    rotation: int = 0
    hfov_deg: float = 98.3
    readout_s: float = 0.0
    shake_deg: float = 0.3
    seconds: float = 5.0
    codec: str = "libx264"
    seed: int = 0

    @property
    def frames(self) -> int:
        return round(self.seconds * self.fps)

    @property
    def has_gyro(self) -> bool:
        """A body gyro that describes the picture (not after in-camera stabilisation)."""
        return self.shake != "eis-residual"

    def intrinsics(self) -> Intrinsics:
        """Pinhole intrinsics in display orientation (focal length from the long side)."""
        long_side = max(self.width, self.height)
        focal = long_side / 2.0 / np.tan(np.radians(self.hfov_deg) / 2.0)
        return Intrinsics.from_focal(self.width, self.height, focal)


def default_cases() -> list[Case]:
    """The benchmark's cases: every motion, every shake, every frame rate, both shutters, both
    orientations and the rotation flag, each at least once (13 clips of 4-5 s at 640 px)."""
    return [
        Case("walk-30-hand", "walk", "hand"),
        Case("walk-30-gyro5", "walk", "gyro-hero5", shake_deg=0.35, seed=1),
        Case("run-30-gyro6", "run", "gyro-hero6", shake_deg=0.4, seed=2),
        Case("run-60-hand", "run", "hand", fps=60.0, seconds=4.0, seed=3),
        Case("pan-30-hand", "pan", "hand", shake_deg=0.25, seed=4),
        Case("pan-50-gyro5", "pan", "gyro-hero5", fps=50.0, seconds=4.0, seed=5),
        Case("drive-25-vibration", "drive", "vibration", fps=25.0, shake_deg=0.12, seed=6),
        Case("drive-24-rs", "drive", "hand", fps=24.0, readout_s=0.025, shake_deg=0.2, seed=7),
        Case("walk-24-eis", "walk", "eis-residual", fps=24.0, shake_deg=0.05, seed=8),
        Case("run-60-eis", "run", "eis-residual", fps=60.0, seconds=4.0, shake_deg=0.04, seed=9),
        Case("walk-30-portrait", "walk", "hand", width=360, height=640, hfov_deg=68.0, seed=10),
        Case(
            "walk-30-phone-rotated",
            "walk",
            "hand",
            width=360,
            height=640,
            rotation=90,
            hfov_deg=68.0,
            readout_s=0.03,
            codec="libx265",
            seed=11,
        ),
        Case("pan-60-phone-rs", "pan", "gyro-hero6", fps=60.0, seconds=4.0, hfov_deg=68.0, readout_s=0.02, seed=12),
    ]


# --------------------------------------------------------------------------------------------
# Motions as functions of time.


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3 - 2 * u)


def intended_motion(kind: str, t: np.ndarray, seed: int = 0) -> np.ndarray:
    """(len(t), 3) intended yaw, pitch, roll in degrees at times ``t`` (seconds)."""
    t = np.asarray(t, dtype=float)
    ph = np.random.default_rng(seed).uniform(0, 2 * np.pi, 4)
    tau = 2 * np.pi
    z = np.zeros_like(t)
    if kind == "walk":  # a step at 1.8 Hz: pitch bob per step, yaw and roll sway per stride
        yaw = 1.2 * np.sin(tau * 0.9 * t + ph[0]) + 8.0 * np.sin(tau * 0.08 * t + ph[1])
        pitch = 0.8 * np.sin(tau * 1.8 * t + 2 * ph[0]) + 2.0 * np.sin(tau * 0.05 * t + ph[2])
        roll = 1.0 * np.sin(tau * 0.9 * t + ph[0] - np.pi / 2)
    elif kind == "run":  # the thesis' running: yaw per stride, pitch twice as fast
        yaw = 5.0 * np.sin(tau * 1.3 * t + ph[0])
        pitch = 2.0 * np.sin(tau * 2.6 * t + 2 * ph[0])
        roll = 1.5 * np.sin(tau * 1.3 * t + ph[0] - np.pi / 2)
    elif kind == "drive":  # a 25° turn over 2.5 s and a gentle road pitch
        yaw = 25.0 * _smoothstep((t - 1.5) / 2.5)
        pitch = 0.4 * np.sin(tau * 0.3 * t + ph[1])
        roll = z
    elif kind == "pan":  # still, a 40° eased pan, still
        yaw = 40.0 * _smoothstep((t - 1.0) / 2.0)
        pitch = 1.0 * _smoothstep((t - 1.0) / 2.0)
        roll = z
    else:
        raise EgovidError(f"unknown test-bed motion {kind!r}", f"choose one of {', '.join(MOTIONS)}")
    return np.stack([yaw, pitch, roll], axis=1)


def _band(x: np.ndarray, rate: float, band: tuple[float, float]) -> np.ndarray:
    """Zero-phase Butterworth band-pass (order 4) of the columns of ``x`` sampled at ``rate``."""
    from scipy.signal import butter, sosfiltfilt

    sos = butter(4, band, btype="bandpass", fs=rate, output="sos")
    return sosfiltfilt(sos, x, axis=0)


@lru_cache(maxsize=4)
def _gyro_angles(log: str, real_dir: str) -> tuple[np.ndarray, np.ndarray]:
    """(times s, (N, 3) yaw, pitch, roll degrees): the integral of a real clip's gyro, in camera
    axes (GoPro: camera x, y, z = IMU -y, -x, -z, as egovid's sync finds on the HERO5 clip)."""

    path = Path(real_dir) / GYRO_LOGS[log]
    if not path.exists():
        raise EgovidError(f"the gyro log {path} is not there", "run from the repository next to ../shared")
    imu = read_camera_telemetry(path).imu
    if imu is None:
        raise EgovidError(f"{path} holds no gyro", "check ../shared/data/real")
    t = np.asarray(imu.times, float)
    w = np.degrees(np.asarray(imu.gyro, float))
    cam = np.stack([-w[:, 1], -w[:, 0], -w[:, 2]], axis=1)  # rates about camera x, y, z
    rates = np.stack([cam[:, 1], cam[:, 0], cam[:, 2]], axis=1)  # yaw (y), pitch (x), roll (z)
    ang = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (rates[1:] + rates[:-1]) * np.diff(t)[:, None], 0)])
    return t - t[0], ang


def shake_motion(
    kind: str,
    t: np.ndarray,
    amplitude_deg: float,
    seed: int = 0,
    real_dir: str | os.PathLike | None = None,
    seconds: float = 10.0,
) -> np.ndarray:
    """(len(t), 3) shake in degrees at times ``t`` (seconds from 0) of a clip ``seconds`` long:
    RMS ``amplitude_deg`` over the clip (on the yaw scale; see :data:`_AXIS_SHARE` and, for gyro
    logs, the log's own axis ratios). The shake depends on the clip, not on the times asked."""
    if kind not in SHAKES:
        raise EgovidError(f"unknown test-bed shake {kind!r}", f"choose one of {', '.join(SHAKES)}")
    t = np.asarray(t, dtype=float)
    sh, grid = _shake_grid(kind, float(amplitude_deg), int(seed), str(real_dir or default_real_dir()), float(seconds))
    return np.stack([np.interp(t, grid, sh[:, i]) for i in range(3)], axis=1)


@lru_cache(maxsize=32)
def _shake_grid(kind: str, amplitude_deg: float, seed: int, real_dir: str, seconds: float):
    """The shake of a clip on a 1 kHz grid from 0 to ``seconds`` + 2 s, and that grid."""
    grid = np.arange(0.0, seconds + 2.0, 1.0 / _SHAKE_GRID_HZ)
    if kind in GYRO_LOGS:
        gt, ga = _gyro_angles(kind, real_dir)
        rate = 1.0 / float(np.median(np.diff(gt)))
        even = np.arange(0.0, gt[-1], 1.0 / rate)
        ga = np.stack([np.interp(even, gt, ga[:, i]) for i in range(3)], axis=1)
        # Only the log's steady stretch is shake: a fast intentional turn (the HERO5 clip ends
        # with a pan) would pass the band as one large transient.
        slow = _band(ga - ga.mean(0), rate, (0.05, 0.7))
        speed = np.linalg.norm(np.gradient(slow, 1.0 / rate, axis=0), axis=1)
        ok = speed < _STEADY_DEG_S
        runs = np.flatnonzero(np.diff(np.r_[0, ok.astype(int), 0]))
        a, b = max(zip(runs[::2], runs[1::2], strict=True), key=lambda r: r[1] - r[0])
        seg = ga[a:b] - ga[a:b].mean(0)
        sh = _band(seg, rate, _BANDS[kind])
        even = even[: b - a]
        # Longer clips than the log: the log played forwards and backwards (continuous angle).
        n_rep = int(np.ceil(grid[-1] / even[-1])) + 1
        tiled = np.concatenate([sh if r % 2 == 0 else sh[::-1] for r in range(n_rep)])
        tt = np.arange(len(tiled)) / rate
        start = np.random.default_rng(seed).uniform(0.0, max(even[-1] - 1.0, 0.0))
        sh = np.stack([np.interp(grid + start, tt, tiled[:, i]) for i in range(3)], axis=1)
        used = grid <= seconds  # scaled where the clip plays it
        scale = amplitude_deg / max(float(np.sqrt(np.mean(sh[used, :2] ** 2))), 1e-12)
        sh = sh * scale
    else:
        rng = np.random.default_rng(1000 + seed)
        noise = rng.normal(0.0, 1.0, (len(grid), 3))
        sh = _band(noise, _SHAKE_GRID_HZ, _BANDS[kind])
        sh = sh / sh.std(axis=0) * amplitude_deg * _AXIS_SHARE
    return sh, grid


def default_real_dir() -> Path:
    """``../shared/data/real`` next to the repository root."""
    return Path(__file__).resolve().parents[3].parent / "shared" / "data" / "real"


# --------------------------------------------------------------------------------------------
# Truth and rendering.


@dataclass
class CaseTruth:
    """The exact motion of a case. ``times`` (K,) frame (readout start) times; ``intended`` and
    ``shake`` (K, 3) degrees at each frame's centre row; ``angles`` their sum (what the camera
    did); ``gyro`` the camera's orientation at :data:`GYRO_RATE_HZ` (None without a gyro)."""

    case: Case
    times: np.ndarray
    intended: np.ndarray
    shake: np.ndarray
    gyro: Trajectory | None = field(repr=False, default=None)
    real_dir: str | None = None

    @property
    def angles(self) -> np.ndarray:
        return self.intended + self.shake

    @property
    def frame_centre_times(self) -> np.ndarray:
        """Times (s) at which each frame's centre row was read."""
        return self.times + 0.5 * self.case.readout_s

    def orientation(self, t: np.ndarray) -> np.ndarray:
        """(len(t), 3) true yaw, pitch, roll in degrees at times ``t`` (seconds)."""
        c = self.case
        shake = shake_motion(c.shake, t, c.shake_deg, c.seed, self.real_dir, c.seconds)
        return intended_motion(c.motion, t, c.seed) + shake

    def trajectory(self) -> Trajectory:
        """The true per-frame motion as a trajectory (frame 0 relative orientation kept as is)."""
        return Trajectory.from_euler(self.times, self.angles)


def case_truth(case: Case, real_dir: str | os.PathLike | None = None) -> CaseTruth:
    """The exact motion of ``case`` (see :class:`CaseTruth`)."""
    rd = str(real_dir) if real_dir is not None else None
    times = np.arange(case.frames) / case.fps
    tc = times + 0.5 * case.readout_s
    intended = intended_motion(case.motion, tc, case.seed)
    shake = shake_motion(case.shake, tc, case.shake_deg, case.seed, rd, case.seconds)
    truth = CaseTruth(case, times, intended, shake, None, rd)
    if case.has_gyro:
        tg = np.arange(0.0, times[-1] + case.readout_s + 0.1, 1.0 / GYRO_RATE_HZ)
        truth.gyro = Trajectory.from_euler(tg, truth.orientation(tg))
    return truth


def _coded_rotation(rotation: int) -> np.ndarray:
    """Display camera -> coded (sensor) camera for a file with rotation flag ``rotation``: the
    display image is the coded one turned ``rotation`` degrees counter-clockwise."""
    a = -np.radians(rotation)
    # Turning the image counter-clockwise by a = the camera rolled clockwise by a.
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def render_case(
    case: Case, out: str | os.PathLike, *, real_dir: str | os.PathLike | None = None, crf: int = 16, bands: int = 24
) -> CaseTruth:
    """Render ``case`` to ``out`` (MP4) and return its truth. Rolling shutter: the sensor rows are
    read in ``bands`` bands, each rendered with the orientation at its own time."""

    truth = case_truth(case, real_dir)
    intr = case.intrinsics()
    coded_w, coded_h = (case.height, case.width) if case.rotation in (90, 270) else (case.width, case.height)
    coded = Intrinsics.from_focal(coded_w, coded_h, intr.focal)
    pano_w = int(np.clip(round(360.0 / min(intr.hfov_deg, 100.0) * max(coded_w, coded_h) / 1024.0) * 1024, 2048, 8192))
    renderer = SphereRenderer(scene_panorama("panorama", pano_w, case.seed % 3), coded)
    C = _coded_rotation(case.rotation)
    n_bands = bands if case.readout_s > 0 else 1
    edges = np.linspace(0, coded_h, n_bands + 1).round().astype(int)
    centres = 0.5 * (edges[:-1] + edges[1:]) / coded_h
    k_rot = (case.rotation // 90) % 4
    with VideoWriter(out, case.width, case.height, case.fps, codec=case.codec, crf=crf, rotation=case.rotation) as w:
        for _k, t0 in enumerate(truth.times):
            tb = t0 + centres * case.readout_s
            ang = truth.orientation(tb)
            Rb = matrix_from_euler(ang[:, 0], ang[:, 1], ang[:, 2]) @ C
            img = renderer.render(Rb[0]) if n_bands == 1 else renderer.render_rolling(list(Rb))
            w.write(np.ascontiguousarray(np.rot90(img, k_rot)), float(t0))
    return truth
