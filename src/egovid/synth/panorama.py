"""An equirectangular panorama built from bundled photos.

No installed package ships a 360° image, so egovid tiles photos onto the sphere: a band of
photos around the horizon (where the camera looks most), smaller bands above and below, and
ground and sky textures at the poles. Each tile is resized to the angular size it covers, so
objects keep a natural scale in a perspective view. The layout is deterministic for a seed.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from egovid.synth.photos import COLOUR, GREY, photo

#: Latitude bands (degrees, top to bottom) and the number of tiles around the sphere in each.
_BANDS = ((90.0, 55.0, 4), (55.0, 18.0, 7), (18.0, -18.0, 8), (-18.0, -55.0, 7), (-55.0, -90.0, 4))


@functools.lru_cache(maxsize=8)
def _panorama_cached(width: int, seed: int) -> np.ndarray:
    height = width // 2
    rng = np.random.default_rng(seed)
    pano = np.zeros((height, width, 3), np.uint8)
    names = list(COLOUR) + list(GREY)
    textures = ["grass", "gravel", "brick"]
    for top, bottom, count in _BANDS:
        y0 = round((90.0 - top) / 180.0 * height)
        y1 = round((90.0 - bottom) / 180.0 * height)
        polar = top == 90.0 or bottom == -90.0
        offset = rng.uniform(0, width / count)
        order = rng.permutation(len(names))
        for k in range(count):
            x0 = round(offset + k * width / count)
            x1 = round(offset + (k + 1) * width / count)
            name = textures[(k + (y0 > 0)) % len(textures)] if polar else names[order[k % len(names)]]
            img = photo(name)
            if rng.random() < 0.5 and not polar:
                img = img[:, ::-1]
            tile = cv2.resize(img, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
            # Tint grey tiles so colour statistics vary across the sphere.
            if name in GREY:
                tint = rng.uniform(0.75, 1.15, size=3)
                tile = np.clip(tile.astype(np.float32) * tint, 0, 255).astype(np.uint8)
            xs = np.arange(x0, x1) % width
            pano[y0:y1, xs] = tile
    return pano


def build_panorama(width: int = 4096, seed: int = 0) -> np.ndarray:
    """An equirectangular BGR panorama of ``width`` x ``width/2`` pixels (read-only, cached).

    Longitude 0 (looking along +z) is the image centre column; latitude +90° (up) the top row.
    """
    if width < 64 or width % 2:
        raise ValueError("panorama width must be an even number >= 64")
    pano = _panorama_cached(width, seed)
    pano.setflags(write=False)
    return pano
