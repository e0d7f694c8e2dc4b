"""Rotation-only pose graph on SO(3) (thesis eq. 6.1–6.2), solved with GTSAM.

Each edge (i, j) carries a measured ``Q_ij = R_i.T R_j``; the graph minimises
``sum ||Log(Q_ij^T R_i^T R_j)||^2`` over rotations ``R`` (eq. 6.2, in our camera-to-world
convention) under robust kernels: first Huber, which is convex enough to recover from a chained
start that contains a bad lag-1 pair, then Cauchy from that solution, whose influence vanishes for
gross errors, so a few bad pairs cannot drag the result. Frame 0 is
anchored at the identity. Edges at distance 1 and distance l (default 5) make the graph
over-determined, which is what reduces the drift of plain chaining (eq. 6.1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egovid.geometry import project_to_so3


@dataclass
class Edge:
    """Measured relative rotation ``Q = R_i.T R_j`` between frames ``i < j``.

    Its uncertainty is either ``info`` (3x3 information matrix for a right perturbation
    ``Q exp(w)``, radians⁻²) or, when that is None, an isotropic ``sigma_deg`` in degrees.
    """

    i: int
    j: int
    Q: np.ndarray
    sigma_deg: float = 1.0
    info: np.ndarray | None = None


def chain(n: int, edges: list[Edge]) -> np.ndarray:
    """Eq. 6.1: orientations from lag-1 edges alone (missing edges count as no rotation)."""
    step = {e.i: e.Q for e in edges if e.j == e.i + 1}
    R = np.empty((n, 3, 3))
    R[0] = np.eye(3)
    for k in range(1, n):
        R[k] = R[k - 1] @ step.get(k - 1, np.eye(3))
    return project_to_so3(R)


def optimize(n: int, edges: list[Edge], *, robust_k: float = 3.0, init: np.ndarray | None = None) -> np.ndarray:
    """Eq. 6.2: camera-to-world rotations (n, 3, 3) best agreeing with all ``edges``.

    ``robust_k`` is the Cauchy kernel's scale in standard deviations. Frames not reached by any edge keep
    their initial (chained) value.
    """
    import gtsam

    if n == 0:
        return np.zeros((0, 3, 3))
    R0 = chain(n, edges) if init is None else init
    if n == 1 or not edges:
        return R0
    values = gtsam.Values()
    for k in range(n):
        values.insert(k, gtsam.Rot3(R0[k]))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    for kernel in (
        gtsam.noiseModel.mEstimator.Huber.Create(1.345),
        gtsam.noiseModel.mEstimator.Cauchy.Create(robust_k),
    ):
        graph = _graph(edges, kernel)
        values = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    result = values
    return np.stack([result.atRot3(k).matrix() for k in range(n)])


def _graph(edges: list[Edge], kernel):
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorRot3(0, gtsam.Rot3(np.eye(3)), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    for e in edges:
        if e.info is not None:
            base = gtsam.noiseModel.Gaussian.Information(e.info + np.eye(3) * 1e-6)
        else:
            base = gtsam.noiseModel.Isotropic.Sigma(3, np.deg2rad(max(e.sigma_deg, 1e-4)))
        model = gtsam.noiseModel.Robust.Create(kernel, base)
        graph.add(gtsam.BetweenFactorRot3(e.i, e.j, gtsam.Rot3(project_to_so3(e.Q)), model))
    return graph
