"""Rotation pose error of a visual odometer (thesis §21.5.1, eq. 21.7–21.12).

With ground-truth orientations ``p`` and estimates ``p̂`` (camera-to-world, per frame), the error
of eq. 21.11 compares relative rotations instead of absolute ones (so an early mistake is not
counted again in every later frame, [90]):

    e = Σ_{t = 1 : s : K-1}  (p_t ⊖ p_K) ⊙ (p̂_t ⊖ p̂_K)

where ``a ⊖ b = a⁻¹ b`` is the relative rotation and ``R_m ⊙ R_n = Σ_{i=x,y,z} ‖R_m⁻¹ R_n e_i − e_i‖``
sums the displacement of the three axes (eq. 21.12; unlike the KITTI angle it sees yaw, pitch and
roll errors separately). Parameters:

* ``pairs="to_last"`` — every frame against the last one (eq. 21.11, the thesis' default);
  ``pairs="consecutive"`` — each frame against the next (``delta`` frames on), the definition of
  evo's RPE, used to cross-check;
* ``step`` — s, the stride over t; ``aggregate`` — ``"sum"`` (the thesis) or ``"mean"``.
"""

from __future__ import annotations

import numpy as np

AXES = np.eye(3)


def relative(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """``a ⊖ b = a⁻¹ b`` for stacks of rotations."""
    return np.swapaxes(Ra, -1, -2) @ Rb


def axis_sum_error(E: np.ndarray) -> np.ndarray:
    """Eq. 21.12 on a stack of error rotations ``E = R_m⁻¹ R_n``: Σ_i ‖E e_i − e_i‖."""
    d = E - np.eye(3)  # columns are E e_i - e_i
    return np.sum(np.linalg.norm(d, axis=-2), axis=-1)


def pair_errors(
    R_gt: np.ndarray, R_est: np.ndarray, *, pairs: str = "to_last", step: int = 1, delta: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pair error rotations ``(p_a ⊖ p_b)⁻¹ (p̂_a ⊖ p̂_b)`` and their eq. 21.12 values."""
    K = len(R_gt)
    if len(R_est) != K:
        raise ValueError("ground truth and estimate have different lengths")
    if pairs == "to_last":
        a = np.arange(0, K - 1, step)
        b = np.full(len(a), K - 1)
    elif pairs == "consecutive":
        a = np.arange(0, K - delta, step)
        b = a + delta
    else:
        raise ValueError(f"unknown pairs {pairs!r}")
    E = relative(relative(R_gt[a], R_gt[b]), relative(R_est[a], R_est[b]))
    return E, axis_sum_error(E)


def pose_error(
    R_gt: np.ndarray,
    R_est: np.ndarray,
    *,
    pairs: str = "to_last",
    step: int = 1,
    delta: int = 1,
    aggregate: str = "sum",
) -> float:
    """Eq. 21.11 (dimensionless: sums of unit-vector displacements)."""
    _, e = pair_errors(R_gt, R_est, pairs=pairs, step=step, delta=delta)
    if aggregate == "sum":
        return float(np.sum(e))
    if aggregate == "mean":
        return float(np.mean(e)) if len(e) else 0.0
    raise ValueError(f"unknown aggregate {aggregate!r}")
