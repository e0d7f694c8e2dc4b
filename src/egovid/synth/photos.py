"""Photos that ship inside installed packages (no network): scikit-image's data set and
matplotlib's sample image. They are the raw material of every synthetic scene in egovid."""

from __future__ import annotations

import functools
import os

import cv2
import numpy as np

from egovid.core.errors import EgovidError

#: Colour photographs with rich texture (scikit-image names).
COLOUR = (
    "astronaut",
    "coffee",
    "chelsea",
    "rocket",
    "stereo_motorcycle",
    "immunohistochemistry",
    "hubble_deep_field",
    "retina",
    "colorwheel",
    "cat",
)
#: Grey photographs and textures.
GREY = ("camera", "brick", "grass", "gravel", "moon", "coins", "clock", "text", "page", "cell")
#: Photos shown to "learned" models in voeval (the rest are "unseen").
ALL = (*COLOUR, *GREY, "grace_hopper")


@functools.lru_cache(maxsize=64)
def _load(name: str) -> np.ndarray:
    if name == "grace_hopper":
        import matplotlib

        path = os.path.join(matplotlib.get_data_path(), "sample_data", "grace_hopper.jpg")
        img = cv2.imread(path, cv2.IMREAD_COLOR)
        if img is None:  # pragma: no cover
            raise FileNotFoundError(path)
        return img
    import skimage.data

    img = getattr(skimage.data, name)()
    if isinstance(img, tuple):
        img = img[0]
    img = np.asarray(img)
    if img.dtype != np.uint8:
        img = np.clip(img * (255.0 if img.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    return img


def photo(name: str) -> np.ndarray:
    """A bundled photo as an HxWx3 BGR uint8 array (a copy)."""
    if name not in ALL:
        raise EgovidError(f"unknown photo {name!r}", f"choose one of: {', '.join(ALL)}")
    return _load(name).copy()
