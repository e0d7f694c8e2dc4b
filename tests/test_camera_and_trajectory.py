"""Intrinsics from --focal/--hfov and trajectory files (motion CSV, TUM, KITTI)."""

import math

import numpy as np
import pytest

from egovid.core.camera.intrinsics import Intrinsics, resolve_intrinsics
from egovid.core.errors import EgovidError
from egovid.core.trajectory import (
    Trajectory,
    read_kitti,
    read_motion_csv,
    read_trajectory,
    read_tum,
    write_motion_csv,
    write_tum,
)


def test_default_camera_is_thesis_gopro_scaled_with_width():
    assert Intrinsics.default(1920, 1080).fx == 830.0
    assert Intrinsics.default(1280, 720).fx == pytest.approx(830 * 1280 / 1920)
    assert Intrinsics.default(1920, 1080).hfov_deg == pytest.approx(2 * math.degrees(math.atan(960 / 830)))


def test_hfov_and_focal_agree_and_scaling_keeps_fov():
    a = Intrinsics.from_hfov(1280, 720, 90.0)
    assert a.fx == pytest.approx(640.0)
    assert a.hfov_deg == pytest.approx(90.0)
    b = a.scaled(0.5)
    assert (b.width, b.height) == (640, 360)
    assert b.hfov_deg == pytest.approx(90.0, abs=0.1)


@pytest.mark.parametrize(
    "focal,hfov", [(0.0, None), (-5.0, None), (1e7, None), (None, 179.5), (None, 0.5), (500.0, 60.0)]
)
def test_absurd_intrinsics_are_refused(focal, hfov):
    with pytest.raises(EgovidError):
        resolve_intrinsics(1280, 720, focal, hfov)


def _traj(n=40):
    t = np.arange(n) / 30.0
    e = np.stack([10 * np.sin(t * 3), 2 * np.cos(t * 5), 0.5 * t], axis=1)
    return Trajectory.from_euler(t, e), e


def test_motion_csv_round_trip(tmp_path):
    traj, e = _traj()
    write_motion_csv(tmp_path / "m.csv", traj)
    back = read_motion_csv(tmp_path / "m.csv")
    np.testing.assert_allclose(back.euler(), e, atol=1e-5)
    np.testing.assert_allclose(back.times, traj.times, atol=1e-6)
    assert (tmp_path / "m.csv").read_text().splitlines()[0] == "frame,time,yaw,pitch,roll"


def test_tum_round_trip_and_autodetect(tmp_path):
    traj, e = _traj()
    traj.t[:, 2] = np.linspace(0, 1, len(traj))
    write_tum(tmp_path / "m.tum", traj)
    back = read_tum(tmp_path / "m.tum")
    np.testing.assert_allclose(back.R, traj.R, atol=1e-8)
    np.testing.assert_allclose(back.t, traj.t, atol=1e-8)
    np.testing.assert_allclose(read_trajectory(tmp_path / "m.tum").euler(), e, atol=1e-6)


def test_kitti_reader_reorthonormalises(tmp_path):
    traj, e = _traj(5)
    rows = [np.hstack([R + 1e-4, np.zeros((3, 1))]).ravel() for R in traj.R]
    (tmp_path / "k.txt").write_text("\n".join(" ".join(f"{v:.9f}" for v in r) for r in rows))
    k = read_kitti(tmp_path / "k.txt")
    np.testing.assert_allclose(np.linalg.det(k.R), 1.0, atol=1e-12)
    np.testing.assert_allclose(k.euler(), e, atol=0.02)


def test_bad_motion_files_give_clear_errors(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("frame,time,yaw,pitch\n0,0,1,2\n")
    with pytest.raises(EgovidError, match="lacks column"):
        read_motion_csv(p)
    p.write_text("frame,time,yaw,pitch,roll\n0,0,1,2,3\n1,0.03,nan,2,3\n")
    with pytest.raises(EgovidError, match="NaN"):
        read_motion_csv(p)
    p.write_text("frame,time,yaw,pitch,roll\n")
    with pytest.raises(EgovidError, match="no rows"):
        read_motion_csv(p)
    with pytest.raises(EgovidError, match="not found"):
        read_motion_csv(tmp_path / "missing.csv")
    (tmp_path / "x.txt").write_text("1 2 3\n")
    with pytest.raises(EgovidError, match="neither"):
        read_trajectory(tmp_path / "x.txt")
