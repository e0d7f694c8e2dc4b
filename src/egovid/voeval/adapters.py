"""Visual odometers under evaluation, each giving per-frame camera rotations in egovid's
convention (camera-to-world, x right, y down, z forward, relative to the first frame),
re-orthonormalised, the camera positions where it estimates them (in its own scale), a mask of the
frames it actually tracked, and why it lost frames or failed (:class:`Diagnosis`).

Built-in odometers live in the registry :data:`ODOMETERS` (name -> class, in the default order):

* ``egovid`` — egovid's own estimator (features, pairwise RANSAC, SO(3) pose graph);
* ``ecc`` — a direct method: ECC alignment of consecutive frames with a homography
  (``cv2.findTransformECC``), rotation ``K⁻¹HK`` projected to SO(3), chained;
* ``monovo`` — the classic Mono-VO recipe: FAST corners tracked by KLT, essential matrix +
  ``recoverPose`` per frame pair, chained (unit-length steps: no scale); features re-detected when
  too few survive;
* ``colmap`` — incremental structure from motion (pycolmap, the VisualSfM-like method), run in a
  separate process (pycolmap and OpenCV ship clashing libraries); unregistered frames are lost;
* ``orbslam3`` — ORB-SLAM3 monocular (pyorbslam3) with a vocabulary built locally from bundled
  photos (no download), in a separate process; frames before initialisation are lost.

Besides them, :class:`CommandVO` runs any external odometer (``--vo-cmd "tool {video} {out}"``
writing TUM or KITTI; OpenCV or OpenGL camera axes).

A VO that crashes, times out or loses track is recorded with its status and its diagnosis (the
reason, the exit status and the last lines of its output); lost frames hold the last tracked pose
(a VO that never tracks scores as "no motion").
"""

from __future__ import annotations

import importlib.util
import json
import math
import resource
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.motion.estimate import MotionOptions, estimate_motion
from egovid.core.rotations import project_to_so3
from egovid.core.trajectory import read_trajectory
from egovid.core.video import count_frames, iter_frames, probe
from egovid.voeval import colmap_worker, orbslam_worker
from egovid.voeval.orbvocab import build_vocabulary
from egovid.voeval.sequences import match_reference

OPENGL_TO_CV = np.diag([1.0, -1.0, -1.0])
#: Lines of an odometer's own output (stderr, then stdout) kept when it fails or loses frames.
LOG_LINES = 12
#: Seconds an external odometer (worker or command) may run on one video.
DEFAULT_TIMEOUT_S = 600.0


@dataclass
class Diagnosis:
    """Why an odometer lost frames or failed: ``reason`` (one line, empty when all went well), the
    exit status of its process (None when it ran in this process or was killed by the timeout),
    whether it ran past its time limit, and the last lines of its output."""

    reason: str = ""
    exit_status: int | None = None
    timed_out: bool = False
    log_tail: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class VOResult:
    """Rotations (N, 3, 3) of a VO on one video, what it tracked, and how it went. ``t`` (N, 3):
    camera positions in the odometer's own world and scale, relative to its first pose (None: it
    gives no positions)."""

    R: np.ndarray
    valid: np.ndarray
    status: str = "ok"  # ok | lost-tracking | failed | timeout
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    t: np.ndarray | None = None
    diagnosis: Diagnosis = field(default_factory=Diagnosis)
    extra: dict = field(default_factory=dict)


def lost_result(n: int, status: str, diagnosis: Diagnosis) -> VOResult:
    """A run that gave no pose for any of ``n`` frames."""
    return VOResult(np.repeat(np.eye(3)[None], n, 0), np.zeros(n, bool), status, diagnosis=diagnosis)


def output_tail(*texts: str | bytes | None, lines: int = LOG_LINES) -> list[str]:
    """The last ``lines`` non-empty lines of a process's outputs (stderr first, then stdout)."""
    out: list[str] = []
    for text in texts:
        if isinstance(text, bytes):
            text = text.decode("utf-8", errors="replace")
        out += [ln.rstrip() for ln in (text or "").splitlines() if ln.strip()]
    return [ln[:300] for ln in out[-lines:]]


def exit_reason(what: str, returncode: int) -> str:
    """How a process ended: "exited with status N", or the signal that killed it (a crash)."""
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        return f"{what} was killed by {name}"
    return f"{what} exited with status {returncode}"


def finalize(
    R: np.ndarray, valid: np.ndarray, n: int, t: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Hold the last tracked pose over lost frames, orthonormalise, make the first tracked frame
    the identity at the origin. Returns (R, valid, t) of length ``n`` (t None when not given)."""
    R = np.asarray(R, dtype=float)[:n]
    valid = np.asarray(valid, dtype=bool)[:n]
    pos = None if t is None else np.asarray(t, dtype=float)[:n]
    if len(R) < n:
        R = np.concatenate([R, np.repeat(np.eye(3)[None], n - len(R), 0)])
        valid = np.concatenate([valid, np.zeros(n - len(valid), bool)])
    if pos is not None and len(pos) < n:
        pos = np.concatenate([pos, np.zeros((n - len(pos), 3))])
    out = np.repeat(np.eye(3)[None], n, 0)
    out_t = np.zeros((n, 3))
    if valid.any():
        first = int(np.argmax(valid))
        ref = project_to_so3(R[first])
        last, last_t = np.eye(3), np.zeros(3)
        for k in range(n):
            if valid[k]:
                last = ref.T @ project_to_so3(R[k])
                if pos is not None:
                    last_t = ref.T @ (pos[k] - pos[first])
            out[k] = last
            out_t[k] = last_t
    return project_to_so3(out), valid, (out_t if pos is not None else None)


def anchor_to_truth(R: np.ndarray, valid: np.ndarray, R_gt: np.ndarray) -> np.ndarray:
    """Express an estimate that started tracking late in the ground truth's frame.

    :func:`finalize` makes the first *tracked* frame the identity; when that is not frame 0, the
    odometer could not know how far the camera had turned before it initialised. Its trajectory is
    anchored to the true orientation of its first tracked frame; the frames before stay at the
    identity (no estimate means "no motion"), so the late start is still paid for.
    """
    if not valid.any():
        return R
    first = int(np.argmax(valid))
    if first == 0:
        return R
    out = R.copy()
    out[first:] = R_gt[first] @ R[first:]
    return out


def tracking_status(valid: np.ndarray) -> str:
    """``failed`` (no frame), ``lost-tracking`` (some) or ``ok`` (all frames tracked)."""
    if not valid.any():
        return "failed"
    return "ok" if valid.all() else "lost-tracking"


def lost_frames_reason(valid: np.ndarray) -> str:
    """One line on which frames an odometer gave no pose for ("" when it tracked all)."""
    n, k = len(valid), int(np.sum(valid))
    if k == n:
        return ""
    if k == 0:
        return f"no pose for any of the {n} frames"
    first = int(np.argmax(valid))
    return f"poses for {k} of {n} frames (first at frame {first})"


def _result(R, valid, n, t=None, reason: str = "", **kw) -> VOResult:
    Rf, v, tf = finalize(R, valid, n, t)
    return VOResult(Rf, v, tracking_status(v), t=tf, diagnosis=Diagnosis(reason or lost_frames_reason(v)), **kw)


class VisualOdometer:
    """Base class: ``run(video, intrinsics, workdir, dataset) -> VOResult``.

    Class attributes describe the method: ``assumes_pure_rotation`` (it models the image motion
    as a pure camera rotation, a homography ``K R K⁻¹``, so it cannot work by design on scenes
    where the camera translates near the scene: the report marks it out of its domain there),
    ``needs_parallax`` (monocular two-view initialisation: it gives nothing until two views are far
    enough apart), ``slow_rank`` (the grid starts slow odometers first). ``dataset`` names the kind
    of footage (``synthetic``, ``euroc``, ``tum``, ``kitti``, ``frames``, ``gyro``) for odometers
    with settings per dataset camera.
    """

    name = "vo"
    assumes_pure_rotation = False
    needs_parallax = False
    slow_rank = 9

    @classmethod
    def missing(cls) -> str | None:
        """Why it cannot run here, as the fix to give the user (None: it can)."""
        return None

    def run(self, video: Path, intr: Intrinsics, workdir: Path, dataset: str = "synthetic") -> VOResult:
        raise NotImplementedError


#: The built-in odometers by name, in the default order.
ODOMETERS: dict[str, type[VisualOdometer]] = {}


def builtin(cls: type[VisualOdometer]) -> type[VisualOdometer]:
    """Register a built-in odometer class under its ``name``."""
    ODOMETERS[cls.name] = cls
    return cls


@builtin
class EgovidVO(VisualOdometer):
    """egovid's own rotation estimator with its default options (one thread: the grid runs one
    cell per core)."""

    name = "egovid"
    assumes_pure_rotation = True
    slow_rank = 2

    def run(self, video, intr, workdir, dataset="synthetic") -> VOResult:
        est = estimate_motion(video, intr, MotionOptions(threads=1))
        n = len(est.trajectory)
        failed_steps = {i for i, j, p in est.pairs if j == i + 1 and not p.ok}
        valid = np.ones(n, bool)
        for i in failed_steps:
            valid[i + 1] = False
        reason = f"{len(failed_steps)} frame-to-frame steps failed (orientation held)" if failed_steps else ""
        return _result(est.trajectory.R, valid, n, reason=reason)


@builtin
class EccVO(VisualOdometer):
    """Direct method: frame-to-frame ECC homography, rotation from K⁻¹HK.

    Like direct methods on an image pyramid, it aligns a pyramid level about :attr:`work_width`
    pixels wide (640x480 frames: the half-size level), starting from the previous frame pair's
    motion (constant velocity). On the 300-frame 640x480 scenes this was 3 times faster than
    full-size ECC refined from the half-size level, and no less accurate (compression noise
    dominates the finest level). A frame pair that does not converge is lost (orientation held)."""

    name = "ecc"
    assumes_pure_rotation = True
    work_width = 400
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 1e-5)

    def run(self, video, intr, workdir, dataset="synthetic") -> VOResult:
        K, Ki = intr.K, intr.K_inv
        levels = max(0, round(math.log2(intr.width / self.work_width)))
        S = np.diag([0.5**levels, 0.5**levels, 1.0])  # full-size pixels -> pyramid-level pixels
        S_inv = np.linalg.inv(S)
        prev = None
        last = np.eye(3)
        R = [np.eye(3)]
        valid = [True]
        for f in iter_frames(video, gray=True):
            g = cv2.GaussianBlur(f.image, (5, 5), 1.0)
            for _ in range(levels):
                g = cv2.pyrDown(g)
            g = g.astype(np.float32)
            if prev is not None:
                try:
                    warp = (S @ last @ S_inv).astype(np.float32)
                    _, warp = cv2.findTransformECC(prev, g, warp, cv2.MOTION_HOMOGRAPHY, self.criteria, None, 5)
                    # warp maps frame-(k-1) pixels to frame-k pixels: K Q K^-1 with Q = R_k^T R_{k-1},
                    # so R_k = R_{k-1} Q^T.
                    last = S_inv @ warp.astype(float) @ S
                    Q = project_to_so3(Ki @ last @ K)
                    R.append(R[-1] @ Q.T)
                    valid.append(True)
                except cv2.error:
                    last = np.eye(3)
                    R.append(R[-1])
                    valid.append(False)
            prev = g
        return _result(np.stack(R), np.array(valid), len(R))


@builtin
class MonoVO(VisualOdometer):
    """FAST + KLT + essential matrix, chained (no bundle adjustment). Positions chain the
    unit-length translation of each frame pair (monocular: no scale)."""

    name = "monovo"
    needs_parallax = True

    def run(self, video, intr, workdir, dataset="synthetic") -> VOResult:
        K = intr.K
        fast = cv2.FastFeatureDetector_create(threshold=20, nonmaxSuppression=True)
        lk = {
            "winSize": (21, 21),
            "maxLevel": 3,
            "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
        }
        prev, pts = None, None
        R, t = [np.eye(3)], [np.zeros(3)]
        valid = [True]
        for f in iter_frames(video, gray=True):
            g = f.image
            if prev is None:
                pts = np.array([k.pt for k in fast.detect(g)], np.float32).reshape(-1, 1, 2)
                prev = g
                continue
            ok = False
            if pts is not None and len(pts) >= 8:
                nxt, st, _ = cv2.calcOpticalFlowPyrLK(prev, g, pts, None, **lk)
                good = st.ravel() == 1
                p0, p1 = pts[good].reshape(-1, 2), nxt[good].reshape(-1, 2)
                if len(p0) >= 8:
                    E, mask = cv2.findEssentialMat(p1, p0, K, cv2.RANSAC, 0.999, 1.0)
                    if E is not None and E.shape == (3, 3):
                        _, Rr, tr, _ = cv2.recoverPose(E, p1, p0, K, mask=mask)
                        # (Rr, tr) map frame-k coordinates to frame k-1: X_{k-1} = Rr X_k + tr, so
                        # R_k = R_{k-1} Rr and the camera centre moves by R_{k-1} tr.
                        t.append(t[-1] + R[-1] @ tr.ravel())
                        R.append(R[-1] @ Rr)
                        ok = True
                pts = p1.reshape(-1, 1, 2)
            if not ok:
                R.append(R[-1])
                t.append(t[-1])
            valid.append(ok)
            if pts is None or len(pts) < 300:
                pts = np.array([k.pt for k in fast.detect(g)], np.float32).reshape(-1, 1, 2)
            prev = g
        return _result(np.stack(R), np.array(valid), len(R), np.stack(t))


class WorkerVO(VisualOdometer):
    """An odometer run by an egovid worker module in its own process (crash isolation, and no
    native-library clashes with OpenCV), on frames as PNG files or, when :attr:`reads_video`, on
    the video itself (the worker decodes it: no frame folder written and read back).

    It is called as ``python -m MODULE SOURCE OUT.json SETTINGS.json`` (:meth:`settings`) and
    writes JSON ``{"rotations": {frame: 3x3}, "positions": {frame: [x, y, z]}, "frames": N (when it
    reads the video), "notes": {...}}``; :meth:`rotation` turns an entry into camera-to-world,
    :meth:`notes_reason` the notes into a reason. :meth:`frames` chooses the frames the worker
    sees as PNG files (default: all)."""

    module = ""
    reads_video = False

    def __init__(self, timeout: float = DEFAULT_TIMEOUT_S) -> None:
        self.timeout = timeout

    def settings(self, intr: Intrinsics, fps: float, dataset: str) -> dict:
        return {}

    def rotation(self, matrix: np.ndarray) -> np.ndarray:
        return matrix

    def frames(self, n: int) -> np.ndarray:
        """Indices of the frames given to the worker, out of ``n``."""
        return np.arange(n)

    def fill(self, R, t, valid, given) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Poses of the frames not given to the worker (default: none, they are lost)."""
        return R, t, valid

    def notes_reason(self, notes: dict, valid: np.ndarray) -> str:
        """One line from the worker's notes on why frames were lost (default: which ones)."""
        return lost_frames_reason(valid)

    def _source(self, video: Path, workdir: Path) -> Path:
        if self.reads_video:
            return video
        source = workdir / "frames"
        source.mkdir(parents=True, exist_ok=True)
        wanted = set(self.frames(count_frames(video)).tolist())
        for f in iter_frames(video):
            if f.index in wanted:
                cv2.imwrite(str(source / f"{f.index:06d}.png"), f.image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        return source

    def run(self, video, intr, workdir, dataset="synthetic") -> VOResult:
        source = self._source(video, workdir)
        out, cfg = workdir / "worker.json", workdir / "settings.json"
        cfg.write_text(json.dumps(self.settings(intr, probe(video).fps, dataset)))
        cmd = [sys.executable, "-m", self.module, str(source), str(out), str(cfg)]
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=self.timeout)
        except subprocess.TimeoutExpired as exc:
            why = Diagnosis(f"timed out after {self.timeout:.0f} s", None, True, output_tail(exc.stderr, exc.stdout))
            return lost_result(count_frames(video), "timeout", why)
        tail = output_tail(r.stderr, r.stdout)
        if r.returncode != 0 or not out.exists():
            why = exit_reason(f"the {self.name} worker", r.returncode) + ("" if out.exists() else ", no output")
            return lost_result(count_frames(video), "failed", Diagnosis(why, r.returncode, False, tail))
        got = json.loads(out.read_text())
        n = int(got["frames"]) if self.reads_video else count_frames(video)
        given = self.frames(n)
        R, t, valid = np.repeat(np.eye(3)[None], n, 0), np.zeros((n, 3)), np.zeros(n, bool)
        positions = got.get("positions", {})
        for key, rot in got["rotations"].items():
            k = int(Path(key).stem)
            if k < n:
                R[k] = self.rotation(np.array(rot))
                t[k] = positions.get(key, (0.0, 0.0, 0.0))
                valid[k] = True
        notes = got.get("notes", {})
        extra = {"worker_frames": len(given), "worker_poses": int(valid.sum()), **notes}
        R, t, valid = self.fill(R, t, valid, given)
        Rf, v, tf = finalize(R, valid, n, t if positions else None)
        why = Diagnosis(self.notes_reason(notes, v), r.returncode, False, tail if not v.all() else [])
        return VOResult(Rf, v, tracking_status(v), t=tf, diagnosis=why, extra=extra)


@builtin
class ColmapVO(WorkerVO):
    """pycolmap incremental mapping (SIFT, sequential matching, fixed pinhole intrinsics) on
    keyframes, as SfM is used on video: at most :attr:`max_images` (30) frames, evenly spaced (every
    ``ceil(N / max_images)``-th, and the last); the frames between two registered keyframes are
    interpolated (slerp for rotations, linear for positions), frames outside the registered ones
    are lost. SIFT starts at the original resolution (``first_octave`` 0, at most 1024 features per
    image). See :mod:`egovid.voeval.colmap_worker` for what is tried when no model is built."""

    name = "colmap"
    module = "egovid.voeval.colmap_worker"
    max_images = 30
    needs_parallax = True
    slow_rank = 0

    @classmethod
    def missing(cls) -> str | None:
        return None if importlib.util.find_spec("pycolmap") else "pip install pycolmap"

    def settings(self, intr, fps, dataset) -> dict:
        return {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy}

    def rotation(self, matrix: np.ndarray) -> np.ndarray:
        return matrix.T  # cam_from_world -> camera-to-world

    def frames(self, n: int) -> np.ndarray:
        stride = max(1, -(-n // self.max_images))
        idx = np.arange(0, n, stride)
        return idx if idx[-1] == n - 1 else np.append(idx, n - 1)

    def fill(self, R, t, valid, given):
        reg = given[valid[given]]
        if len(reg) < 2:
            return R, t, valid
        # Registered keyframes with unregistered ones between them leave a gap: not interpolated.
        stride = int(np.median(np.diff(given))) if len(given) > 1 else 1
        frames = np.arange(reg[0], reg[-1] + 1)
        Ri, ok = match_reference(frames.astype(float), reg.astype(float), R[reg], max_gap=stride + 1e-9)
        R, t, valid = R.copy(), t.copy(), valid.copy()
        R[frames[ok]] = Ri[ok]
        for axis in range(3):
            t[frames[ok], axis] = np.interp(frames[ok], reg, t[reg, axis])
        valid[frames[ok]] = True
        return R, t, valid

    def notes_reason(self, notes: dict, valid: np.ndarray) -> str:
        return colmap_worker.reason(notes) or lost_frames_reason(valid)


@builtin
class OrbSlam3VO(WorkerVO):
    """ORB-SLAM3 (monocular) through pyorbslam3, with a vocabulary built locally from bundled
    photos (:mod:`egovid.voeval.orbvocab`), on every frame (the worker decodes the video), with
    the ORB settings ORB-SLAM3 ships for the dataset's camera (:data:`orbslam_worker.ORB_PROFILES`)."""

    name = "orbslam3"
    module = "egovid.voeval.orbslam_worker"
    reads_video = True
    needs_parallax = True
    slow_rank = 1

    @classmethod
    def missing(cls) -> str | None:
        return None if importlib.util.find_spec("pyorbslam3") else "pip install pyorbslam3 (x86-64 Linux)"

    def settings(self, intr, fps, dataset) -> dict:
        return orbslam_worker.settings(str(build_vocabulary()), intr, fps, dataset)

    def notes_reason(self, notes: dict, valid: np.ndarray) -> str:
        return orbslam_worker.reason(notes) or lost_frames_reason(valid)


class CommandVO(VisualOdometer):
    """An external odometer run as ``template.format(video=..., out=...)`` writing TUM or KITTI.

    TUM rows are matched to the video's frames by timestamp (seconds from the first frame,
    nearest frame within half a frame interval), so an odometer may skip frames; KITTI rows (no
    times) are frames in order. Frames without a pose are lost. Its positions count as given when
    they are not all zero.
    """

    def __init__(
        self, template: str, name: str = "cmd", convention: str = "opencv", timeout: float = DEFAULT_TIMEOUT_S
    ):
        self.template = template
        self.name = name
        self.convention = convention
        self.timeout = timeout

    def run(self, video, intr, workdir, dataset="synthetic") -> VOResult:
        times = np.array([f.time for f in iter_frames(video, gray=True)])
        n = len(times)
        out = workdir / f"{self.name}.txt"
        cmd = self.template.format(
            video=shlex.quote(str(video)),
            out=shlex.quote(str(out)),
            fx=intr.fx,
            fy=intr.fy,
            cx=intr.cx,
            cy=intr.cy,
            width=intr.width,
            height=intr.height,
        )
        try:
            r = subprocess.run(cmd, shell=True, capture_output=True, text=True, timeout=self.timeout)
        except subprocess.TimeoutExpired as exc:
            why = Diagnosis(f"timed out after {self.timeout:g} s", None, True, output_tail(exc.stderr, exc.stdout))
            return lost_result(n, "timeout", why)
        tail = output_tail(r.stderr, r.stdout)
        if r.returncode != 0 or not out.exists():
            why = exit_reason("the command", r.returncode) + ("" if out.exists() else f", no {out.name}")
            return lost_result(n, "failed", Diagnosis(why, r.returncode, False, tail))
        try:
            traj = read_trajectory(out)
        except EgovidError as exc:  # a broken output file is a failed run, not a crash of the grid
            return lost_result(n, "failed", Diagnosis(f"unreadable output: {exc.message}"[:300], 0, False, tail))
        R, t = traj.R, traj.t
        if self.convention == "opengl":
            R, t = OPENGL_TO_CV @ R @ OPENGL_TO_CV, t @ OPENGL_TO_CV
        if _has_times(out):
            R, t, valid = _match_rows(traj.times, R, t, times)
        else:
            valid = np.ones(len(R), bool)
        res = _result(R, valid, n, t if np.any(t) else None)
        if res.diagnosis.reason:
            res.diagnosis.exit_status, res.diagnosis.log_tail = r.returncode, tail
        return res


def _has_times(path: Path) -> bool:
    """True for TUM files (8 columns: a timestamp first), False for KITTI (12)."""
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        if line.strip() and not line.startswith("#"):
            return len(line.replace(",", " ").split()) == 8
    return False


def _match_rows(
    row_times: np.ndarray, R: np.ndarray, t: np.ndarray, frame_times: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Put timed poses on frames: each row goes to the nearest frame within half a frame interval."""
    n = len(frame_times)
    out, out_t = np.repeat(np.eye(3)[None], n, 0), np.zeros((n, 3))
    valid = np.zeros(n, bool)
    if n == 0:
        return out, out_t, valid
    half = 0.5 * (float(np.median(np.diff(frame_times))) if n > 1 else 1.0)
    k = np.clip(np.searchsorted(frame_times, row_times), 0, n - 1)
    k_prev = np.clip(k - 1, 0, n - 1)
    nearest = np.where(np.abs(frame_times[k_prev] - row_times) < np.abs(frame_times[k] - row_times), k_prev, k)
    ok = np.abs(frame_times[nearest] - row_times) <= half + 1e-9
    out[nearest[ok]] = R[ok]
    out_t[nearest[ok]] = t[ok]
    valid[nearest[ok]] = True
    return out, out_t, valid


def _cpu_seconds() -> float:
    """CPU seconds used so far by this process and the child processes it has waited for."""
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + kids.ru_utime + kids.ru_stime


def timed_run(vo: VisualOdometer, video: Path, intr: Intrinsics, workdir: Path, dataset: str = "synthetic") -> VOResult:
    """Run a VO, turning any exception into a ``failed`` result (its type and message the reason).
    Sets ``seconds`` (wall) and ``cpu_seconds`` (this process and the odometer's own processes: a
    figure that does not depend on what else runs on the machine)."""
    workdir.mkdir(parents=True, exist_ok=True)
    t, cpu = time.perf_counter(), _cpu_seconds()
    try:
        res = vo.run(video, intr, workdir, dataset)
    except Exception as exc:
        res = lost_result(count_frames(video), "failed", Diagnosis(f"{type(exc).__name__}: {exc}"[:300]))
    res.seconds = time.perf_counter() - t
    res.cpu_seconds = _cpu_seconds() - cpu
    return res


def available_vos() -> list[str]:
    """The built-in odometers that can run here (ORB-SLAM3 only where pyorbslam3 installs)."""
    return [n for n, cls in ODOMETERS.items() if cls.missing() is None]


def split_command(command: str, index: int) -> tuple[str, str]:
    """``"[NAME=]template"`` of ``--vo-cmd`` -> (name, template); unnamed: ``cmd1``, ``cmd2``..."""
    head = command.split(" ")[0]
    name, _, tmpl = command.partition("=") if "=" in head else (f"cmd{index + 1}", "", command)
    if "{video}" not in tmpl or "{out}" not in tmpl:
        raise EgovidError(
            f"--vo-cmd {command!r} lacks {{video}} or {{out}}", 'write e.g. --vo-cmd "myvo {video} {out}"'
        )
    if name in ODOMETERS or name.startswith("floor-"):
        raise EgovidError(f"--vo-cmd name {name!r} is a built-in odometer or floor", "give the command another NAME=")
    return name, tmpl


def make_vos(
    names: list[str], commands: list[str] | None = None, timeout: float = DEFAULT_TIMEOUT_S
) -> list[VisualOdometer]:
    """Odometers by name (``egovid, ecc, monovo, colmap, orbslam3``) plus external commands;
    ``timeout`` (seconds) bounds every odometer run in its own process."""
    out: list[VisualOdometer] = []
    for n in names:
        cls = ODOMETERS.get(n)
        if cls is None:
            raise EgovidError(f"unknown visual odometer {n!r}", f"choose from {', '.join(ODOMETERS)} or use --vo-cmd")
        if cls.missing() is not None:
            raise EgovidError(f"visual odometer {n!r} is not installed", cls.missing())
        out.append(cls(timeout) if issubclass(cls, WorkerVO) else cls())
    for i, c in enumerate(commands or []):
        name, template = split_command(c, i)
        out.append(CommandVO(template, name, timeout=timeout))
    names_seen = [v.name for v in out]
    dup = sorted({v for v in names_seen if names_seen.count(v) > 1})
    if dup:
        raise EgovidError(f"odometer name(s) {', '.join(dup)} given twice", "name each --vo-cmd differently (NAME=...)")
    return out


def make_vo(name: str, commands: list[str] | None = None, timeout: float = DEFAULT_TIMEOUT_S) -> VisualOdometer:
    """One odometer of :func:`make_vos` by name."""
    if name in ODOMETERS:
        return make_vos([name], timeout=timeout)[0]
    return next(v for v in make_vos([], commands, timeout) if v.name == name)
