"""How a lens maps viewing directions to pixels: pinhole or fisheye (pure numbers).

A pinhole (rectilinear) lens puts the ray at angle ``θ`` from the optical axis at radius
``r = f tan θ`` from the principal point; a fisheye lens at ``r = f θ_d`` with OpenCV's fisheye
model ``θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`` (``k = 0``: the equidistant lens of GoPro's
wide modes, the model of Gyroflow's lens profiles). Near the axis both agree; at a 1-radian
field angle (a GoPro Wide frame's edge) the pinhole model moves a pixel by ``sec² θ ≈ 3.4`` times
what a small rotation really moves it, which is what a rotation warp built on the wrong model
shows as wobble at the frame's edges.

Rays are (…, 3) camera-axis vectors (x right, y down, z forward); pixels (…,) x and y in the
image of :class:`egovid.core.camera.intrinsics.Intrinsics` (``fx``, ``fy``, ``cx``, ``cy``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics

KINDS = ("pinhole", "fisheye")


@dataclass(frozen=True)
class Lens:
    """``kind`` pinhole or fisheye; ``k`` the fisheye model's k1..k4 (ignored for pinhole)."""

    kind: str = "pinhole"
    k: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    @property
    def fisheye(self) -> bool:
        return self.kind == "fisheye"

    def describe(self) -> str:
        """In words, e.g. ``equidistant fisheye``."""
        if not self.fisheye:
            return "pinhole"
        return "equidistant fisheye" if not any(self.k) else "fisheye k=" + ",".join(f"{x:.4g}" for x in self.k)


PINHOLE = Lens()
EQUIDISTANT = Lens("fisheye")


def _theta_d(lens: Lens, theta: np.ndarray) -> np.ndarray:
    k1, k2, k3, k4 = lens.k
    t2 = theta * theta
    return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


def _theta_of(lens: Lens, theta_d: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_theta_d` by Newton steps from ``θ = θ_d`` (monotonic over a real lens's field)."""
    if not any(lens.k):
        return theta_d
    k1, k2, k3, k4 = lens.k
    th = np.array(theta_d, dtype=float)
    for _ in range(8):
        t2 = th * th
        f = th * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d
        df = 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        th = th - f / np.where(np.abs(df) > 1e-9, df, 1e-9)
    return th


def unproject(lens: Lens, intr: Intrinsics, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """Unit-free rays (…, 3) that pixels ``(px, py)`` see (z = 1 for pinhole, unit length for fisheye)."""
    x = (np.asarray(px, float) - intr.cx) / intr.fx
    y = (np.asarray(py, float) - intr.cy) / intr.fy
    if not lens.fisheye:
        return np.stack([x, y, np.ones_like(x)], axis=-1)
    rd = np.hypot(x, y)
    th = _theta_of(lens, rd)
    s = np.where(rd > 1e-12, np.sin(th) / np.maximum(rd, 1e-12), 1.0)
    return np.stack([x * s, y * s, np.cos(th)], axis=-1)


def project(lens: Lens, intr: Intrinsics, rays: np.ndarray) -> np.ndarray:
    """Pixels (…, 2) where rays (…, 3) land; rays behind the camera (pinhole) or beyond 175° of
    field (fisheye) go to -1e6 (outside any frame)."""
    r = np.asarray(rays, float)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        if not lens.fisheye:
            ok = z > 1e-9
            u, v = x / z, y / z
        else:
            rho = np.hypot(x, y)
            th = np.arctan2(rho, z)
            ok = th < np.radians(87.5)
            s = np.where(rho > 1e-12, _theta_d(lens, th) / np.maximum(rho, 1e-12), 1.0 / np.maximum(z, 1e-12))
            u, v = x * s, y * s
    px = np.where(ok, intr.fx * u + intr.cx, -1e6)
    py = np.where(ok, intr.fy * v + intr.cy, -1e6)
    return np.stack([px, py], axis=-1)
