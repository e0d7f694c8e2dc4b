"""Relative rotation between two frames from matched keypoints (thesis ch. 6, initialisation).

Two models compete on the same (sub-pixel refined) matches:

* **rotation** — a RANSAC homography finds the matches consistent with a pure rotation; the
  rotation is the least-squares alignment of their bearing vectors (Kabsch), i.e. ``K⁻¹HK``
  projected onto SO(3) without the projective noise of ``H``, fitted together with a zoom about
  the principal point (what walking forward in front of a distant scene looks like), which would
  otherwise bias the rotation;
* **essential** — rotation plus a translation direction, refined jointly by minimising the
  Sampson epipolar error over the inliers (5 parameters), starting from the rotation model and
  from a RANSAC five-point essential matrix (the better end is kept).

Both models see the same matches: :func:`correspondences` keeps those a rotation explains and
those an essential matrix explains (near points under translation), on undistorted points for a
fisheye lens. Selecting by the rotation alone threw the parallax away, and with it what tells a
sideways step from a turn (walking indoors past things 1-3 m away: a degree per pair).

The thesis tries the essential matrix first and falls back to the homography when too few points
survive triangulation. We decide from the other side, which is cheaper and better conditioned:
the rotation model is kept unless the essential model explains clearly more matches, i.e. unless
the baseline produces parallax that a pure rotation cannot explain. A pure-rotation model fitted
to a translating camera is biased by the parallax (towards the side with more features), which is
why the switch matters for real walking or driving video.

Each estimate also returns its 3x3 information matrix (inverse covariance, radians⁻²) from the
bearing geometry and the measured residual noise, which weights the edge in the pose graph: roll
is only constrained by points far from the image centre, so it is weaker than yaw and pitch.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

MIN_INLIERS = 12
#: Matches the joint rotation + translation refinement uses at most.
ESSENTIAL_POINTS = 200
#: Iterations of that refinement at most.
ESSENTIAL_MAX_ITERATIONS = 15
#: Degrees from the rotation fit within which a five-point essential matrix may start that
#: refinement (parallax of walking past things 1-3 m away moves the rotation fit by up to ~2°).
ESSENTIAL_START_MAX_DEG = 5.0
#: Share of the robust epipolar cost from the rotation fit's start that the five-point start
#: must end below to be taken instead.
ESSENTIAL_SWITCH_COST = 0.5


@dataclass
class PairRotation:
    """Rotation ``Q`` mapping camera-j coordinates to camera-i coordinates (``R_i.T @ R_j``).

    ``inliers`` counts the matches the chosen ``model`` explains; ``info`` is the 3x3 information
    matrix of ``Q`` for a right perturbation ``Q exp(w)`` (radians⁻²); ``ok`` is False when the
    pair could not be estimated (then ``Q`` is the identity and must not be trusted).
    """

    Q: np.ndarray
    inliers: int
    matches: int
    model: str
    ok: bool
    info: np.ndarray | None = None
    residual_px: float = float("nan")


def _failed(n_inliers: int, n: int) -> PairRotation:
    return PairRotation(np.eye(3), n_inliers, n, "none", False)


def bearings(pts: np.ndarray, K_inv: np.ndarray) -> np.ndarray:
    """Unit bearing vectors (N, 3) of pixel points (N, 2)."""
    h = np.column_stack([pts, np.ones(len(pts))]) @ K_inv.T
    return h / np.linalg.norm(h, axis=1, keepdims=True)


def kabsch(b_from: np.ndarray, b_to: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Rotation Q minimising sum w |b_to - Q b_from|^2 (both (N, 3) unit vectors)."""
    b = np.asarray(b_from, dtype=np.float64)
    if weights is not None:
        b = b * np.asarray(weights, dtype=np.float64)[:, None]
    return _kabsch_nb(np.ascontiguousarray(b), np.ascontiguousarray(b_to, dtype=np.float64))


def rotation_residuals(Q: np.ndarray, pj: np.ndarray, pi: np.ndarray, K: np.ndarray, zoom: float = 1.0) -> np.ndarray:
    """Pixel distances between frame-i points and frame-j points rotated by ``Q`` (and zoomed by
    ``zoom`` about the principal point) into frame i."""
    f64 = np.float64
    K = np.asarray(K, f64)
    return _residuals_nb(
        np.asarray(Q, f64), np.ascontiguousarray(pj, f64), np.ascontiguousarray(pi, f64), K, np.linalg.inv(K), zoom
    )


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _exp(w: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(w, dtype=np.float64).reshape(3, 1))[0]


def sampson_px(Q: np.ndarray, t: np.ndarray, xi: np.ndarray, xj: np.ndarray, focal: float) -> np.ndarray:
    """Sampson epipolar distance in pixels of normalised points ``xi``, ``xj`` ((N, 3), z = 1)."""
    E = _skew(t) @ Q
    Exj = xj @ E.T
    Etxi = xi @ E
    num = np.einsum("ij,ij->i", xi, Exj)
    den = Exj[:, 0] ** 2 + Exj[:, 1] ** 2 + Etxi[:, 0] ** 2 + Etxi[:, 1] ** 2
    return focal * num / np.sqrt(np.maximum(den, 1e-18))


def _translation_given(Q: np.ndarray, bi: np.ndarray, bj: np.ndarray) -> np.ndarray:
    C = np.cross(bi, bj @ Q.T)
    _, _, Vt = np.linalg.svd(C, full_matrices=False)
    return Vt[-1]


def _refine_essential(
    Q0: np.ndarray, t0: np.ndarray, xi: np.ndarray, xj: np.ndarray, focal: float, scale_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """Joint (rotation, translation direction) refinement of the Sampson error (robust).

    Levenberg-Marquardt on 5 parameters (a rotation vector on ``Q0`` and two coordinates of the
    translation direction in the tangent plane of ``t0``) with the soft-L1 loss of scale
    ``scale_px`` by iteratively reweighted least squares, and a forward-difference Jacobian: the
    same problem SciPy's ``least_squares(loss="soft_l1")`` solves, without its per-iteration
    overhead (this refinement was the most expensive step of a pair).
    """
    # Translation direction on the sphere: t = normalise(t0 + a*u + b*v) with u, v ⟂ t0.
    u = np.cross(t0, [1.0, 0.0, 0.0] if abs(t0[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(t0, u)

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = t0 + p[3] * u + p[4] * v
        return Q0 @ _exp(p[:3]), t / np.linalg.norm(t)

    def fun(p: np.ndarray) -> np.ndarray:
        Q, t = unpack(p)
        return sampson_px(Q, t, xi, xj, focal)

    def cost(r: np.ndarray) -> float:
        z = (r / scale_px) ** 2
        return float(np.sum(2.0 * (np.sqrt(1.0 + z) - 1.0)))

    p = np.zeros(5)
    r = fun(p)
    c = cost(r)
    lam = 1e-3
    h = 1e-7
    for _ in range(ESSENTIAL_MAX_ITERATIONS):
        J = np.empty((len(r), 5))
        for k in range(5):
            dp = p.copy()
            dp[k] += h
            J[:, k] = (fun(dp) - r) / h
        w = 1.0 / np.sqrt(1.0 + (r / scale_px) ** 2)  # IRLS weights of the soft-L1 loss
        A = (J * w[:, None]).T @ J
        g = (J * w[:, None]).T @ r
        while True:
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
            r_new = fun(p + step)
            c_new = cost(r_new)
            if c_new <= c or lam > 1e6:
                break
            lam *= 10.0
        if c_new > c:
            break
        p, r, c = p + step, r_new, c_new
        lam = max(lam / 10.0, 1e-9)
        if np.max(np.abs(step)) < 1e-10:
            break
    return unpack(p)


def _soft_l1(r: np.ndarray, scale: float) -> float:
    """The soft-L1 cost of residuals ``r`` (pixels) at ``scale`` pixels."""
    return float(np.sum(2.0 * (np.sqrt(1.0 + (r / scale) ** 2) - 1.0)))


def _essential_starts(
    Q: np.ndarray, pi: np.ndarray, pj: np.ndarray, bi: np.ndarray, bj: np.ndarray, K: np.ndarray, threshold_px: float
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Starting points (rotation, unit translation) of the essential refinement: the rotation fit
    ``Q`` with its best translation, and OpenCV's RANSAC five-point essential matrix (seeded)
    with the pose its cheirality check picks, where it finds one within
    :data:`ESSENTIAL_START_MAX_DEG` of ``Q`` (a five-point solution further away is one of its
    spurious decompositions or a lens the pinhole model misses, not parallax)."""
    starts = [(Q, _translation_given(Q, bi, bj))]
    try:
        cv2.setRNGSeed(12345)
        E, mask = cv2.findEssentialMat(pj, pi, K, cv2.RANSAC, 0.999, threshold_px, maxIters=500)
        if E is not None and E.shape == (3, 3):
            _, R5, t5, _ = cv2.recoverPose(E, pj, pi, K, mask=mask)
            t5 = t5.ravel()
            turn = np.degrees(np.linalg.norm(cv2.Rodrigues(Q.T @ R5)[0]))
            if np.all(np.isfinite(R5)) and np.linalg.norm(t5) > 0 and turn < ESSENTIAL_START_MAX_DEG:
                starts.append((R5, t5 / np.linalg.norm(t5)))
    except cv2.error:
        pass
    return starts


def _information(Q: np.ndarray, bj: np.ndarray, sigma_rad: float) -> np.ndarray:
    """Information of Q for right perturbations, from inlier bearings and angular noise."""
    M = np.eye(3) * len(bj) - bj.T @ bj  # sum (I - b b^T) in camera-j coordinates
    return M / max(sigma_rad, 1e-6) ** 2


def _coarse_rotation(pi: np.ndarray, pj: np.ndarray, K: np.ndarray, threshold_px: float) -> np.ndarray | None:
    """RANSAC homography inliers, then Kabsch on their bearings; None if too few agree."""
    H, mask = cv2.findHomography(pj, pi, cv2.RANSAC, threshold_px, maxIters=500, confidence=0.995)
    if H is None or mask is None or int(mask.sum()) < MIN_INLIERS:
        return None
    K_inv = np.linalg.inv(K)
    inl = mask.ravel().astype(bool)
    return kabsch(bearings(pj[inl], K_inv), bearings(pi[inl], K_inv))


_LK_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)


def refine_by_prewarp(
    img_i: np.ndarray,
    img_j: np.ndarray,
    pi: np.ndarray,
    Q: np.ndarray,
    K: np.ndarray,
    pj: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel correspondences of points ``pi`` (frame i) in frame j.

    Frame j is first warped into frame i's view with the rotation homography ``K Q K⁻¹``, so the
    remaining displacement is small and free of rotation and perspective distortion; Lucas-Kanade
    then measures it to a few hundredths of a pixel, and the result is mapped back into frame j.
    ORB keypoints alone sit on whole pixels of their pyramid level; this step cuts the pairwise
    rotation error about five-fold, at distance 5 as at distance 1. Returns empty (0, 2) arrays
    when no point survives.

    ``pj`` (same length as ``pi``, NaN rows allowed) are the matches' own positions in frame j
    where the rotation does not explain them (parallax of near points under translation): there
    Lucas-Kanade starts from the match mapped into the warped picture instead of from ``pi``, and
    the 3 px limit applies to the refinement's step from that start.
    """
    empty = np.zeros((0, 2))
    if len(pi) == 0:
        return empty, empty
    H = K @ Q @ np.linalg.inv(K)  # frame j pixels -> frame i pixels
    h, w = img_i.shape[:2]
    warped = cv2.warpPerspective(img_j, H, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    p0 = np.ascontiguousarray(pi, np.float32).reshape(-1, 1, 2)
    start = np.asarray(pi, np.float64).copy()
    if pj is not None:
        own = np.all(np.isfinite(pj), axis=1)
        if own.any():
            hp = np.column_stack([pj[own], np.ones(int(own.sum()))]) @ H.T
            start[own] = hp[:, :2] / hp[:, 2:3]
    p1, status, _ = cv2.calcOpticalFlowPyrLK(
        img_i,
        warped,
        p0,
        np.ascontiguousarray(start, np.float32).reshape(-1, 1, 2),
        winSize=(15, 15),
        maxLevel=1,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        criteria=_LK_CRITERIA,
    )
    if p1 is None or status is None:
        return empty, empty
    p1 = p1.reshape(-1, 2).astype(np.float64)
    ok = (status.ravel() == 1) & np.all(np.isfinite(p1), axis=1) & (np.linalg.norm(p1 - start, axis=1) < 3.0)
    margin = 8
    ok &= (p1[:, 0] > margin) & (p1[:, 0] < w - margin) & (p1[:, 1] > margin) & (p1[:, 1] < h - margin)
    back = np.column_stack([p1[ok], np.ones(int(ok.sum()))]) @ np.linalg.inv(H).T
    good = np.abs(back[:, 2]) > 1e-9
    return pi[ok][good], back[good, :2] / back[good, 2:3]


def correspondences(
    pts_i: np.ndarray,
    pts_j: np.ndarray,
    K: np.ndarray,
    *,
    threshold_px: float = 1.0,
    images: tuple[np.ndarray, np.ndarray] | None = None,
    undistort: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The matches of a frame pair that a rotation, or a rotation and a translation, explains,
    refined to sub-pixel accuracy.

    ``pts_i``, ``pts_j`` (M, 2) matched pixels; a RANSAC homography (seeded: identical results
    on every run) finds the ones a rotation explains, and a RANSAC essential matrix those a
    translating camera explains (the parallax of near points, which a rotation-only selection
    throws away: the pair's essential model then never sees what separates rotation from
    translation, and a walking camera's rotation comes out biased). With ``images = (grey_i,
    grey_j)`` they are refined by :func:`refine_by_prewarp`. ``undistort`` maps pixels (N, 2) to
    the pinhole pixels of ``K`` (a fisheye lens): the models are selected on those, while the
    refinement and the result stay in the pictures' own pixels. Returns ``(pi, pj)`` (n, 2)
    float64 pixels, or None when fewer than :data:`MIN_INLIERS` survive. The result does not
    depend on ``K`` beyond the selection and the pre-warp, so a pair can be re-fitted later with
    another focal length.
    """
    if len(pts_i) < MIN_INLIERS or len(pts_i) != len(pts_j):
        return None
    pi = np.ascontiguousarray(pts_i, dtype=np.float64)
    pj = np.ascontiguousarray(pts_j, dtype=np.float64)
    finite = np.all(np.isfinite(pi), axis=1) & np.all(np.isfinite(pj), axis=1)
    pi, pj = pi[finite], pj[finite]
    if len(pi) < MIN_INLIERS:
        return None
    ui, uj = (undistort(pi), undistort(pj)) if undistort is not None else (pi, pj)
    cv2.setRNGSeed(12345)
    Q = _coarse_rotation(ui, uj, K, 2.0 * threshold_px)
    if Q is None:
        return None
    rot = rotation_residuals(Q, uj, ui, K) < 4.0 * threshold_px
    keep = rot | _epipolar_inliers(ui, uj, K, threshold_px, rot)
    if keep.sum() < MIN_INLIERS:
        return None
    pi, pj, rot = pi[keep], pj[keep], rot[keep]
    if images is not None:
        own = np.where(rot[:, None], np.nan, pj)  # parallax matches: LK starts from the match
        pi, pj = refine_by_prewarp(images[0], images[1], pi, Q, K, own)
        if len(pi) < MIN_INLIERS:
            return None
    return pi, pj


#: Matches beyond the rotation's own that an essential matrix must explain to be added at all.
PARALLAX_MIN_EXTRA = 8


def _epipolar_inliers(
    ui: np.ndarray, uj: np.ndarray, K: np.ndarray, threshold_px: float, rot: np.ndarray
) -> np.ndarray:
    """Matches (bool (N,)) a RANSAC essential matrix explains within ``threshold_px``, where it
    explains at least :data:`PARALLAX_MIN_EXTRA` and 5 % more than the rotation (``rot``): with
    a pure rotation the essential matrix is degenerate and adds only chance matches, which it
    must not. All False otherwise."""
    none = np.zeros(len(ui), bool)
    if len(ui) - int(rot.sum()) < max(PARALLAX_MIN_EXTRA, 0.05 * rot.sum()):
        return none
    try:
        E, mask = cv2.findEssentialMat(uj, ui, K, cv2.RANSAC, 0.999, threshold_px, maxIters=500)
    except cv2.error:
        return none
    if E is None or mask is None or E.shape[0] < 3:
        return none
    ess = mask.ravel().astype(bool)
    if (ess & ~rot).sum() < max(PARALLAX_MIN_EXTRA, 0.05 * rot.sum()):
        return none
    return ess


@njit(cache=True, nogil=True, error_model="numpy")
def _unit_rows(x: np.ndarray) -> np.ndarray:
    out = np.empty_like(x)
    for k in range(x.shape[0]):
        n = math.sqrt(x[k, 0] ** 2 + x[k, 1] ** 2 + x[k, 2] ** 2)
        out[k] = x[k] / n
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _kabsch_nb(b_from: np.ndarray, b_to: np.ndarray) -> np.ndarray:
    H = np.ascontiguousarray(b_from.T) @ b_to
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    D = np.eye(3)
    D[2, 2] = d
    return Vt.T @ D @ U.T


@njit(cache=True, nogil=True, error_model="numpy")
def _rotation_zoom_nb(xi: np.ndarray, xj: np.ndarray, iterations: int, zoom: float) -> tuple[np.ndarray, float]:
    """Rotation Q and zoom s with ``x_i ∝ diag(s, s, 1) Q x_j`` (normalised image points, (N, 3)).

    A camera moving along its optical axis in front of a distant, roughly equidistant scene sees a
    zoom about the principal point; left in the residuals it biases a pure-rotation fit towards
    the side with more features. Solved by alternation: Kabsch on de-zoomed bearings, then the
    least-squares zoom in closed form, starting from ``zoom``.
    """
    s = zoom
    Q = np.eye(3)
    bj = _unit_rows(xj)
    for _ in range(iterations):
        xi_ = xi.copy()
        xi_[:, 0] /= s
        xi_[:, 1] /= s
        Q = _kabsch_nb(bj, _unit_rows(xi_))
        u = xj @ Q.T
        num = 0.0
        den = 0.0
        for k in range(u.shape[0]):
            ux, uy = u[k, 0] / u[k, 2], u[k, 1] / u[k, 2]
            den += ux * ux + uy * uy
            num += ux * xi[k, 0] + uy * xi[k, 1]
        s = num / den if den > 1e-12 else 1.0
    return Q, s


@njit(cache=True, nogil=True, error_model="numpy")
def _residuals_nb(Q: np.ndarray, pj: np.ndarray, pi: np.ndarray, K: np.ndarray, K_inv: np.ndarray, zoom: float):
    S = np.eye(3)
    S[0, 0] = zoom
    S[1, 1] = zoom
    M = K @ S @ Q @ K_inv
    out = np.empty(pj.shape[0])
    for k in range(pj.shape[0]):
        hx = M[0, 0] * pj[k, 0] + M[0, 1] * pj[k, 1] + M[0, 2]
        hy = M[1, 0] * pj[k, 0] + M[1, 1] * pj[k, 1] + M[1, 2]
        hz = M[2, 0] * pj[k, 0] + M[2, 1] * pj[k, 1] + M[2, 2]
        out[k] = math.hypot(hx / hz - pi[k, 0], hy / hz - pi[k, 1])
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _fit_rotation_zoom(pi, pj, xi, xj, bi, bj, K, K_inv, threshold_px, min_inliers, Q0):  # pragma: no cover - numba
    """The rotation model of :func:`rotation_from_correspondences` in one compiled call (no GIL,
    so the pair jobs of two threads run at once): from ``Q0`` (3x3; all zeros: Kabsch on all
    matches), three rounds of rotation + zoom on the inliers with a robust noise estimate, and a
    final fit. Returns (ok, Q, zoom, residuals, inliers)."""
    Q = _kabsch_nb(bj, bi) if np.all(Q0 == 0.0) else Q0.copy()
    inl = _residuals_nb(Q, pj, pi, K, K_inv, 1.0) < 2.0 * threshold_px
    zoom = 1.0
    r = np.zeros(pj.shape[0])
    if inl.sum() < min_inliers:
        return False, Q, zoom, r, inl
    for it in range(3):
        Q, zoom = _rotation_zoom_nb(xi[inl], xj[inl], 4 if it == 0 else 2, zoom)
        r = _residuals_nb(Q, pj, pi, K, K_inv, zoom)
        sigma = max(0.02, 1.4826 * np.median(r[inl]) / 1.1774)  # per-axis noise, robust
        inl = r < min(threshold_px, max(4.0 * sigma, 0.1))
        if inl.sum() < min_inliers:
            return False, Q, zoom, r, inl
    Q, zoom = _rotation_zoom_nb(xi[inl], xj[inl], 2, zoom)
    r = _residuals_nb(Q, pj, pi, K, K_inv, zoom)
    return True, Q, zoom, r, inl


def rotation_from_correspondences(
    pi: np.ndarray, pj: np.ndarray, K: np.ndarray, *, threshold_px: float = 1.0
) -> PairRotation:
    """Estimate ``Q = R_i.T R_j`` from correspondences ``pi`` (frame i) and ``pj`` (frame j),
    (n, 2) pixels of images with camera matrix ``K`` (see the module docstring for the two
    models). A pair that cannot be fitted comes back with ``ok = False``."""
    n = len(pi)
    if n < MIN_INLIERS:
        return _failed(n, n)
    K_inv = np.linalg.inv(K)
    focal = 0.5 * (K[0, 0] + K[1, 1])
    bi, bj = bearings(pi, K_inv), bearings(pj, K_inv)
    xi = np.column_stack([pi, np.ones(n)]) @ K_inv.T
    xj = np.column_stack([pj, np.ones(n)]) @ K_inv.T
    thr = float(threshold_px)
    ok, Q, _, r, inl = _fit_rotation_zoom(pi, pj, xi, xj, bi, bj, K, K_inv, thr, MIN_INLIERS, np.zeros((3, 3)))
    if not ok or inl.sum() < 0.5 * n:
        # Near points' parallax pulls a Kabsch fit of all matches off the rotation: start from the
        # matches a RANSAC homography finds instead, and keep whichever start explains more.
        cv2.setRNGSeed(12345)
        Q0 = _coarse_rotation(pi, pj, K, 2.0 * thr)
        if Q0 is not None:
            fit = _fit_rotation_zoom(pi, pj, xi, xj, bi, bj, K, K_inv, thr, MIN_INLIERS, Q0)
            if fit[0] and (not ok or fit[4].sum() > inl.sum()):
                ok, Q, _, r, inl = fit
    if not ok:
        return _failed(int(inl.sum()), n)
    n_rot = int(inl.sum())
    res_rot = float(np.sqrt(np.mean(r[inl] ** 2) / 2.0))
    rot = PairRotation(Q, n_rot, n, "rotation", True, _information(Q, bj[inl], res_rot / focal), res_rot)
    # Is there parallax a pure rotation cannot explain? Fit rotation + translation direction
    # and keep it only if it explains clearly more matches with clearly smaller residuals.
    loose = r < 4.0 * threshold_px
    if loose.sum() - n_rot < max(8, 0.05 * n_rot):
        return rot
    # The 5-parameter refinement runs on at most ESSENTIAL_POINTS of the loose matches (an even
    # stride through them, deterministic): it decides the model, so a few hundred points suffice,
    # and it was the most expensive step of a pair. It starts from the rotation fit and from a
    # RANSAC five-point essential matrix, and keeps the better end: from the rotation fit alone it
    # can stay in the wrong basin where a sideways step's parallax was taken for a turn (near
    # points, walking: a degree off at 1-3 m).
    sub = np.flatnonzero(loose)
    sub = sub[np.linspace(0, len(sub) - 1, min(len(sub), ESSENTIAL_POINTS)).astype(int)]
    scale = max(res_rot, 0.05)
    best = None
    for k, (Q0, t0) in enumerate(_essential_starts(Q, pi[loose], pj[loose], bi[loose], bj[loose], K, threshold_px)):
        try:
            Qe, te = _refine_essential(Q0, t0, xi[sub], xj[sub], focal, scale)
        except (ValueError, np.linalg.LinAlgError):
            continue
        c = _soft_l1(sampson_px(Qe, te, xi[sub], xj[sub], focal), scale)
        # The five-point start (k > 0) must end clearly better: on an ambiguous pair (a short
        # baseline, a lens model that is slightly off) both ends fit about as well, and the
        # rotation fit's is the one the pose graph's other pairs agree with.
        if best is None or c < (ESSENTIAL_SWITCH_COST if k else 1.0) * best[0]:
            best = (c, Qe, te)
    if best is None:
        return rot
    _, Qe, te = best
    d = np.abs(sampson_px(Qe, te, xi, xj, focal))
    e_inl = d < min(threshold_px, max(4.0 * res_rot, 0.1))
    n_ess = int(e_inl.sum())
    if n_ess < MIN_INLIERS or n_ess < n_rot + max(8, 0.1 * n_rot):
        return rot
    res_e = float(np.sqrt(np.mean(d[e_inl] ** 2)))
    # Epipolar distances constrain one direction per point: half the rotation information.
    info = 0.5 * _information(Qe, bj[e_inl], max(res_e, 0.02) / focal)
    return PairRotation(Qe, n_ess, n, "essential", True, info, res_e)


def relative_rotation(
    pts_i: np.ndarray,
    pts_j: np.ndarray,
    K: np.ndarray,
    *,
    threshold_px: float = 1.0,
    images: tuple[np.ndarray, np.ndarray] | None = None,
) -> PairRotation:
    """Estimate ``Q = R_i.T R_j`` from matched pixels ``pts_i`` (frame i) and ``pts_j`` (frame j):
    :func:`correspondences` then :func:`rotation_from_correspondences`.

    ``K`` is the camera matrix of the images the points were found in; ``threshold_px`` the
    inlier distance in those pixels. With ``images = (grey_i, grey_j)`` the matches are refined
    to sub-pixel accuracy (:func:`refine_by_prewarp`) before the final fit. Never raises on
    degenerate input (too few, identical or non-finite points): the pair comes back failed.
    """
    found = correspondences(pts_i, pts_j, K, threshold_px=threshold_px, images=images)
    if found is None:
        return _failed(0, len(pts_i))
    return rotation_from_correspondences(*found, K, threshold_px=threshold_px)
