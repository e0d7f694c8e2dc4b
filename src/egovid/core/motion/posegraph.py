"""Rotation-only pose graph on SO(3) (thesis eq. 6.1–6.2), solved with GTSAM.

Each edge (i, j) carries a measured ``Q_ij = R_i.T R_j``; the graph minimises
``sum ||Log(Q_ij^T R_i^T R_j)||^2`` over rotations ``R`` (eq. 6.2, in our camera-to-world
convention) under robust kernels: first Huber, which is convex enough to recover from a chained
start that contains a bad lag-1 pair, then Cauchy from that solution, whose influence vanishes for
gross errors, so a few bad pairs cannot drag the result. Frame 0 is
anchored at the identity. Edges at distance 1 and distance l (default 5) make the graph
over-determined, which is what reduces the drift of plain chaining (eq. 6.1).

**Noise calibrated from the data.** An edge's information matrix comes from its own point
residuals, which measure the matching noise but not what the two-view model misses (parallax the
essential model trades against rotation, rolling shutter, lens distortion, compression): on real
footage they claim hundredths of the actual error, and the errors of long edges grow with their
length. Taken at face value, every edge sits deep in the robust kernel's tail and the distance-l
edges, as confident as the distance-1 ones but biased, leave an l-periodic error in the per-frame
rotation (the 5-frame artefact of the GoPro clip: error autocorrelation 0.53 at lag 5 against its
gyro). So each group of edges (by default: same frame distance; the gyro's own) gets one scale
factor, estimated from its residuals (median whitened χ² against that of a 3-D Gaussian,
repeated twice), before the robust solve: edges are weighted by how well they actually agree
with each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egovid.core.rotations import project_to_so3, so3_log


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
    group: str | None = None

    @property
    def key(self) -> str:
        """Noise-calibration group: :attr:`group`, or ``"lagL"`` for frame distance L."""
        return self.group or f"lag{self.j - self.i}"

    def information(self) -> np.ndarray:
        """3x3 information matrix in radians⁻² (from ``info`` or ``sigma_deg``)."""
        if self.info is not None:
            return 0.5 * (self.info + self.info.T) + np.eye(3) * 1e-6
        return np.eye(3) / np.deg2rad(max(self.sigma_deg, 1e-4)) ** 2


def chain(n: int, edges: list[Edge]) -> np.ndarray:
    """Eq. 6.1: orientations from lag-1 edges alone (missing edges count as no rotation)."""
    step = {e.i: e.Q for e in edges if e.j == e.i + 1}
    R = np.empty((n, 3, 3))
    R[0] = np.eye(3)
    for k in range(1, n):
        R[k] = R[k - 1] @ step.get(k - 1, np.eye(3))
    return project_to_so3(R)


#: Median of a χ² variable with 3 degrees of freedom (whitened residual of a rotation edge).
_CHI2_3_MEDIAN = 2.366
#: Groups with fewer edges keep their stated noise.
_MIN_GROUP = 8
#: Groups that keep their stated noise (weak edges that only bridge gaps).
FIXED_GROUPS = frozenset({"bridge"})


def optimize(
    n: int,
    edges: list[Edge],
    *,
    robust_k: float = 3.0,
    init: np.ndarray | None = None,
    calibrate: bool = True,
    report: dict | None = None,
) -> np.ndarray:
    """Eq. 6.2: camera-to-world rotations (n, 3, 3) best agreeing with all ``edges``.

    ``robust_k`` is the Cauchy kernel's scale in standard deviations. Frames not reached by any
    edge keep their initial (chained) value. With ``calibrate`` the noise of each edge group is
    first scaled to what its residuals show (module docstring); the factors (variance
    multipliers per group) go into ``report["noise_scale"]`` when a dict is given.
    """
    if n == 0:
        return np.zeros((0, 3, 3))
    R = chain(n, edges) if init is None else init
    if n == 1 or not edges:
        return R
    infos = [e.information() for e in edges]
    Q = project_to_so3(np.stack([e.Q for e in edges]))  # GTSAM wants exact rotations
    scales: dict[str, float] = {}
    if calibrate:
        R = _solve(n, edges, Q, infos, R, ("huber",))
        for _ in range(2):
            step = _group_scales(edges, infos, R)
            infos = [inf / step.get(e.key, 1.0) for e, inf in zip(edges, infos, strict=True)]
            for k, v in step.items():
                scales[k] = scales.get(k, 1.0) * v
            R = _solve(n, edges, Q, infos, R, ("huber",))
        R = _solve(n, edges, Q, infos, R, ("cauchy",), robust_k)
    else:
        R = _solve(n, edges, Q, infos, R, ("huber", "cauchy"), robust_k)
    if report is not None:
        report["noise_scale"] = {k: float(v) for k, v in sorted(scales.items())}
    return R


def residuals(edges: list[Edge], R: np.ndarray) -> np.ndarray:
    """Rotation-vector residuals (len(edges), 3) in radians of ``Log(Q_ij^T R_i^T R_j)``."""
    if not edges:
        return np.zeros((0, 3))
    I = np.array([e.i for e in edges])
    J = np.array([e.j for e in edges])
    Q = np.stack([e.Q for e in edges])
    return so3_log(np.swapaxes(Q, 1, 2) @ np.swapaxes(R[I], 1, 2) @ R[J])


def _group_scales(edges: list[Edge], infos: list[np.ndarray], R: np.ndarray) -> dict[str, float]:
    """Variance factor per edge group (Helmert's variance-component estimate, approximated).

    A group's whitened residuals against the solution are smaller than its noise by the share of
    the solution it determines itself (its leverage): for groups of edges spanning ``L`` frames
    along the whole video, that share follows from the frequency responses ``|Σ_{k<L} e^{ikω}|²``
    of the groups weighted by their information (a stationary chain, one unknown per frame).
    Median χ² (robust to outliers) is compared with 2.366 (1 - leverage) per group.
    """
    r = residuals(edges, R)
    chi2 = np.einsum("ki,kij,kj->k", r, np.stack(infos), r)
    groups: dict[str, list[int]] = {}
    for k, e in enumerate(edges):
        groups.setdefault(e.key, []).append(k)
    n = len(R)
    omega = np.linspace(0.0, np.pi, 257)[1:]
    resp, weight = {}, {}
    for key, idx in groups.items():
        span = int(np.median([edges[k].j - edges[k].i for k in idx]))
        resp[key] = (np.sin(span * omega / 2) / np.sin(omega / 2)) ** 2
        # Information per frame of the video contributed by this group (scalar, mean over axes).
        weight[key] = float(np.median([np.trace(infos[k]) / 3.0 for k in idx])) * len(idx) / max(n - 1, 1)
    total = sum(weight[k] * resp[k] for k in groups) + 1e-300
    out = {}
    for key, idx in groups.items():
        if len(idx) < _MIN_GROUP or key in FIXED_GROUPS:
            continue
        leverage = float(np.mean(weight[key] * resp[key] / total)) * (n - 1) / len(idx)
        expected = _CHI2_3_MEDIAN * max(1.0 - leverage, 0.05)
        out[key] = float(np.clip(np.median(chi2[idx]) / expected, 1e-4, 1e6))
    return out


def _solve(
    n: int, edges: list[Edge], Q: np.ndarray, infos: list[np.ndarray], R0: np.ndarray, kernels, robust_k: float = 3.0
):
    import gtsam

    values = gtsam.Values()
    for k in range(n):
        values.insert(k, gtsam.Rot3(R0[k]))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    for name in kernels:
        kernel = (
            gtsam.noiseModel.mEstimator.Huber.Create(1.345)
            if name == "huber"
            else gtsam.noiseModel.mEstimator.Cauchy.Create(robust_k)
        )
        graph = _graph(edges, Q, infos, kernel)
        values = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return np.stack([values.atRot3(k).matrix() for k in range(n)])


def _graph(edges: list[Edge], Q: np.ndarray, infos: list[np.ndarray], kernel):
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorRot3(0, gtsam.Rot3(np.eye(3)), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    for e, q, info in zip(edges, Q, infos, strict=True):
        base = gtsam.noiseModel.Gaussian.Information(info)
        model = gtsam.noiseModel.Robust.Create(kernel, base)
        graph.add(gtsam.BetweenFactorRot3(e.i, e.j, gtsam.Rot3(q), model))
    return graph
