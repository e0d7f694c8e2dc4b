"""Gyroscope as a camera-motion source: integration, gyro-to-video sync, focal-length fit.

A body gyro measures the angular rate ``ω(t)`` of the camera in its own (IMU) axes, so the
camera-to-world orientation obeys ``dR/dt = R [ω]×`` and the rotation between two instants is the
ordered product of ``exp(ω dt)`` over the samples between them. Three things separate these
rotations from the frames of the video, and all three are estimated from the video itself, as
Gyroflow does, by comparing the gyro with the rotations vision measures between frames:

* **time offset** ``d``: frame ``k`` shown at ``t_k`` was exposed around gyro time ``t_k + d``
  (clock offsets, exposure, rolling-shutter readout). Found by maximising the correlation of the
  two angular-speed curves ``|ω|`` (independent of the axis mapping and of errors of the focal
  length), coarse over ``±max_offset`` and then to a millisecond;
* **axis mapping** ``M`` (camera = ``M`` · IMU): the least-squares rotation between the two
  angular-velocity series at that offset (Kabsch), snapped to the nearest signed permutation of
  the axes when it is within 20° of one, as real IMUs are mounted along the sensor axes;
* **focal length**: vision's rotation about x and y is the picture's shift divided by the focal
  length, so the slope of vision's rotations on the gyro's gives the focal length at which the
  two agree (roll, which does not depend on it, is left out), independently of any lens table.

Rates are in radians per second, times in seconds on the video clock, rotations camera-to-world
in egovid's camera axes (x right, y down, z forward; see :mod:`egovid.core.rotations`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from egovid.core.camera.telemetry import ImuSamples, OrientationSamples
from egovid.core.rotations import project_to_so3, so3_log

#: Largest time offset (seconds) searched between gyro and video.
MAX_OFFSET_S = 1.0
#: Correlation below which a sync is not trusted (no usable motion, or not the same camera).
MIN_SYNC_R = 0.5
#: Largest gyro bias (degrees per second, norm) a sync may take off. A MEMS gyro's bias is a
#: fraction of a degree per second up to about one (the HERO5's 0.9); what vision and the gyro
#: disagree by beyond that is vision's own error (a lens model that misses the fisheye, parallax
#: taken for a turn: 10-11 °/s on the HERO6 walk through a pinhole model), which a larger bias
#: would hide from every comparison and put into the gyro's own trajectory.
MAX_BIAS_DEG_S = 1.5
#: Step of the fine offset searches (seconds).
FINE_STEP_S = 0.0005


# --------------------------------------------------------------------------------------------
# Quaternion helpers (w, x, y, z), vectorised.


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def _qexp(w: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation vectors ``w`` (..., 3) in radians."""
    angle = np.linalg.norm(w, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a with its limit 1/2 at a = 0.
    k = np.where(angle > 1e-12, np.sin(half) / np.maximum(angle, 1e-300), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), w * k], axis=-1)


def _cumprod_quaternions(q: np.ndarray) -> np.ndarray:
    """Running product ``q[0] q[1] ... q[k]`` for every k (parallel prefix, O(N log N) vectorised)."""
    out = q.copy()
    step = 1
    n = len(q)
    while step < n:
        out[step:] = _qmul(out[: n - step], out[step:])
        step *= 2
        # Renormalise now and then against round-off over millions of samples.
        out /= np.linalg.norm(out, axis=-1, keepdims=True)
    return out


def quaternions_to_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) ``(w, x, y, z)``."""
    from scipy.spatial.transform import Rotation

    q = np.asarray(q, float)
    flat = q.reshape(-1, 4)
    return Rotation.from_quat(flat[:, [1, 2, 3, 0]]).as_matrix().reshape((*q.shape[:-1], 3, 3))


# --------------------------------------------------------------------------------------------
# Integration.


@dataclass(frozen=True)
class GyroTrack:
    """Orientation of the IMU over time, from integrating its rates.

    ``times`` (N,) seconds; ``R`` (N, 3, 3) IMU-to-world rotations (``R[0]`` = identity), in the
    IMU's axes; ``theta`` (N, 3) the running integral of the rate vector in radians (a cheap,
    first-order stand-in used to average rates over intervals when searching the offset).
    """

    times: np.ndarray
    R: np.ndarray
    theta: np.ndarray

    def rotations_at(self, t: np.ndarray) -> np.ndarray:
        """IMU-to-world rotations (len(t), 3, 3) at times ``t`` (spherical interpolation; clamped
        to the first/last sample outside the recorded span)."""
        from scipy.spatial.transform import Rotation, Slerp

        tt = np.clip(np.asarray(t, float), self.times[0], self.times[-1])
        return Slerp(self.times, Rotation.from_matrix(self.R))(tt).as_matrix()

    def mean_rates(self, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
        """Mean angular-rate vectors (len(t0), 3) in rad/s over the intervals ``[t0, t1]``."""
        a = np.column_stack([np.interp(t0, self.times, self.theta[:, i]) for i in range(3)])
        b = np.column_stack([np.interp(t1, self.times, self.theta[:, i]) for i in range(3)])
        return (b - a) / np.maximum(np.asarray(t1) - np.asarray(t0), 1e-9)[:, None]


def integrate(imu: ImuSamples, bias: np.ndarray | None = None) -> GyroTrack:
    """Integrate the gyro of ``imu`` (rates in rad/s, minus ``bias`` (3,) rad/s when given)
    into orientations at the sample times (midpoint rule between samples)."""
    t = np.asarray(imu.times, float)
    w = np.asarray(imu.gyro, float)
    if bias is not None:
        w = w - np.asarray(bias, float)
    dt = np.diff(t)
    mid = 0.5 * (w[1:] + w[:-1])
    steps = _qexp(mid * dt[:, None])
    q = np.concatenate([[[1.0, 0.0, 0.0, 0.0]], _cumprod_quaternions(steps)])
    theta = np.concatenate([np.zeros((1, 3)), np.cumsum(mid * dt[:, None], axis=0)])
    return GyroTrack(t, quaternions_to_matrices(q), theta)


def orientation_track(samples: OrientationSamples) -> GyroTrack:
    """A :class:`GyroTrack` from orientations the camera recorded itself (e.g. GoPro CORI·IORI):
    rotations relative to the first sample, and the integral of their rates."""
    R = quaternions_to_matrices(samples.quaternions)
    R = np.swapaxes(R[0], -1, -2)[None] @ R
    steps = so3_log(np.swapaxes(R[:-1], -1, -2) @ R[1:])
    theta = np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    return GyroTrack(np.asarray(samples.times, float), R, theta)


# --------------------------------------------------------------------------------------------
# Sync: time offset and axis mapping.


def frame_rates(times: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Angular-velocity vectors (N-1, 3) in rad/s between consecutive orientations ``R`` (N, 3, 3)
    taken at ``times`` (N,), in the body's own axes (right perturbation)."""
    steps = so3_log(np.swapaxes(R[:-1], -1, -2) @ R[1:])
    return steps / np.maximum(np.diff(times), 1e-9)[:, None]


def _corr(a: np.ndarray, b: np.ndarray, w: np.ndarray | None = None) -> float:
    w = np.ones(len(a)) if w is None else w
    if w.sum() <= 0:
        return 0.0
    am = a - np.average(a, weights=w)
    bm = b - np.average(b, weights=w)
    den = math.sqrt(float(np.sum(w * am * am) * np.sum(w * bm * bm)))
    return float(np.sum(w * am * bm) / den) if den > 0 else 0.0


def signed_permutations() -> list[np.ndarray]:
    """The 24 proper rotations that permute and flip the three axes."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = np.zeros((3, 3))
            for row, (col, s) in enumerate(zip(perm, signs, strict=True)):
                M[row, col] = s
            if np.linalg.det(M) > 0:
                out.append(M)
    return out


def _kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rotation M minimising sum |dst - M src|² over rows (N, 3)."""
    H = src.T @ dst
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


@dataclass(frozen=True)
class GyroSync:
    """How a gyro lines up with a video.

    ``offset_s``: frame time ``t`` corresponds to gyro time ``t + offset_s``; ``axes`` (3, 3): the
    rotation from IMU axes to camera axes (``ω_cam = axes @ ω_imu``); ``snapped``: ``axes`` is an
    exact signed permutation; ``r_speed``: correlation of the two angular-speed curves at the
    offset; ``r_vector``: correlation of all three rate components after mapping; ``frames``:
    number of frame intervals compared; ``bias`` (3,) rad/s gyro bias in IMU axes (subtracted
    before integrating).
    """

    offset_s: float
    axes: np.ndarray
    snapped: bool
    r_speed: float
    r_vector: float
    frames: int
    bias: np.ndarray

    @property
    def trusted(self) -> bool:
        """True when the correlation is high enough to believe the sync."""
        return self.r_vector >= MIN_SYNC_R

    def to_dict(self) -> dict:
        """JSON-ready description (offset in milliseconds)."""
        return {
            "offset_ms": round(1000.0 * self.offset_s, 2),
            "axes": self.axes.round(4).tolist(),
            "axes_snapped": self.snapped,
            "r_speed": round(self.r_speed, 4),
            "r_vector": round(self.r_vector, 4),
            "frames_compared": self.frames,
            "bias_deg_s": np.degrees(self.bias).round(4).tolist(),
        }


def sync_gyro(
    track: GyroTrack,
    frame_times: np.ndarray,
    vision_rates: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    max_offset_s: float = MAX_OFFSET_S,
    prior_axes: np.ndarray | None = None,
    estimate_bias: bool = True,
) -> GyroSync:
    """Time offset and axis mapping of a gyro ``track`` against the video.

    ``frame_times`` (N,) seconds; ``vision_rates`` (N-1, 3) rad/s between consecutive frames in
    camera axes (from vision); ``weights`` (N-1,) in [0, 1] (0 for intervals vision failed on).
    ``prior_axes`` is used when the motion is too weak to estimate the mapping; without
    ``estimate_bias`` (orientations the camera recorded itself) the bias stays zero.
    """
    t0, t1 = frame_times[:-1], frame_times[1:]
    wts = np.ones(len(t0)) if weights is None else np.asarray(weights, float)
    v_speed = np.linalg.norm(vision_rates, axis=1)

    def speed_score(d: float) -> float:
        g = track.mean_rates(t0 + d, t1 + d)
        return _corr(v_speed, np.linalg.norm(g, axis=1), wts)

    dt = float(np.median(np.diff(frame_times))) if len(frame_times) > 1 else 1 / 30
    coarse = np.arange(-max_offset_s, max_offset_s + 1e-9, max(0.002, dt / 8))
    scores = np.array([speed_score(d) for d in coarse])
    best = float(coarse[int(np.argmax(scores))])
    offset, _ = _peak(speed_score, np.arange(best - 0.01, best + 0.01 + 1e-9, FINE_STEP_S))
    g = track.mean_rates(t0 + offset, t1 + offset)
    # Axis mapping from the intervals with real motion.
    strong = wts * (np.linalg.norm(g, axis=1) > np.percentile(np.linalg.norm(g, axis=1), 30))
    axes, snapped = _axes(g[strong > 0], vision_rates[strong > 0], prior_axes)
    offset = _refine_offset(track, t0, t1, vision_rates, wts, axes, offset, dt)
    r_speed = speed_score(offset)
    g = track.mean_rates(t0 + offset, t1 + offset)
    mapped = g @ axes.T
    # Bias: the constant part of the gyro rate that vision does not see (MEMS gyros drift by
    # up to a degree per second). The median over the frames is robust to fast moves, where a
    # focal-length error of the vision side would leak into a mean; its norm is capped at
    # MAX_BIAS_DEG_S, so that a constant error of vision is not taken for the gyro's.
    ok = wts > 0
    bias_cam = np.zeros(3)
    if estimate_bias and ok.sum() >= 10:
        bias_cam = np.median(mapped[ok] - vision_rates[ok], axis=0)
        norm = float(np.linalg.norm(bias_cam))
        if norm > np.radians(MAX_BIAS_DEG_S):
            bias_cam *= np.radians(MAX_BIAS_DEG_S) / norm
    bias = axes.T @ bias_cam
    mapped = mapped - bias_cam
    r_vec = _corr(mapped.ravel(), vision_rates.ravel(), np.repeat(wts, 3))
    return GyroSync(offset, axes, snapped, r_speed, r_vec, int((wts > 0).sum()), bias)


def _refine_offset(
    track: GyroTrack,
    t0: np.ndarray,
    t1: np.ndarray,
    v: np.ndarray,
    wts: np.ndarray,
    axes: np.ndarray,
    start: float,
    dt: float,
) -> float:
    """The time offset (seconds) within one frame interval ``dt`` of ``start`` at which the gyro's
    rate vectors, mapped by ``axes``, best match vision's ``v`` (N-1, 3) rad/s: the weighted
    correlation of all three components, each about its own mean (a bias moves none of them).

    The angular speed the coarse search correlates carries little timing where the camera turns
    steadily (a walk: the speed barely changes while its direction does): on the HERO6 walk it
    left the offset 17 ms late and 0.37°/frame between vision and gyro (0.30 at the refined
    offset). With too little motion the start is kept."""
    if (wts > 0).sum() < 10:
        return start

    def score(d: float) -> float:
        m = track.mean_rates(t0 + d, t1 + d) @ axes.T
        mw = np.average(m, axis=0, weights=wts)
        vw = np.average(v, axis=0, weights=wts)
        return _corr((m - mw).ravel(), (v - vw).ravel(), np.repeat(wts, 3))

    best, top = _peak(score, start + np.arange(-dt, dt + 1e-9, FINE_STEP_S))
    return best if top > score(start) else start


def _peak(score: Callable[[float], float], grid: np.ndarray) -> tuple[float, float]:
    """Where ``score`` peaks on ``grid`` (offsets in seconds, :data:`FINE_STEP_S` apart): the best
    grid offset moved to the top of the parabola through it and its two neighbours (where they
    bend down), and the best grid score."""
    scores = np.array([score(d) for d in grid])
    k = int(np.argmax(scores))
    best = float(grid[k])
    if 0 < k < len(grid) - 1:
        y0, y1, y2 = scores[k - 1 : k + 2]
        den = y0 - 2 * y1 + y2
        if den < 0:
            best += 0.5 * (y0 - y2) / den * FINE_STEP_S
    return best, float(scores[k])


def _axes(g: np.ndarray, v: np.ndarray, prior: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """IMU-to-camera rotation from rate pairs (rows of ``g`` IMU, ``v`` camera).

    The best of the 24 signed axis permutations (``max Σ v·Pg``) is taken unless the general
    least-squares rotation is clearly different (over 20°) *and* determined: motion about all
    three axes (the cross-covariance's smallest singular value at least a fifth of the largest).
    With motion about one axis only, the other two are told apart by their weak correlation,
    which still picks the right permutation, while Kabsch would mix them freely.
    """
    if len(g) < 10 or np.linalg.norm(g) < 1e-6:
        return (np.eye(3) if prior is None else prior), True
    H = g.T @ v  # Σ g vᵀ
    perms = signed_permutations()
    scores = [float(np.trace(P @ H)) for P in perms]
    best = perms[int(np.argmax(scores))]
    M = _kabsch(g, v)
    angle = float(np.degrees(np.arccos(np.clip((np.trace(best.T @ M) - 1) / 2, -1, 1))))
    sv = np.linalg.svd(H, compute_uv=False)
    if angle > 20.0 and sv[-1] > 0.2 * sv[0]:
        return project_to_so3(M), False
    return best, True


# --------------------------------------------------------------------------------------------
# Per-frame rotations and comparison.


def frame_rotations(track: GyroTrack, sync: GyroSync, frame_times: np.ndarray) -> np.ndarray:
    """Camera-to-world rotations (N, 3, 3) of the frames, frame 0 = identity, in camera axes:
    ``R_cam(t) = M R_imu(t + d) Mᵀ``. Integrate the gyro with ``sync.bias`` removed first
    (``integrate(imu, bias=sync.bias)``)."""
    R = track.rotations_at(np.asarray(frame_times, float) + sync.offset_s)
    R = np.swapaxes(R[0], -1, -2)[None] @ R
    M = sync.axes
    return project_to_so3(M[None] @ R @ M.T[None])


@dataclass(frozen=True)
class RateComparison:
    """Per-frame rotation of one source against another (e.g. vision against the gyro).

    ``r``: Pearson correlation of the per-frame rotation angles (degrees per frame); ``r_axes``:
    per axis (x, y, z camera axes) of the rotation vectors; ``ratio``: least-squares slope of the
    first source's angles on the second's (1 = same magnitude); ``rms_deg``: RMS difference of the
    per-frame rotation vectors in degrees; ``acf_lag``: autocorrelation of that difference at lags
    1..10 (a periodic error shows as a peak).
    """

    r: float
    r_axes: tuple[float, float, float]
    ratio: float
    rms_deg: float
    acf_lag: tuple[float, ...]
    frames: int

    def to_dict(self) -> dict:
        """JSON-ready figures."""
        return {
            "r": round(self.r, 4),
            "r_axes": [round(x, 4) for x in self.r_axes],
            "ratio": round(self.ratio, 4),
            "rms_deg_per_frame": round(self.rms_deg, 4),
            "error_autocorrelation_lag1_10": [round(x, 3) for x in self.acf_lag],
            "frames": self.frames,
        }


def compare_rotations(R_a: np.ndarray, R_b: np.ndarray, weights: np.ndarray | None = None) -> RateComparison:
    """Compare per-frame rotations (frame k to k+1) of two trajectories (N, 3, 3) of the same
    frames, e.g. vision ``R_a`` against the synced gyro ``R_b``."""
    sa = so3_log(np.swapaxes(R_a[:-1], -1, -2) @ R_a[1:])
    sb = so3_log(np.swapaxes(R_b[:-1], -1, -2) @ R_b[1:])
    w = np.ones(len(sa)) if weights is None else np.asarray(weights, float)
    ma, mb = np.degrees(np.linalg.norm(sa, axis=1)), np.degrees(np.linalg.norm(sb, axis=1))
    ratio = float(np.sum(w * ma * mb) / max(np.sum(w * mb * mb), 1e-18))
    err = np.degrees(sa - sb)
    e = err - np.average(err, axis=0, weights=w) if w.sum() > 0 else err
    denom = float(np.sum(e * e))
    acf = tuple(
        float(np.sum(e[:-lag] * e[lag:]) / denom) if denom > 0 and lag < len(e) else 0.0 for lag in range(1, 11)
    )
    return RateComparison(
        r=_corr(ma, mb, w),
        r_axes=tuple(_corr(sa[:, i], sb[:, i], w) for i in range(3)),
        ratio=ratio,
        rms_deg=float(np.sqrt(np.average(np.sum(err**2, axis=1), weights=w))) if w.sum() > 0 else float("nan"),
        acf_lag=acf,
        frames=int((w > 0).sum()),
    )


# --------------------------------------------------------------------------------------------
# Focal length from the gyro.


@dataclass(frozen=True)
class FocalFit:
    """Focal length fitted from the gyro against vision.

    ``focal_px`` in pixels of the full-resolution video; ``pairs`` frame pairs used; ``scale``
    the slope of vision's rotation about x and y on the gyro's at ``start_px`` (vision angles
    scale with 1/focal); ``start_px`` the focal length vision assumed; ``well_posed`` whether
    enough pairs turned about x or y for the focal length to be observable.
    """

    focal_px: float
    pairs: int
    scale: float
    start_px: float
    well_posed: bool

    def to_dict(self) -> dict:
        """JSON-ready figures."""
        return {
            "focal_px": round(self.focal_px, 2),
            "pairs": self.pairs,
            "vision_over_gyro_at_start": round(self.scale, 4),
            "start_focal_px": round(self.start_px, 2),
            "well_posed": self.well_posed,
        }


#: Pairs must turn at least this much (degrees) about x or y to inform the focal length.
_MIN_FIT_TURN_DEG = 0.3
#: At least this many such pairs make a fit.
_MIN_FIT_PAIRS = 15


def fit_focal(pairs: list[tuple[int, int, np.ndarray]], R_gyro: np.ndarray, start_focal_px: float) -> FocalFit:
    """The focal length at which vision's rotations have the gyro's magnitude.

    ``pairs``: ``(i, j, Q_ij)`` rotations vision measured between frames i and j with focal
    length ``start_focal_px``; ``R_gyro`` (N, 3, 3) the synced gyro's rotations of the frames.
    A rotation about x or y moves the picture by about focal x angle pixels, so vision's angle
    about those axes scales with 1/focal (roll does not depend on it): the focal length is the
    start times the least-squares slope of vision's x/y rotation components on the gyro's (pairs
    with outlying residuals, beyond 3 robust standard deviations, left out). A pinhole focal
    length of a fisheye lens depends on where in the picture it is measured; this one is where
    vision measures, so vision and gyro agree with it.
    """
    v, g = [], []
    for i, j, Q in pairs:
        if j >= len(R_gyro):
            continue
        gq = so3_log(R_gyro[i].T @ R_gyro[j])[:2]
        if np.degrees(np.linalg.norm(gq)) >= _MIN_FIT_TURN_DEG:
            v.append(so3_log(Q)[:2])
            g.append(gq)
    if not v:
        return FocalFit(start_focal_px, 0, float("nan"), start_focal_px, False)
    V, G = np.asarray(v), np.asarray(g)
    keep = np.ones(len(V), bool)
    scale = 1.0
    for _ in range(3):
        scale = float(np.sum(V[keep] * G[keep]) / max(np.sum(G[keep] ** 2), 1e-18))
        res = np.linalg.norm(V - scale * G, axis=1)
        mad = 1.4826 * float(np.median(res[keep])) + 1e-12
        keep = res < 3.0 * mad + 1e-9
    n = int(keep.sum())
    return FocalFit(start_focal_px * scale, n, scale, start_focal_px, n >= _MIN_FIT_PAIRS)
