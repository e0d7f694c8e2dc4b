"""Perspective rendering of synthetic scenes with exact camera poses.

:class:`SphereRenderer` paints an equirectangular panorama on a sphere around the origin and
renders pinhole views of it for a camera orientation (camera-to-world ``R``, see
:mod:`egovid.core.rotations`) and position. With the camera at the centre the views are those
of a pure rotation; moving it (e.g. slowly forward) adds real parallax, as two-view odometers
need.
"""

from __future__ import annotations

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics


class SphereRenderer:
    """Views of a panorama on a sphere of ``radius`` metres (world axes: x right, y down, z ahead).

    Parameters
    ----------
    panorama:
        Equirectangular HxWx3 image (W = 2H); longitude 0 at the centre column, up at the top.
    intrinsics:
        The virtual camera.
    radius:
        Sphere radius in metres; only matters when the camera moves away from the centre.
    """

    def __init__(self, panorama: np.ndarray, intrinsics: Intrinsics, radius: float = 10.0) -> None:
        self.pano = panorama
        self.intr = intrinsics
        self.radius = float(radius)
        h, w = intrinsics.height, intrinsics.width
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
        rays = intrinsics.K_inv @ pix
        rays /= np.linalg.norm(rays, axis=0, keepdims=True)
        self._rays = rays.astype(np.float32)  # (3, H*W) unit bearings in camera coordinates
        ph, pw = panorama.shape[:2]
        self._sx = np.float32(pw / (2 * np.pi))
        self._sy = np.float32(ph / np.pi)

    def maps(
        self, R: np.ndarray, position: np.ndarray | None = None, rows: tuple[int, int] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Remap tables (x, y) into the panorama for a camera at ``position`` with orientation ``R``;
        only image rows ``rows = (first, stop)`` when given."""
        h, w = self.intr.height, self.intr.width
        a, b = rows if rows is not None else (0, h)
        d = R.astype(np.float32) @ self._rays[:, a * w : b * w]  # world directions
        if position is not None and np.any(position):
            c = np.asarray(position, dtype=np.float32).reshape(3, 1)
            cd = (c * d).sum(axis=0)
            cc = float((c * c).sum())
            t = -cd + np.sqrt(np.maximum(cd * cd - cc + self.radius**2, 0.0))
            d = c + d * t
        dx, dy, dz = d[0], d[1], d[2]
        lon = cv2.phase(dz, dx)  # atan2(dx, dz) in [0, 2pi)
        lon = np.where(lon > np.pi, lon - 2 * np.pi, lon)
        lat = cv2.phase(cv2.magnitude(dx, dz), -dy)
        lat = np.where(lat > np.pi, lat - 2 * np.pi, lat)
        pw = self.pano.shape[1]
        map_x = (lon * self._sx + np.float32(pw / 2 - 0.5)).reshape(b - a, w)
        map_y = ((np.float32(np.pi / 2) - lat) * self._sy - np.float32(0.5)).reshape(b - a, w)
        return map_x, map_y

    def render_rolling(self, rotations: list[np.ndarray], position: np.ndarray | None = None) -> np.ndarray:
        """A rolling-shutter view: the rows are split into ``len(rotations)`` bands, band i read
        out with orientation ``rotations[i]`` (top band first)."""
        h = self.intr.height
        bands = np.linspace(0, h, len(rotations) + 1).round().astype(int)
        mx = np.empty((h, self.intr.width), np.float32)
        my = np.empty_like(mx)
        for R, a, b in zip(rotations, bands[:-1], bands[1:], strict=True):
            mx[a:b], my[a:b] = self.maps(R, position, rows=(a, b))
        return cv2.remap(self.pano, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)

    def render(self, R: np.ndarray, position: np.ndarray | None = None) -> np.ndarray:
        """HxWx3 BGR view for orientation ``R`` (camera-to-world) at ``position`` (metres)."""
        mx, my = self.maps(R, position)
        return cv2.remap(self.pano, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
