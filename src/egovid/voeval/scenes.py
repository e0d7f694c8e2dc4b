"""Controlled test videos with known rotation (thesis §21.2, §21.4) and the factor pairs.

Two kinds of video, as in the thesis:

* **orbit** — a camera orbiting on a circle of radius r at distance d above a planar picture,
  always looking at its centre, with no rotation about its optical axis (eq. 21.1–21.6); the
  picture is rendered through the exact plane-to-image homography. Used for factors 1–3.
* **pano** — the first-person "running" motion (yaw and pitch sines, pitch at twice the yaw
  rate) rendered from the panorama sphere of radius 10 m, the camera dollying forward and
  back (:func:`dolly`: up to 2 cm per frame, at most 0.6 m from the centre) so two-view
  methods can initialise while the motion stays nearly a pure rotation. Used for factor 4,
  whose challenging scene adds rolling shutter (rows read out over
  0.9 frame) and motion blur (5 sub-frames over half a frame).

Scenes (each pair differs in one factor only, everything else fixed):

=============  ==============================================
factor         ideal scene → challenging scene
=============  ==============================================
feature        orbit-ideal → orbit-fog (fog, 25 % contrast)
data           orbit-ideal → orbit-unseen (pictures never shown to a learned model)
sensor         orbit-ideal → orbit-sensor (noise, vignetting, over-exposure)
motion         pano-ideal  → pano-motion (rolling shutter, motion blur)
compression    every scene at H.264 CRF 18 … 48 and lossless
=============  ==============================================

The thesis drew these from KITTI / Virtual KITTI and its own recordings; here every factor is
synthesised from photos bundled with scikit-image, so each one can be switched on alone.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_text
from egovid.core.rotations import matrix_from_euler
from egovid.core.trajectory import Trajectory, read_tum, write_tum
from egovid.core.video import VideoWriter
from egovid.synth import effects
from egovid.synth.fpv import scene_panorama
from egovid.synth.photos import photo
from egovid.synth.render import SphereRenderer

#: Pictures a learned odometer would have been trained on, and pictures it never saw.
LEARNED = ("astronaut", "coffee", "rocket", "chelsea")
UNSEEN = ("stereo_motorcycle", "cat", "grace_hopper", "colorwheel")

SCENES = ("orbit-ideal", "orbit-fog", "orbit-unseen", "orbit-sensor", "pano-ideal", "pano-motion")
FACTORS = {
    "feature": ("orbit-ideal", "orbit-fog"),
    "data": ("orbit-ideal", "orbit-unseen"),
    "sensor": ("orbit-ideal", "orbit-sensor"),
    "motion": ("pano-ideal", "pano-motion"),
}


#: How the camera moves in each kind of scene: an odometer that models pure rotation cannot work
#: on a "translating" scene by design (see :func:`egovid.voeval.recommend.in_domain`).
MOTION = {"orbit": "translating", "pano": "rotating"}


@dataclass
class SceneTruth:
    """Ground truth of a test video: camera-to-world rotations (N, 3, 3) relative to frame 0,
    the camera, the frame rate, frame times (N,) in seconds (default ``index / fps``), camera
    positions ``t`` (N, 3) relative to frame 0 in the first camera's axes (None: the reference has
    no positions, e.g. a gyro; units in ``meta["translation_unit"]``) and a description (``meta``:
    kind synthetic/real/derived, motion translating/rotating/general, source, format)."""

    name: str
    R: np.ndarray
    intrinsics: Intrinsics
    fps: float
    times: np.ndarray | None = None
    meta: dict | None = None
    t: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.times is None:
            self.times = np.arange(len(self.R)) / self.fps
        if self.meta is None:
            self.meta = {}

    @property
    def motion(self) -> str:
        """ "translating", "rotating" or "general" (real recordings)."""
        return self.meta.get("motion", MOTION.get(self.name.split("-")[0], "general"))

    @property
    def dataset(self) -> str:
        """The kind of footage: ``synthetic`` or a ``--sequence`` format (euroc, tum, kitti, frames, gyro)."""
        return self.meta.get("format", "synthetic")

    def save(self, folder: Path) -> None:
        """Write ``NAME.gt.tum`` and ``NAME.json`` (atomically, the JSON last)."""
        write_tum(folder / f"{self.name}.gt.tum", Trajectory(self.times, self.R, self.t))
        i = self.intrinsics
        meta = {
            **self.meta,
            "name": self.name,
            "fps": self.fps,
            "width": i.width,
            "height": i.height,
            "fx": i.fx,
            "fy": i.fy,
            "cx": i.cx,
            "cy": i.cy,
            "frames": len(self.R),
            "motion": self.motion,
            "has_translation": self.t is not None,
        }
        atomic_write_text(folder / f"{self.name}.json", json.dumps(meta, indent=1))

    @classmethod
    def load(cls, folder: Path, name: str) -> SceneTruth:
        meta = json.loads((folder / f"{name}.json").read_text())
        intr = Intrinsics(meta["width"], meta["height"], meta["fx"], meta["fy"], meta["cx"], meta["cy"])
        traj = read_tum(folder / f"{name}.gt.tum")
        t = traj.t if meta.get("has_translation") else None
        return cls(name, traj.R, intr, meta["fps"], traj.times, meta, t)


def relative_to_first(R: np.ndarray, t: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Camera-to-world poses (R (N, 3, 3), camera centres t (N, 3)) expressed in the first
    camera's frame: ``R0ᵀ R``, ``R0ᵀ (t - t0)``."""
    R0T = np.swapaxes(R[0], -1, -2)
    return R0T @ R, (None if t is None else (np.asarray(t, float) - t[0]) @ R0T.T)


def lossless_writer(path: Path, width: int, height: int, fps: float) -> VideoWriter:
    """The writer of every lossless test video (scenes, real imports, degraded copies): H.264 in
    RGB at QP 0 (x264 ``libx264rgb``, preset ultrafast, tune zerolatency, one thread), in ``.mkv``.

    Bit-exact like FFV1, which it replaced: the decoded BGR frames, and the grey and downscaled
    frames the odometers ask FFmpeg for, are identical pixel for pixel (checked on the 640x480
    scenes), and the files are as large; but it encodes about 4 times and decodes about 3 times
    faster than FFV1's RGB mode, and every cell at the lossless level and every ladder task
    decodes one. ``zerolatency``: no frame delay (each frame's packet comes out at once, as with
    FFV1)."""
    opts = {"qp": "0", "preset": "ultrafast", "tune": "zerolatency"}
    return VideoWriter(
        path, width, height, fps, codec="libx264rgb", pix_fmt="bgr24", crf=None, preset=None, options=opts, threads=1
    )


def mosaic(names: tuple[str, ...], size: int = 1024, order: np.ndarray | None = None) -> np.ndarray:
    """A 2 x 2 mosaic of photos (size x size BGR), tiles in ``order`` (default: as given)."""
    half = size // 2
    names = tuple(names[i] for i in order) if order is not None else names
    tiles = [cv2.resize(photo(n), (half, half), interpolation=cv2.INTER_AREA) for n in names[:4]]
    return np.vstack([np.hstack(tiles[:2]), np.hstack(tiles[2:4])])


def orbit_pose(t: float, r: float, d: float, omega: float, phase: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Camera centre and camera-to-world rotation on the orbit at time t (eq. 21.1–21.5): the
    picture lies in the plane Z = 0 centred at the origin; the camera looks at the origin with its
    x axis along the projection of the world X axis (no rotation about the optical axis).
    ``phase`` (radians) starts the orbit elsewhere on the circle."""
    c = np.array([r * math.cos(omega * t + phase), -r * math.sin(omega * t + phase), d])
    z = -c / np.linalg.norm(c)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return c, np.stack([x, y, z], axis=1)


def render_orbit(picture: np.ndarray, intr: Intrinsics, c: np.ndarray, R: np.ndarray, width_units: float = 2.0):
    """The view of ``picture`` (spanning ``width_units`` in X, centred) from centre ``c``, rotation ``R``."""
    ph, pw = picture.shape[:2]
    s = pw / width_units
    # World +Y is "up" on the picture (its rows grow downwards, towards -Y).
    S = np.array([[s, 0, pw / 2.0], [0, -s, ph / 2.0], [0, 0, 1.0]])
    L = np.array([[-c[2], 0, c[0]], [0, -c[2], c[1]], [0, 0, 1.0]])
    H = S @ L @ R @ intr.K_inv  # camera pixel -> picture pixel
    return cv2.warpPerspective(
        picture,
        H,
        (intr.width, intr.height),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REFLECT,
    )


def running_angles(
    frames: np.ndarray, yaw: float = 6.0, pitch: float = 1.5, period: float = 24.0, phase: float = 0.0
) -> np.ndarray:
    """Running motion at (fractional) frame times: yaw and pitch sines, pitch at twice the rate,
    degrees; ``phase`` shifts the time origin by that many frames."""
    w = 2 * np.pi / period
    f = np.asarray(frames, dtype=float) + phase
    return np.stack([yaw * np.sin(w * f), pitch * np.sin(2 * w * f), 0.3 * np.sin(w * f - 1.0)], axis=-1)


def dolly(frame: float, amplitude: float = 0.3, period: float = 96.0) -> float:
    """Forward position (metres) of the pano camera at ``frame``: it walks forward and back,
    ``amplitude * (1 - cos(2π frame / period))`` — at most 2 cm per frame (parallax for two-view
    methods) and never more than 0.6 m from the centre of the 10 m sphere (so the scene stays
    "rotating": a 300-frame walk straight ahead would end 4 m from the wall)."""
    return amplitude * (1.0 - math.cos(2 * math.pi * frame / period))


def render_scene(
    name: str, out: Path, *, frames: int = 48, width: int = 320, height: int = 240, fps: float = 30.0, seed: int = 0
) -> SceneTruth:
    """Render one scene losslessly (:func:`lossless_writer`, .mkv) and return its ground truth
    (rotations and camera positions: orbit in units of the orbit's distance to the picture, pano
    in metres).

    ``seed`` varies what a repeated run should not depend on, identically for the ideal and the
    challenging scene of a factor: the orbit's start and direction, the order of the photos in
    the mosaic, the panorama, the phase of the running motion, and the sensor noise. Seed 0 is
    the canonical scene (orbit from angle 0, photos in the listed order).
    """
    if name not in SCENES:
        raise EgovidError(f"unknown scene {name!r}", f"choose from {', '.join(SCENES)}")
    kind = name.split("-")[0]
    views = _orbit_views if kind == "orbit" else _pano_views
    intr, frames_iter = views(name, frames, width, height, seed)
    Rs, cs = [], []
    with lossless_writer(out, width, height, fps) as w:
        for k, (img, R, c) in enumerate(frames_iter):
            w.write(img, k / fps)
            Rs.append(R)
            cs.append(c)
    R, t = relative_to_first(np.stack(Rs), np.stack(cs))
    unit = "orbit distance (1 = camera to picture)" if kind == "orbit" else "m"
    meta = {"kind": "synthetic", "motion": MOTION[kind], "seed": seed, "translation_unit": unit}
    return SceneTruth(name, R, intr, fps, meta=meta, t=t)


def _seeded(seed: int) -> tuple[float, float, np.ndarray | None, np.random.Generator]:
    """(start phase in radians, orbit direction, photo order, noise generator) of a seed."""
    rng_motion, rng_pictures, rng_noise = (np.random.default_rng([seed, k]) for k in range(3))
    phase = float(rng_motion.uniform(0, 2 * math.pi)) if seed else 0.0
    direction = float(rng_motion.choice([-1.0, 1.0])) if seed else 1.0
    order = rng_pictures.permutation(4) if seed else None
    return phase, direction, order, rng_noise


def _orbit_views(name: str, frames: int, width: int, height: int, seed: int):
    """(intrinsics, iterator of (BGR image, camera-to-world R, camera centre)) of an orbit scene."""
    phase, direction, order, rng_noise = _seeded(seed)
    intr = Intrinsics.from_hfov(width, height, 60.0)
    picture = mosaic(UNSEEN if name == "orbit-unseen" else LEARNED, order=order)
    omega = direction * 2 * math.pi / frames

    def views():
        for k in range(frames):
            c, R = orbit_pose(k, 0.25, 1.0, omega, phase)
            img = render_orbit(picture, intr, c, R)
            if name == "orbit-fog":
                img = effects.fog(img, 0.75)
            elif name == "orbit-sensor":
                img = effects.sensor(img, rng_noise)
            yield img, R, c

    return intr, views()


def _pano_views(name: str, frames: int, width: int, height: int, seed: int):
    """(intrinsics, iterator of (BGR image, camera-to-world R, camera centre)) of a pano scene;
    pano-motion's rotation is the one at the middle of its exposure and readout."""
    phase = _seeded(seed)[0]
    intr = Intrinsics.from_hfov(width, height, 75.0)
    rend = SphereRenderer(scene_panorama("panorama", 2048, seed), intr)
    stride = phase / (2 * math.pi) * 24.0  # the seed's start, in frames of the 24-frame stride

    def views():
        for k in range(frames):
            pos = np.array([0.0, 0.0, dolly(k)])
            if name == "pano-motion":
                readout, exposure, sub = 0.9, 0.5, 5
                subs = []
                for j in range(sub):
                    t0 = k + exposure * j / (sub - 1)
                    ts = t0 + readout * np.linspace(0, 1, 16)
                    a = running_angles(ts, phase=stride)
                    subs.append(rend.render_rolling(list(matrix_from_euler(a[:, 0], a[:, 1], a[:, 2])), pos))
                img = effects.blur_average(subs)
                a = running_angles(np.array([k + exposure / 2 + readout / 2]), phase=stride)[0]
            else:
                a = running_angles(np.array([k]), phase=stride)[0]
                img = rend.render(matrix_from_euler(*a), pos)
            yield img, matrix_from_euler(*a), pos

    return intr, views()
