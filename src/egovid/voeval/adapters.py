"""Visual odometers under evaluation, each giving per-frame camera rotations in egovid's
convention (camera-to-world, x right, y down, z forward, relative to the first frame),
re-orthonormalised, with a mask of the frames it actually tracked.

* ``egovid`` — egovid's own estimator (features, pairwise RANSAC, SO(3) pose graph);
* ``ecc`` — a direct method: ECC alignment of consecutive frames with a homography
  (``cv2.findTransformECC``), rotation ``K⁻¹HK`` projected to SO(3), chained;
* ``monovo`` — the classic Mono-VO recipe: FAST corners tracked by KLT, essential matrix +
  ``recoverPose`` per frame pair, chained; features re-detected when too few survive;
* ``colmap`` — incremental structure from motion (pycolmap, the VisualSfM-like method), run in a
  separate process (pycolmap and OpenCV ship clashing libraries); unregistered frames are lost;
* ``orbslam3`` — ORB-SLAM3 monocular (pyorbslam3) with a vocabulary built locally from bundled
  photos (no download), in a separate process; frames before initialisation are lost;
* ``cmd`` — any external odometer: ``--vo-cmd "tool {video} {out}"`` writing TUM or KITTI;
  the convention can be OpenCV (default) or OpenGL (y up, z backwards).

A VO that crashes, times out or loses track is recorded with its status; lost frames hold the last
tracked orientation (a VO that never tracks scores as "no motion").
"""

from __future__ import annotations

import json
import math
import shlex
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.rotations import project_to_so3
from egovid.core.trajectory import read_trajectory
from egovid.core.video import iter_frames

OPENGL_TO_CV = np.diag([1.0, -1.0, -1.0])


@dataclass
class VOResult:
    """Rotations (N, 3, 3) of a VO on one video, what it tracked, and how it went."""

    R: np.ndarray
    valid: np.ndarray
    status: str = "ok"  # ok | lost-tracking | failed | timeout
    seconds: float = 0.0
    message: str = ""
    extra: dict = field(default_factory=dict)


def finalize(R: np.ndarray, valid: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Hold the last tracked orientation over lost frames, orthonormalise, make frame 0 the
    identity. Returns (R, valid) of length ``n``."""
    R = np.asarray(R, dtype=float)[:n]
    valid = np.asarray(valid, dtype=bool)[:n]
    if len(R) < n:
        R = np.concatenate([R, np.repeat(np.eye(3)[None], n - len(R), 0)])
        valid = np.concatenate([valid, np.zeros(n - len(valid), bool)])
    out = np.repeat(np.eye(3)[None], n, 0)
    if valid.any():
        first = int(np.argmax(valid))
        ref = project_to_so3(R[first])
        last = np.eye(3)
        for k in range(n):
            if valid[k]:
                last = ref.T @ project_to_so3(R[k])
            out[k] = last
    return project_to_so3(out), valid


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


def _status(valid: np.ndarray) -> str:
    if not valid.any():
        return "failed"
    return "ok" if valid.all() else "lost-tracking"


class VisualOdometer:
    """Base class: ``run(video, intrinsics, workdir) -> VOResult``.

    ``assumes_pure_rotation``: the odometer models the image motion as a pure camera rotation
    (a homography ``K R K⁻¹``), so it cannot work by design on scenes where the camera translates
    near the scene (the orbit scenes); the report marks it out of its domain there.
    """

    name = "vo"
    assumes_pure_rotation = False

    def run(self, video: Path, intr: Intrinsics, workdir: Path) -> VOResult:
        raise NotImplementedError


class EgovidVO(VisualOdometer):
    """egovid's own rotation estimator with its default options (one thread: the grid runs one
    cell per core)."""

    name = "egovid"
    assumes_pure_rotation = True

    def run(self, video, intr, workdir) -> VOResult:
        from egovid.core.motion.estimate import MotionOptions, estimate_motion

        est = estimate_motion(video, intr, MotionOptions(threads=1))
        n = len(est.trajectory)
        failed_steps = {i for i, j, p in est.pairs if j == i + 1 and not p.ok}
        valid = np.ones(n, bool)
        for i in failed_steps:
            valid[i + 1] = False
        R, valid = finalize(est.trajectory.R, valid, n)
        return VOResult(R, valid, _status(valid))


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

    def run(self, video, intr, workdir) -> VOResult:
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
        Rf, v = finalize(np.stack(R), np.array(valid), len(R))
        return VOResult(Rf, v, _status(v))


class MonoVO(VisualOdometer):
    """FAST + KLT + essential matrix, chained (no bundle adjustment)."""

    name = "monovo"

    def run(self, video, intr, workdir) -> VOResult:
        K = intr.K
        fast = cv2.FastFeatureDetector_create(threshold=20, nonmaxSuppression=True)
        lk = {
            "winSize": (21, 21),
            "maxLevel": 3,
            "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
        }
        prev, pts = None, None
        R = [np.eye(3)]
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
                        _, Rr, _, _ = cv2.recoverPose(E, p1, p0, K, mask=mask)
                        # Rr maps frame-k coordinates to frame-(k-1): R_k = R_{k-1} Rr.
                        R.append(R[-1] @ Rr)
                        ok = True
                pts = p1.reshape(-1, 1, 2)
            if not ok:
                R.append(R[-1])
            valid.append(ok)
            if pts is None or len(pts) < 300:
                pts = np.array([k.pt for k in fast.detect(g)], np.float32).reshape(-1, 1, 2)
            prev = g
        Rf, v = finalize(np.stack(R), np.array(valid), len(R))
        return VOResult(Rf, v, _status(v))


class WorkerVO(VisualOdometer):
    """An odometer run by an egovid worker module in its own process (crash isolation, and no
    native-library clashes with OpenCV), on frames as PNG files or, when :attr:`reads_video`, on
    the video itself (the worker decodes it: no frame folder written and read back). The worker
    writes JSON ``{"rotations": {frame: 3x3}}`` (plus ``"frames": N`` when it reads the video);
    :meth:`rotation` turns an entry into camera-to-world. :meth:`frames` chooses the frames the
    worker sees as PNG files (default: all)."""

    module = ""
    reads_video = False

    def __init__(self, timeout: float = 600.0) -> None:
        self.timeout = timeout

    def worker_args(self, intr: Intrinsics, fps: float) -> list[str]:
        return []

    def rotation(self, matrix: np.ndarray) -> np.ndarray:
        return matrix

    def frames(self, n: int) -> np.ndarray:
        """Indices of the frames given to the worker, out of ``n``."""
        return np.arange(n)

    def fill(self, R: np.ndarray, valid: np.ndarray, given: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Poses of the frames not given to the worker (default: none, they are lost)."""
        return R, valid

    def run(self, video, intr, workdir) -> VOResult:
        from egovid.core.video import count_frames, probe

        if self.reads_video:
            source = video
        else:
            source = workdir / "frames"
            source.mkdir(parents=True, exist_ok=True)
            n = count_frames(video)
            wanted = set(self.frames(n).tolist())
            for f in iter_frames(video):
                if f.index in wanted:
                    cv2.imwrite(str(source / f"{f.index:06d}.png"), f.image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        out = workdir / "worker.json"
        cmd = [sys.executable, "-m", self.module, str(source), str(out), *self.worker_args(intr, probe(video).fps)]

        def lost() -> tuple[np.ndarray, np.ndarray]:
            m = count_frames(video)
            return np.repeat(np.eye(3)[None], m, 0), np.zeros(m, bool)

        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=self.timeout)
        except subprocess.TimeoutExpired:
            return VOResult(*lost(), "timeout")
        if r.returncode != 0 or not out.exists():
            return VOResult(*lost(), "failed", message=(r.stderr or r.stdout)[-300:])
        got = json.loads(out.read_text())
        if self.reads_video:
            n = int(got["frames"])
        given = self.frames(n)
        R, valid = np.repeat(np.eye(3)[None], n, 0), np.zeros(n, bool)
        for key, rot in got["rotations"].items():
            k = int(Path(key).stem)
            if k < n:
                R[k] = self.rotation(np.array(rot))
                valid[k] = True
        extra = {"worker_frames": len(given), "worker_poses": int(valid.sum())}
        R, valid = self.fill(R, valid, given)
        Rf, v = finalize(R, valid, n)
        return VOResult(Rf, v, _status(v), extra=extra)


class ColmapVO(WorkerVO):
    """pycolmap incremental mapping (SIFT, sequential matching, fixed pinhole intrinsics) on
    keyframes, as SfM is used on video: at most :attr:`max_images` (30) frames, evenly spaced (every
    ``ceil(N / max_images)``-th, and the last); the frames between two registered keyframes are
    interpolated (slerp), frames outside the registered ones are lost. SIFT starts at the
    original resolution (``first_octave`` 0, at most 1024 features per image)."""

    name = "colmap"
    module = "egovid.voeval.colmap_worker"
    max_images = 30

    def worker_args(self, intr, fps) -> list[str]:
        return [str(v) for v in (intr.fx, intr.fy, intr.cx, intr.cy)]

    def rotation(self, matrix: np.ndarray) -> np.ndarray:
        return matrix.T  # cam_from_world -> camera-to-world

    def frames(self, n: int) -> np.ndarray:
        stride = max(1, -(-n // self.max_images))
        idx = np.arange(0, n, stride)
        return idx if idx[-1] == n - 1 else np.append(idx, n - 1)

    def fill(self, R, valid, given):
        from egovid.voeval.sequences import match_reference

        reg = given[valid[given]]
        if len(reg) < 2:
            return R, valid
        # Registered keyframes with unregistered ones between them leave a gap: not interpolated.
        stride = int(np.median(np.diff(given))) if len(given) > 1 else 1
        frames = np.arange(reg[0], reg[-1] + 1)
        Ri, ok = match_reference(frames.astype(float), reg.astype(float), R[reg], max_gap=stride + 1e-9)
        R, valid = R.copy(), valid.copy()
        R[frames[ok]] = Ri[ok]
        valid[frames[ok]] = True
        return R, valid


class OrbSlam3VO(WorkerVO):
    """ORB-SLAM3 (monocular) through pyorbslam3, with a vocabulary built locally from bundled
    photos (:mod:`egovid.voeval.orbvocab`), on every frame (the worker decodes the video)."""

    name = "orbslam3"
    module = "egovid.voeval.orbslam_worker"
    reads_video = True

    def worker_args(self, intr, fps) -> list[str]:
        from egovid.voeval.orbvocab import build_vocabulary

        vocab = str(build_vocabulary())
        return [vocab, *(str(v) for v in (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height, fps))]


def orbslam3_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("pyorbslam3") is not None


class CommandVO(VisualOdometer):
    """An external odometer run as ``template.format(video=..., out=...)`` writing TUM or KITTI.

    TUM rows are matched to the video's frames by timestamp (seconds from the first frame,
    nearest frame within half a frame interval), so an odometer may skip frames; KITTI rows (no
    times) are frames in order. Frames without a pose are lost.
    """

    def __init__(self, template: str, name: str = "cmd", convention: str = "opencv", timeout: float = 600.0):
        self.template = template
        self.name = name
        self.convention = convention
        self.timeout = timeout

    def run(self, video, intr, workdir) -> VOResult:
        times = np.array([f.time for f in iter_frames(video, gray=True)])
        n = len(times)
        lost = (np.repeat(np.eye(3)[None], n, 0), np.zeros(n, bool))
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
        except subprocess.TimeoutExpired:
            return VOResult(*lost, "timeout")
        if r.returncode != 0 or not out.exists():
            return VOResult(*lost, "failed", message=(r.stderr or r.stdout)[-300:])
        try:
            traj = read_trajectory(out)
        except Exception as exc:  # a broken output file is a failed run, not a crash of the grid
            return VOResult(*lost, "failed", message=str(exc)[:300])
        R = traj.R
        if self.convention == "opengl":
            R = OPENGL_TO_CV @ R @ OPENGL_TO_CV
        if _has_times(out):
            R, valid = _match_rows(traj.times, R, times)
        else:
            valid = np.ones(len(R), bool)
        Rf, v = finalize(R, valid, n)
        return VOResult(Rf, v, _status(v))


def _has_times(path: Path) -> bool:
    """True for TUM files (8 columns: a timestamp first), False for KITTI (12)."""
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        if line.strip() and not line.startswith("#"):
            return len(line.replace(",", " ").split()) == 8
    return False


def _match_rows(row_times: np.ndarray, R: np.ndarray, frame_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Put timed poses on frames: each row goes to the nearest frame within half a frame interval."""
    n = len(frame_times)
    out = np.repeat(np.eye(3)[None], n, 0)
    valid = np.zeros(n, bool)
    if n == 0:
        return out, valid
    half = 0.5 * (float(np.median(np.diff(frame_times))) if n > 1 else 1.0)
    k = np.clip(np.searchsorted(frame_times, row_times), 0, n - 1)
    k_prev = np.clip(k - 1, 0, n - 1)
    nearest = np.where(np.abs(frame_times[k_prev] - row_times) < np.abs(frame_times[k] - row_times), k_prev, k)
    ok = np.abs(frame_times[nearest] - row_times) <= half + 1e-9
    out[nearest[ok]] = R[ok]
    valid[nearest[ok]] = True
    return out, valid


class TruthVO(VisualOdometer):
    """The ground truth itself (tests: zero pose error, capped visual errors)."""

    name = "truth"

    def __init__(self, truth: Callable[[Path], np.ndarray], drift_deg_per_frame: float = 0.0):
        self.truth = truth
        self.drift = drift_deg_per_frame
        if self.drift:
            self.name = "drift"

    def run(self, video, intr, workdir) -> VOResult:
        from egovid.core.rotations import rot_y

        R = self.truth(video)
        if self.drift:
            R = R @ rot_y(self.drift * np.arange(len(R)))
        Rf, v = finalize(R, np.ones(len(R), bool), len(R))
        return VOResult(Rf, v, "ok")


BUILTIN = {"egovid": EgovidVO, "ecc": EccVO, "monovo": MonoVO, "colmap": ColmapVO, "orbslam3": OrbSlam3VO}


def timed_run(vo: VisualOdometer, video: Path, intr: Intrinsics, workdir: Path) -> VOResult:
    """Run a VO, turning any exception into a ``failed`` result."""
    from egovid.core.video import count_frames

    workdir.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    try:
        res = vo.run(video, intr, workdir)
    except Exception as exc:
        n = count_frames(video)
        res = VOResult(
            np.repeat(np.eye(3)[None], n, 0), np.zeros(n, bool), "failed", message=f"{type(exc).__name__}: {exc}"[:300]
        )
    res.seconds = time.perf_counter() - t
    return res


def available_vos() -> list[str]:
    """The built-in odometers that can run here (ORB-SLAM3 only where pyorbslam3 installs)."""
    return [n for n in BUILTIN if n != "orbslam3" or orbslam3_available()]


def split_command(command: str, index: int) -> tuple[str, str]:
    """``"[NAME=]template"`` of ``--vo-cmd`` -> (name, template); unnamed: ``cmd1``, ``cmd2``..."""
    from egovid.core.errors import EgovidError

    head = command.split(" ")[0]
    name, _, tmpl = command.partition("=") if "=" in head else (f"cmd{index + 1}", "", command)
    if "{video}" not in tmpl or "{out}" not in tmpl:
        raise EgovidError(
            f"--vo-cmd {command!r} lacks {{video}} or {{out}}", 'write e.g. --vo-cmd "myvo {video} {out}"'
        )
    if name in BUILTIN:
        raise EgovidError(f"--vo-cmd name {name!r} is a built-in odometer", "give the command another NAME=")
    return name, tmpl


def make_vos(names: list[str], commands: list[str] | None = None) -> list[VisualOdometer]:
    """Odometers by name (``egovid, ecc, monovo, colmap, orbslam3``) plus external commands."""
    from egovid.core.errors import EgovidError

    out: list[VisualOdometer] = []
    for n in names:
        if n not in BUILTIN:
            raise EgovidError(f"unknown visual odometer {n!r}", f"choose from {', '.join(BUILTIN)} or use --vo-cmd")
        if n == "orbslam3" and not orbslam3_available():
            raise EgovidError("ORB-SLAM3 (pyorbslam3) is not installed", "pip install pyorbslam3 (x86-64 Linux)")
        out.append(BUILTIN[n]())
    for i, c in enumerate(commands or []):
        out.append(CommandVO(*reversed(split_command(c, i))))
    names_seen = [v.name for v in out]
    dup = sorted({v for v in names_seen if names_seen.count(v) > 1})
    if dup:
        raise EgovidError(f"odometer name(s) {', '.join(dup)} given twice", "name each --vo-cmd differently (NAME=...)")
    return out


def make_vo(name: str, commands: list[str] | None = None) -> VisualOdometer:
    """One odometer of :func:`make_vos` by name."""
    if name in BUILTIN:
        return make_vos([name])[0]
    return next(v for v in make_vos([], commands) if v.name == name)
