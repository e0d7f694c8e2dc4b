"""Floor rows: what an "odometer" that looks at no image scores on a scene.

Every table of the report has them, so a reader sees when an odometer is no better than doing
nothing. They depend on the reference only, not on the video, so each is scored once per scene
and seed (at the lossless level) and stands for every compression level.

* ``floor-stationary`` — the identity at every frame, no positions: "no motion", also what an
  odometer that never tracked scores;
* ``floor-constant-velocity`` — the reference's mean motion per frame, repeated from the
  identity: the mean body-frame rotation step ``ω̄ = mean_k log(R_kᵀ R_{k+1})`` and, where the
  reference has positions, the mean body-frame translation step ``v̄ = mean_k R_kᵀ (t_{k+1} − t_k)``;
  ``R̂_{k+1} = R̂_k exp(ω̄)``, ``t̂_{k+1} = t̂_k + R̂_k v̄``. It knows six numbers of the reference and
  nothing of how the motion varies: a constant-velocity motion model that never sees a frame.
"""

from __future__ import annotations

import numpy as np

from egovid.core.rotations import so3_exp, so3_log
from egovid.voeval.scenes import SceneTruth

STATIONARY, CONSTANT_VELOCITY = "floor-stationary", "floor-constant-velocity"
FLOORS = (STATIONARY, CONSTANT_VELOCITY)
#: How the report names them.
FLOOR_LABELS = {STATIONARY: "floor: stationary", CONSTANT_VELOCITY: "floor: constant velocity"}


def is_floor(name: str) -> bool:
    return name in FLOORS


def floor_trajectory(name: str, truth: SceneTruth) -> tuple[np.ndarray, np.ndarray | None]:
    """(R (N, 3, 3), t (N, 3) or None) of floor ``name`` on the scene of ``truth``."""
    n = len(truth.R)
    if name == STATIONARY:
        return np.repeat(np.eye(3)[None], n, 0), None
    if name != CONSTANT_VELOCITY:
        raise ValueError(f"unknown floor {name!r}")
    R, t = truth.R, truth.t
    step = so3_exp(np.mean(so3_log(np.swapaxes(R[:-1], -1, -2) @ R[1:]), axis=0)[None])[0]
    v = None if t is None else np.mean(np.einsum("kji,kj->ki", R[:-1], np.diff(t, axis=0)), axis=0)
    Rs, ts = [np.eye(3)], [np.zeros(3)]
    for _ in range(n - 1):
        if v is not None:
            ts.append(ts[-1] + Rs[-1] @ v)
        Rs.append(Rs[-1] @ step)
    return np.stack(Rs), (np.stack(ts) if v is not None else None)
