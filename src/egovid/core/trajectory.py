"""Rotation trajectories on disk: egovid motion CSV, TUM and KITTI files.

* Motion CSV: header ``frame,time,yaw,pitch,roll``; one row per frame, time in seconds, angles in
  degrees (see :mod:`egovid.core.rotations` for the convention).
* TUM: ``timestamp tx ty tz qx qy qz qw`` per line, camera-to-world (translation 0 when only
  rotation is known). Readable by evo and most SLAM tools.
* KITTI: 12 numbers per line, the row-major 3x4 camera-to-world matrix ``[R | t]``.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_text
from egovid.core.rotations import euler_from_matrix, matrix_from_euler, project_to_so3

MOTION_COLUMNS = ("frame", "time", "yaw", "pitch", "roll")


@dataclass
class Trajectory:
    """Per-frame camera orientations.

    ``times`` (N,) seconds; ``R`` (N, 3, 3) camera-to-world rotations; ``t`` (N, 3) positions
    (zeros when unknown). ``valid`` (N,) marks frames a visual odometer actually tracked.
    """

    times: np.ndarray
    R: np.ndarray
    t: np.ndarray | None = None
    valid: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=float)
        self.R = np.asarray(self.R, dtype=float)
        if self.t is None:
            self.t = np.zeros((len(self.times), 3))
        if self.valid is None:
            self.valid = np.ones(len(self.times), dtype=bool)

    def __len__(self) -> int:
        return len(self.times)

    @classmethod
    def from_euler(cls, times: np.ndarray, angles_deg: np.ndarray) -> Trajectory:
        """From an (N, 3) array of yaw, pitch, roll in degrees."""
        a = np.asarray(angles_deg, dtype=float)
        return cls(times, matrix_from_euler(a[:, 0], a[:, 1], a[:, 2]))

    def euler(self, unwrap: bool = True) -> np.ndarray:
        """(N, 3) yaw, pitch, roll in degrees, unwrapped over time so long pans stay continuous."""
        e = euler_from_matrix(self.R)
        if unwrap and len(e) > 1:
            e = np.rad2deg(np.unwrap(np.deg2rad(e), axis=0))
        return e

    def relative_to_first(self) -> Trajectory:
        """Same motion expressed so that the first orientation is the identity."""
        R0T = self.R[0].T
        return Trajectory(self.times, R0T @ self.R, (self.t - self.t[0]) @ R0T.T, self.valid)


def write_motion_csv(path: str | os.PathLike, traj: Trajectory, confidence: np.ndarray | None = None) -> Path:
    """Write ``frame,time,yaw,pitch,roll`` (degrees) atomically, plus a ``confidence`` column
    (0-1 per frame: 1 measured, 0.5 bridged, 0 interpolated) when given."""
    e = traj.euler()
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow((*MOTION_COLUMNS, "confidence") if confidence is not None else MOTION_COLUMNS)
    for i, (t, (y, p, r)) in enumerate(zip(traj.times, e, strict=True)):
        row = [i, f"{t:.6f}", f"{y:.6f}", f"{p:.6f}", f"{r:.6f}"]
        if confidence is not None:
            row.append(f"{float(confidence[i]):.2f}")
        w.writerow(row)
    return atomic_write_text(path, buf.getvalue())


def read_motion_csv(path: str | os.PathLike) -> Trajectory:
    """Read a motion CSV written by ``egovid fpv motion`` (or any CSV with those columns).

    Column names ``yaw_deg``/``pitch_deg``/``roll_deg`` are accepted too. ``frame`` is optional.
    """
    p = Path(path)
    if not p.exists():
        raise EgovidError(f"motion file not found: {p}", "check the path or run `egovid fpv motion`")
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except UnicodeDecodeError:
        raise EgovidError(f"{p} is not a text CSV file", "give the CSV written by `egovid fpv motion`") from None
    if not rows:
        raise EgovidError(f"motion file {p} is empty", "give the CSV written by `egovid fpv motion`")
    header = [h.strip().lower().removesuffix("_deg") for h in rows[0]]
    missing = [c for c in ("time", "yaw", "pitch", "roll") if c not in header]
    if missing:
        raise EgovidError(
            f"motion file {p} lacks column(s) {', '.join(missing)} (found: {', '.join(header) or 'none'})",
            "the header must be frame,time,yaw,pitch,roll with angles in degrees",
        )
    idx = [header.index(c) for c in ("time", "yaw", "pitch", "roll")]
    data = []
    for n, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        try:
            data.append([float(row[i]) for i in idx])
        except (ValueError, IndexError):
            raise EgovidError(f"{p} line {n} is not numeric: {','.join(row)[:60]}", "fix or remove the line") from None
    if not data:
        raise EgovidError(f"motion file {p} has no rows", "give at least one frame")
    arr = np.array(data)
    bad = ~np.isfinite(arr)
    if bad.any():
        line = int(np.argmax(bad.any(axis=1))) + 2
        raise EgovidError(f"{p} has NaN or infinite values (first at line {line})", "re-estimate the motion")
    return Trajectory.from_euler(arr[:, 0], arr[:, 1:])


def write_tum(path: str | os.PathLike, traj: Trajectory) -> Path:
    """Write a TUM trajectory (camera-to-world, quaternion x y z w) atomically."""
    q = Rotation.from_matrix(traj.R).as_quat()  # x, y, z, w
    lines = [
        f"{t:.6f} {x:.9f} {y:.9f} {z:.9f} {a:.9f} {b:.9f} {c:.9f} {d:.9f}"
        for t, (x, y, z), (a, b, c, d) in zip(traj.times, traj.t, q, strict=True)
    ]
    return atomic_write_text(path, "\n".join(["# timestamp tx ty tz qx qy qz qw", *lines]) + "\n")


def _numeric_rows(p: Path, width: int, kind: str) -> np.ndarray:
    if not p.exists():
        raise EgovidError(f"{kind} file not found: {p}", "check the path")
    rows = []
    for n, line in enumerate(p.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != width:
            raise EgovidError(
                f"{p} line {n} has {len(parts)} numbers, a {kind} file has {width}", f"give a {kind} file"
            )
        try:
            rows.append([float(v) for v in parts])
        except ValueError:
            raise EgovidError(f"{p} line {n} is not numeric", f"give a {kind} file") from None
    if not rows:
        raise EgovidError(f"{kind} file {p} has no poses", f"give a non-empty {kind} file")
    arr = np.array(rows)
    if not np.all(np.isfinite(arr)):
        raise EgovidError(f"{p} contains NaN or infinite values", "the odometer output is broken")
    return arr


def read_tum(path: str | os.PathLike) -> Trajectory:
    """Read a TUM trajectory file; rotations are re-orthonormalised."""
    arr = _numeric_rows(Path(path), 8, "TUM")
    q = arr[:, 4:8]
    norms = np.linalg.norm(q, axis=1)
    if np.any(norms < 1e-9):
        raise EgovidError(f"{path} has zero quaternions", "the odometer output is broken")
    R = Rotation.from_quat(q / norms[:, None]).as_matrix()
    return Trajectory(arr[:, 0], R, arr[:, 1:4])


def read_kitti(path: str | os.PathLike, fps: float = 30.0) -> Trajectory:
    """Read a KITTI pose file (3x4 row-major per line); rotations are re-orthonormalised."""
    arr = _numeric_rows(Path(path), 12, "KITTI")
    M = arr.reshape(-1, 3, 4)
    return Trajectory(np.arange(len(M)) / fps, project_to_so3(M[:, :, :3]), M[:, :, 3])


def read_trajectory(path: str | os.PathLike, fps: float = 30.0) -> Trajectory:
    """Read TUM (8 columns), KITTI (12 columns) or an egovid motion CSV, by content."""
    p = Path(path)
    if not p.exists():
        raise EgovidError(f"trajectory file not found: {p}", "check the path")
    first = ""
    for line in p.read_text(encoding="utf-8", errors="replace").splitlines():
        if line.strip() and not line.startswith("#"):
            first = line
            break
    if first.lower().startswith(("frame", "time")):
        return read_motion_csv(p)
    n = len(first.replace(",", " ").split())
    if n == 8:
        return read_tum(p)
    if n == 12:
        return read_kitti(p, fps)
    raise EgovidError(
        f"{p} is neither a TUM (8 columns), KITTI (12 columns) nor an egovid motion CSV",
        "convert the odometer output to TUM",
    )
