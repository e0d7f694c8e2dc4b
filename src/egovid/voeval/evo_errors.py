"""The standard trajectory errors, ATE and RPE, computed by evo on a cell's trajectories.

Besides the thesis' pose error, OITF and RITF (eq. 21.11-21.19), every cell gets the figures most
odometry papers quote, computed with evo's own functions (``evo.main_ape.ape`` and
``evo.main_rpe.rpe``, what the ``evo_ape`` and ``evo_rpe`` commands run) after evo's timestamp
association, on the same trajectories as the pose error (the reference and the estimate as scored:
lost frames hold the last pose). Each figure is the RMSE over the frames or frame pairs:

=================  ================================================================================
``ate_rot_deg``    absolute rotation error, degrees: ``evo_ape tum REF EST --pose_relation angle_deg
                   --align_origin`` (both trajectories start at the identity, so the origin
                   alignment changes nothing; evo cannot align rotation-only trajectories otherwise)
``rpe_rot_deg``    rotation error of consecutive frames, degrees: ``evo_rpe tum REF EST
                   --pose_relation angle_deg --delta 1 --delta_unit f`` (no alignment: it does not
                   change relative rotations)
``ate_trans``      absolute position error after a Sim(3) Umeyama alignment of the estimate to the
                   reference (``evo_ape tum REF EST -as``), in the reference's units
``rpe_trans``      position error of consecutive frames after the same alignment (``evo_rpe tum REF
                   EST -as --delta 1 --delta_unit f``)
=================  ================================================================================

The translation figures exist only where the odometer gives positions and the reference has
them; the Sim(3) alignment (a monocular odometer has no scale) needs positions that span a plane:
on a line or a point (a camera dollying straight, a stationary estimate) it is not unique, evo
refuses it (or, at machine precision, not always), and the figures are None with the reason in
``translation_note``.
"""

from __future__ import annotations

import copy

import numpy as np
from evo import EvoException
from evo.core import metrics, sync
from evo.core.trajectory import PoseTrajectory3D
from evo.main_ape import ape
from evo.main_rpe import rpe
from scipy.spatial.transform import Rotation

#: The figures of :func:`ate_rpe`, all lower-is-better.
EVO_METRICS = ("ate_rot_deg", "rpe_rot_deg", "ate_trans", "rpe_trans")


def evo_trajectory(times: np.ndarray, R: np.ndarray, t: np.ndarray | None = None) -> PoseTrajectory3D:
    """An evo trajectory of camera-to-world rotations (N, 3, 3) and positions (N, 3; zeros when None)."""
    q = Rotation.from_matrix(R).as_quat()[:, [3, 0, 1, 2]]  # evo: w x y z
    pos = np.zeros((len(R), 3)) if t is None else np.asarray(t, float)
    return PoseTrajectory3D(positions_xyz=pos, orientations_quat_wxyz=q, timestamps=np.asarray(times, float))


def _flat(t: np.ndarray, what: str) -> str:
    """Why positions (N, 3) admit no unique Sim(3) alignment ("": they do): all on a point or a
    line (the second singular value of the centred positions below 1e-6 of the first; trajectory
    files round positions to 1e-9). evo's own test (a covariance rank below 2 at machine precision)
    lets rounding noise through, so a straight dolly would get an alignment on some scenes and not
    on others."""
    s = np.linalg.svd(np.asarray(t, float) - np.mean(t, axis=0), compute_uv=False)
    if s[0] <= 1e-12:
        return f"{what}'s positions are all the same point"
    return f"{what}'s positions lie on a line" if s[1] <= 1e-6 * s[0] else ""


def _rmse(result) -> float:
    return float(result.stats["rmse"])


def ate_rpe(
    times: np.ndarray,
    R_ref: np.ndarray,
    R_est: np.ndarray,
    t_ref: np.ndarray | None = None,
    t_est: np.ndarray | None = None,
) -> dict:
    """ATE and RPE (see the module doc) of an estimate against a reference sampled at the same
    ``times`` (N,) seconds: rotations (N, 3, 3) camera-to-world, positions (N, 3) or None.

    Returns ``{"ate_rot_deg", "rpe_rot_deg", "ate_trans", "rpe_trans", "translation_note"}``; the
    translation figures are None (and the note says why) without positions on both sides or when
    the Sim(3) alignment is impossible."""
    ref, est = sync.associate_trajectories(evo_trajectory(times, R_ref, t_ref), evo_trajectory(times, R_est, t_est))
    angle, trans = metrics.PoseRelation.rotation_angle_deg, metrics.PoseRelation.translation_part
    frames = metrics.Unit.frames
    out: dict = {
        "ate_rot_deg": _rmse(ape(copy.deepcopy(ref), copy.deepcopy(est), angle, align_origin=True)),
        "rpe_rot_deg": _rmse(rpe(copy.deepcopy(ref), copy.deepcopy(est), angle, delta=1, delta_unit=frames)),
        "ate_trans": None,
        "rpe_trans": None,
        "translation_note": "",
    }
    if t_ref is None or t_est is None:
        out["translation_note"] = "the reference has no positions" if t_ref is None else "the odometer gives none"
        return out
    flat = _flat(t_ref, "reference") or _flat(t_est, "estimate")
    if flat:
        out["translation_note"] = f"no Sim(3) alignment: the {flat}"
        return out
    try:
        sim3 = {"align": True, "correct_scale": True}
        out["ate_trans"] = _rmse(ape(copy.deepcopy(ref), copy.deepcopy(est), trans, **sim3))
        out["rpe_trans"] = _rmse(rpe(copy.deepcopy(ref), copy.deepcopy(est), trans, delta=1, delta_unit=frames, **sim3))
    except EvoException as exc:  # Umeyama: positions on a line or a point
        out["translation_note"] = f"no Sim(3) alignment: {exc}"
    return out
