"""Readers for public visual-odometry datasets and plain frame folders (``voeval run --sequence``).

Each reader turns a dataset folder into a :class:`RawSequence`: the image files with their
timestamps, the reference camera orientations with theirs (camera-to-world, OpenCV optical axes:
x right, y down, z forward), and the pinhole camera (plus lens distortion where the dataset has
one). Matching frames to reference poses by timestamp is :func:`egovid.voeval.sequences.match_reference`.

========  ===================================================================================
format    layout read
========  ===================================================================================
tum       TUM RGB-D: ``rgb.txt`` (``time file``), ``groundtruth.txt`` (``time tx ty tz qx qy qz
          qw``, the colour camera's optical centre in the world). Intrinsics and distortion: the
          published calibration of freiburg1/2/3 (from the folder name), else ``camera.txt``.
euroc     EuRoC MAV / ASL: ``mav0/cam0/data.csv`` + ``data/*.png`` (times in ns),
          ``mav0/cam0/sensor.yaml`` (intrinsics, radial-tangential distortion, ``T_BS`` camera to
          body), ``mav0/state_groundtruth_estimate0/data.csv`` (body in world, quaternion w x y z).
kitti     KITTI odometry: ``image_0/*.png``, ``times.txt``, ``calib.txt`` (``P0``), and the
          poses (3x4 per line, camera 0 to world) in ``poses.txt`` in the sequence folder or
          ``../../poses/NN.txt`` (the dataset's own layout).
frames    any folder of images plus a TUM trajectory (``groundtruth.txt``, ``trajectory.tum``
          or the one ``*.tum`` file); times from ``times.txt`` (one per image, or ``time file``)
          or from numeric file names (seconds; nanoseconds when above 1e15); the camera from
          ``camera.txt``.
========  ===================================================================================

``camera.txt`` holds ``fx fy cx cy`` and optionally distortion ``k1 k2 p1 p2 [k3]`` (OpenCV order)
on one line, or the 3x3 camera matrix on three lines.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from egovid.core.errors import EgovidError
from egovid.core.rotations import project_to_so3

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")

#: Published calibrations of the TUM RGB-D colour cameras (fx, fy, cx, cy, k1, k2, p1, p2, k3);
#: freiburg3 images are already undistorted.
TUM_CAMERAS = {
    "freiburg1": (517.306408, 516.469215, 318.643040, 255.313989, 0.262383, -0.953104, -0.005358, 0.002628, 1.163314),
    "freiburg2": (520.908620, 521.007327, 325.141442, 249.701764, 0.231222, -0.784899, -0.003257, -0.000105, 0.917205),
    "freiburg3": (535.4, 539.2, 320.1, 247.6, 0.0, 0.0, 0.0, 0.0, 0.0),
}


@dataclass
class Camera:
    """Pinhole camera of the dataset's images (pixels) and its distortion (OpenCV order, or None)."""

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] | None = None


@dataclass
class RawSequence:
    """A dataset sequence as found on disk.

    ``images`` (N,) image files in time order; ``image_times`` (N,) seconds; ``ref_times`` (M,)
    seconds on the same clock; ``ref_rot`` (M, 3, 3) camera-to-world rotations of the camera that
    took the images (OpenCV optical axes); ``ref_pos`` (M, 3) its optical centre in the world
    (metres), None where the dataset has no positions.
    """

    name: str
    fmt: str
    source: Path
    images: list[Path]
    image_times: np.ndarray
    ref_times: np.ndarray
    ref_rot: np.ndarray
    camera: Camera
    ref_pos: np.ndarray | None = None


def _need(path: Path, what: str, fix: str) -> Path:
    if not path.exists():
        raise EgovidError(f"{what} not found: {path}", fix)
    return path


def _table(path: Path, min_cols: int, kind: str) -> list[list[str]]:
    """Rows of a whitespace- or comma-separated text table, comments (#) skipped."""
    rows = []
    for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith(("#", "%")):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) < min_cols:
            raise EgovidError(
                f"{path} line {n} has {len(parts)} fields, a {kind} has at least {min_cols}", f"give a {kind}"
            )
        rows.append(parts)
    if not rows:
        raise EgovidError(f"{path} is empty", f"give a {kind}")
    return rows


def _floats(path: Path, rows: list[list[str]], cols: slice, kind: str) -> np.ndarray:
    try:
        arr = np.array([[float(v) for v in r[cols]] for r in rows])
    except ValueError:
        raise EgovidError(f"{path} has a non-numeric value", f"give a {kind}") from None
    if not np.all(np.isfinite(arr)):
        raise EgovidError(f"{path} contains NaN or infinite values", f"give a valid {kind}")
    return arr


def _quat_rotations(path: Path, q_xyzw: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(q_xyzw, axis=1)
    if np.any(norms < 1e-9):
        raise EgovidError(f"{path} has zero quaternions", "the reference trajectory is broken")
    return Rotation.from_quat(q_xyzw / norms[:, None]).as_matrix()


def read_tum_trajectory(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times (M,) s, camera-to-world rotations (M, 3, 3), positions (M, 3)) of a TUM
    ``time tx ty tz qx qy qz qw`` file."""
    rows = _table(path, 8, "TUM trajectory (time tx ty tz qx qy qz qw)")
    arr = _floats(path, rows, slice(0, 8), "TUM trajectory")
    return arr[:, 0], _quat_rotations(path, arr[:, 4:8]), arr[:, 1:4]


def read_camera_file(path: Path) -> Camera:
    """``fx fy cx cy [k1 k2 p1 p2 [k3]]`` on one line, or a 3x3 camera matrix on three lines."""
    rows = _table(path, 3, "camera file (fx fy cx cy [k1 k2 p1 p2 k3], or a 3x3 matrix)")
    if len(rows) == 3 and all(len(r) == 3 for r in rows):
        K = _floats(path, rows, slice(0, 3), "camera file")
        cam = Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    else:
        v = list(_floats(path, rows[:1], slice(None), "camera file")[0])
        if len(v) not in (4, 8, 9):
            raise EgovidError(
                f"{path} has {len(v)} numbers on its first line",
                "write fx fy cx cy, optionally followed by k1 k2 p1 p2 [k3]",
            )
        cam = Camera(*v[:4], distortion=tuple(v[4:]) or None)
    if not (cam.fx > 0 and cam.fy > 0):
        raise EgovidError(f"{path} gives a non-positive focal length", "fx and fy are in pixels, > 0")
    return cam


def _image_list(folder: Path) -> list[Path]:
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise EgovidError(f"{folder} has no images", f"give a folder of {'/'.join(IMAGE_SUFFIXES)} frames")
    return files


def _stem_time(p: Path) -> float | None:
    try:
        v = float(p.stem)
    except ValueError:
        return None
    return v * 1e-9 if v > 1e15 else v


def read_tum(folder: Path) -> RawSequence:
    """A TUM RGB-D sequence folder (``rgb.txt``, ``groundtruth.txt``, ``rgb/``)."""
    fix = "give the folder of a TUM RGB-D sequence (rgb.txt, rgb/, groundtruth.txt)"
    rgb = _table(_need(folder / "rgb.txt", "TUM image list rgb.txt", fix), 2, "TUM rgb.txt (time file)")
    times = _floats(folder / "rgb.txt", rgb, slice(0, 1), "TUM rgb.txt")[:, 0]
    images = [folder / r[1] for r in rgb]
    missing = [p for p in images if not p.exists()]
    if missing:
        raise EgovidError(f"{len(missing)} images of {folder / 'rgb.txt'} are missing (first: {missing[0]})", fix)
    ref_t, ref_rot, ref_pos = read_tum_trajectory(
        _need(folder / "groundtruth.txt", "TUM ground truth groundtruth.txt", fix)
    )
    if (folder / "camera.txt").exists():
        cam = read_camera_file(folder / "camera.txt")
    else:
        match = re.search(r"freiburg([123])", folder.resolve().name)
        if not match:
            raise EgovidError(
                f"cannot tell which TUM camera took {folder} (no freiburg1/2/3 in its name)",
                "write its intrinsics to camera.txt in the folder: fx fy cx cy [k1 k2 p1 p2 k3]",
            )
        v = TUM_CAMERAS[f"freiburg{match.group(1)}"]
        cam = Camera(*v[:4], distortion=tuple(v[4:]) if any(v[4:]) else None)
    return RawSequence(folder.resolve().name, "tum", folder, images, times, ref_t, ref_rot, cam, ref_pos)


def _euroc_yaml(path: Path) -> dict:
    text = "\n".join(ln for ln in path.read_text(encoding="utf-8").splitlines() if not ln.startswith("%YAML"))
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise EgovidError(
            f"{path} is not valid YAML ({exc.__class__.__name__})", "give the EuRoC sensor.yaml"
        ) from None
    if not isinstance(data, dict):
        raise EgovidError(f"{path} is not a EuRoC sensor.yaml", "give the EuRoC sensor.yaml")
    return data


def read_euroc(folder: Path) -> RawSequence:
    """A EuRoC MAV sequence (the folder holding ``mav0/``, or ``mav0`` itself)."""
    fix = "give the folder of a EuRoC sequence (mav0/cam0/data.csv, mav0/state_groundtruth_estimate0/data.csv)"
    mav = folder / "mav0" if (folder / "mav0").is_dir() else folder
    cam_dir = mav / "cam0"
    csv = _table(_need(cam_dir / "data.csv", "EuRoC image list cam0/data.csv", fix), 2, "EuRoC cam0/data.csv")
    times = _floats(cam_dir / "data.csv", csv, slice(0, 1), "EuRoC cam0/data.csv")[:, 0] * 1e-9
    images = [cam_dir / "data" / r[1] for r in csv]
    missing = [p for p in images if not p.exists()]
    if missing:
        raise EgovidError(f"{len(missing)} images of {cam_dir / 'data.csv'} are missing (first: {missing[0]})", fix)
    meta = _euroc_yaml(_need(cam_dir / "sensor.yaml", "EuRoC camera calibration cam0/sensor.yaml", fix))
    try:
        fu, fv, cu, cv = (float(x) for x in meta["intrinsics"])
        dist = tuple(float(x) for x in meta.get("distortion_coefficients") or ()) or None
        T_BS = np.array(meta["T_BS"]["data"], dtype=float).reshape(4, 4)
    except (KeyError, TypeError, ValueError):
        raise EgovidError(f"{cam_dir / 'sensor.yaml'} lacks intrinsics or T_BS", "give the EuRoC sensor.yaml") from None
    model = str(meta.get("distortion_model", "radial-tangential"))
    if dist and model != "radial-tangential":
        raise EgovidError(f"EuRoC distortion model {model!r} is not supported", "use radial-tangential calibrations")
    gt_file = mav / "state_groundtruth_estimate0" / "data.csv"
    if not gt_file.exists() and (mav / "vicon0" / "data.csv").exists():  # raw motion capture (same columns)
        gt_file = mav / "vicon0" / "data.csv"
    gt = _table(_need(gt_file, "EuRoC ground truth state_groundtruth_estimate0/data.csv", fix), 8, "EuRoC ground truth")
    arr = _floats(gt_file, gt, slice(0, 8), "EuRoC ground truth")
    R_WB = _quat_rotations(gt_file, arr[:, [5, 6, 7, 4]])  # file order w x y z
    R_BC = project_to_so3(T_BS[:3, :3])  # camera -> body
    p_WC = arr[:, 1:4] + R_WB @ T_BS[:3, 3]  # the camera's centre: body position + its offset on the body
    return RawSequence(
        folder.resolve().name,
        "euroc",
        folder,
        images,
        times,
        arr[:, 0] * 1e-9,
        R_WB @ R_BC,
        Camera(fu, fv, cu, cv, dist),
        p_WC,
    )


def read_kitti(folder: Path) -> RawSequence:
    """A KITTI odometry sequence folder (``image_0/``, ``times.txt``, ``calib.txt``; poses beside
    it as ``poses.txt`` or in the dataset's ``poses/NN.txt``)."""
    fix = "give a KITTI odometry sequence folder (image_0/, times.txt, calib.txt) with its poses"
    img_dir = _need(folder / "image_0", "KITTI image folder image_0", fix)
    images = _image_list(img_dir)
    times = _floats(
        folder / "times.txt",
        _table(_need(folder / "times.txt", "KITTI times.txt", fix), 1, "times.txt"),
        slice(0, 1),
        "KITTI times.txt",
    )[:, 0]
    if len(times) != len(images):
        raise EgovidError(f"{folder} has {len(images)} images but {len(times)} times", "give the complete sequence")
    calib = {}
    for row in _table(_need(folder / "calib.txt", "KITTI calib.txt", fix), 2, "KITTI calib.txt"):
        calib[row[0].rstrip(":")] = row[1:]
    if "P0" not in calib or len(calib["P0"]) != 12:
        raise EgovidError(f"{folder / 'calib.txt'} has no P0 line with 12 numbers", "give the KITTI calib.txt")
    P0 = np.array([float(v) for v in calib["P0"]]).reshape(3, 4)
    candidates = [folder / "poses.txt", folder.resolve().parent.parent / "poses" / f"{folder.resolve().name}.txt"]
    pose_file = next((p for p in candidates if p.exists()), None)
    if pose_file is None:
        raise EgovidError(
            f"no poses for KITTI sequence {folder} (looked for {', '.join(map(str, candidates))})",
            "KITTI publishes poses for sequences 00-10 only; put them in poses.txt in the sequence folder",
        )
    M = _floats(pose_file, _table(pose_file, 12, "KITTI pose file"), slice(0, 12), "KITTI pose file").reshape(-1, 3, 4)
    if len(M) != len(times):
        raise EgovidError(f"{pose_file} has {len(M)} poses for {len(times)} images", "give the sequence's own poses")
    name = folder.resolve().name
    cam = Camera(P0[0, 0], P0[1, 1], P0[0, 2], P0[1, 2])
    return RawSequence(name, "kitti", folder, images, times, times.copy(), project_to_so3(M[:, :, :3]), cam, M[:, :, 3])


def read_frames(folder: Path) -> RawSequence:
    """A folder of frames with a TUM trajectory, ``camera.txt`` and times (see the module doc)."""
    fix = "give a folder of images with camera.txt and a TUM trajectory (groundtruth.txt or *.tum)"
    img_dir = folder / "images" if (folder / "images").is_dir() else folder
    images = _image_list(img_dir)
    traj = next((folder / n for n in ("groundtruth.txt", "trajectory.tum") if (folder / n).exists()), None)
    if traj is None:
        tums = sorted(folder.glob("*.tum"))
        if len(tums) != 1:
            raise EgovidError(f"{folder} has {len(tums)} *.tum trajectories and no groundtruth.txt", fix)
        traj = tums[0]
    if (folder / "times.txt").exists():
        rows = _table(folder / "times.txt", 1, "times.txt (one time per image, or time file)")
        if len(rows[0]) >= 2:
            times = _floats(folder / "times.txt", rows, slice(0, 1), "times.txt")[:, 0]
            images = [img_dir / r[1] for r in rows]
            missing = [p for p in images if not p.exists()]
            if missing:
                raise EgovidError(f"{len(missing)} images of times.txt are missing (first: {missing[0]})", fix)
        else:
            times = _floats(folder / "times.txt", rows, slice(0, 1), "times.txt")[:, 0]
            if len(times) != len(images):
                raise EgovidError(f"{folder} has {len(images)} images but {len(times)} times", "one time per image")
    else:
        stamps = [_stem_time(p) for p in images]
        if any(s is None for s in stamps):
            raise EgovidError(
                f"cannot tell when the frames of {folder} were taken (file names are not times, no times.txt)",
                "add times.txt with one time in seconds per image (sorted by file name)",
            )
        times = np.array(stamps, dtype=float)
    ref_t, ref_rot, ref_pos = read_tum_trajectory(traj)
    cam = read_camera_file(_need(folder / "camera.txt", "camera file camera.txt", fix))
    return RawSequence(folder.resolve().name, "frames", folder, images, times, ref_t, ref_rot, cam, ref_pos)


READERS = {"tum": read_tum, "euroc": read_euroc, "kitti": read_kitti, "frames": read_frames}


def check_times(seq: RawSequence) -> None:
    """Image and reference times must increase; raise naming the first offending entry otherwise."""
    for what, t in (("image", seq.image_times), ("reference", seq.ref_times)):
        d = np.diff(t)
        if np.any(d <= 0):
            k = int(np.argmax(d <= 0))
            raise EgovidError(
                f"{seq.source}: {what} times do not increase (entry {k + 2}: {t[k + 1]:.6f} after {t[k]:.6f})",
                "sort the list by time and remove duplicates",
            )
    if len(seq.images) < 2 or len(seq.ref_times) < 2:
        raise EgovidError(f"{seq.source} has fewer than two frames or reference poses", "give a longer sequence")
