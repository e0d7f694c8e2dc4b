"""An ORB vocabulary for ORB-SLAM3 built locally from bundled photos (no download).

ORB-SLAM3 needs a DBoW2 vocabulary (``ORBvoc.txt``, normally a 139 MB download). egovid builds a
smaller one (k = 10 branches, L = 4 levels, up to 10 000 words) from ORB descriptors of the photos
bundled with scikit-image and matplotlib, at several scales and rotations, by hierarchical
k-majority clustering (k-means for binary descriptors: Hamming distance, bitwise-majority centres),
with inverse-document-frequency weights, and writes DBoW2's text format. It is cached under
``$EGOVID_CACHE`` (default ``~/.cache/egovid``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np

from egovid.core.files import atomic_write_text
from egovid.synth.photos import ALL, photo

K, L = 10, 4


def cache_dir() -> Path:
    d = Path(os.environ.get("EGOVID_CACHE", Path.home() / ".cache" / "egovid"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def _descriptors() -> tuple[np.ndarray, np.ndarray]:
    """(N, 32) ORB descriptors and the image index each came from."""
    orb = cv2.ORB_create(nfeatures=1500)
    out, img_id = [], []
    k = 0
    for name in ALL:
        base = cv2.cvtColor(photo(name), cv2.COLOR_BGR2GRAY)
        for scale in (1.0, 0.6):
            for angle in (0, 25):
                g = cv2.resize(base, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
                if angle:
                    h, w = g.shape
                    g = cv2.warpAffine(g, cv2.getRotationMatrix2D((w / 2, h / 2), angle, 1.0), (w, h))
                _, d = orb.detectAndCompute(g, None)
                if d is not None:
                    out.append(d)
                    img_id.append(np.full(len(d), k))
                k += 1
    return np.concatenate(out), np.concatenate(img_id)


def _kmajority(bits: np.ndarray, k: int, rng: np.random.Generator, iters: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Cluster (n, 256) bit rows; returns (labels, centres (k', 256))."""
    n = len(bits)
    k = min(k, n)
    centres = bits[rng.choice(n, k, replace=False)].astype(np.float32)
    b = bits.astype(np.float32)
    labels = np.zeros(n, np.int64)
    for _ in range(iters):
        d = b @ (1 - centres).T + (1 - b) @ centres.T  # Hamming distances
        labels = np.argmin(d, axis=1)
        for c in range(k):
            members = b[labels == c]
            if len(members):
                centres[c] = (members.mean(axis=0) > 0.5).astype(np.float32)
    return labels, centres.astype(np.uint8)


def build_vocabulary(path: Path | None = None, seed: int = 0) -> Path:
    """Build (or reuse) the vocabulary file; returns its path."""
    path = path or cache_dir() / f"orbvoc-egovid-k{K}L{L}.txt"
    if path.exists():
        return path
    desc, img = _descriptors()
    n_images = int(img.max()) + 1
    bits = np.unpackbits(desc, axis=1)
    rng = np.random.default_rng(seed)
    lines = [f"{K} {L} 0 0"]  # k, L, scoring L1-norm, weighting TF-IDF
    # Breadth-first: node ids are assigned in the order the lines are written (root = 0).
    queue = [(0, np.arange(len(bits)), 0)]  # (node id, members, depth)
    next_id = 1
    while queue:
        nid, members, depth = queue.pop(0)
        labels, centres = _kmajority(bits[members], K, rng)
        for c in range(len(centres)):
            child = members[labels == c]
            if len(child) == 0:
                continue
            cid = next_id
            next_id += 1
            leaf = depth + 1 == L or len(child) <= K
            weight = math.log(n_images / max(len(np.unique(img[child])), 1)) if leaf else 0.0
            d = np.packbits(centres[c])
            lines.append(f"{nid} {int(leaf)} " + " ".join(str(int(v)) for v in d) + f" {weight:.6f}")
            if not leaf:
                queue.append((cid, child, depth + 1))
    atomic_write_text(path, "\n".join(lines))  # no trailing newline: DBoW2 reads to EOF
    return path
