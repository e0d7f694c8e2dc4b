"""Real sequences in voeval: tiny TUM RGB-D, EuRoC and KITTI sequences (and a plain frame folder)
written from a synthetic render in each dataset's own layout and conventions (world frames,
camera-to-body transform, reference rates and clocks), read back, and evaluated with a VO that
outputs the *render's* rotations: the imported reference must equal the render's truth, so the
truth VO scores zero pose error on every sequence, factor and compression level."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from egovid.core.errors import EgovidError
from egovid.core.rotations import angle_deg, matrix_from_euler, so3_exp, so3_log
from egovid.core.trajectory import Trajectory, read_tum, write_tum
from egovid.core.video import iter_frames
from egovid.voeval.sequences import longest_run, match_reference, parse_specs

from conftest import assert_one_error, invoke_cli, real_clip, run_cli

N, W, H, FPS = 14, 160, 120, 20.0
T0 = 1305031102.175  # a TUM-like epoch: times are absolute seconds in the datasets
WORLD = matrix_from_euler(30.0, -20.0, 75.0)  # the dataset's world frame is not the first camera
R_BC = matrix_from_euler(90.0, 0.0, -90.0)  # EuRoC-like camera-to-body rotation (T_BS)


@pytest.fixture(scope="module")
def render(tmp_path_factory):
    """A short render with exact rotations: (BGR frames, camera-to-world R relative to frame 0, intrinsics)."""
    from egovid.voeval.scenes import render_scene

    d = tmp_path_factory.mktemp("render")
    truth = render_scene("pano-ideal", d / "r.mkv", frames=N, width=W, height=H, seed=1)
    frames = [f.image for f in iter_frames(d / "r.mkv")]
    write_tum(d / "truth.tum", Trajectory(np.arange(N) / FPS, truth.R))
    return frames, truth.R, truth.intrinsics, d / "truth.tum"


def _fine_reference(R: np.ndarray, times: np.ndarray, per_frame: int = 3, lead: int = 4):
    """Reference samples at ``per_frame`` x the frame rate, starting ``lead`` samples before the
    first frame and ending after the last, exact at frame times, slerped in between."""
    dt = (times[1] - times[0]) / per_frame
    t = times[0] + dt * np.arange(-lead, per_frame * (len(times) - 1) + lead + 1)
    k = np.clip((t - times[0]) / (times[1] - times[0]), 0, len(times) - 1 - 1e-12)
    i = np.floor(k).astype(int)
    a = k - i
    Rs = R[i] @ so3_exp(so3_log(np.swapaxes(R[i], 1, 2) @ R[np.minimum(i + 1, len(R) - 1)]) * a[:, None])
    return t, Rs


def _q_xyzw(R):
    return Rotation.from_matrix(R).as_quat()


def write_tum_dataset(root: Path, frames, R, intr) -> Path:
    seq = root / "rgbd_dataset_freiburg3_synthetic"
    (seq / "rgb").mkdir(parents=True)
    times = T0 + np.arange(N) / FPS
    lines = []
    for t, img in zip(times, frames, strict=True):
        cv2.imwrite(str(seq / "rgb" / f"{t:.6f}.png"), img)
        lines.append(f"{t:.6f} rgb/{t:.6f}.png")
    (seq / "rgb.txt").write_text("# color images\n# timestamp filename\n" + "\n".join(lines) + "\n")
    t_ref, R_ref = _fine_reference(WORLD @ R, times)
    q = _q_xyzw(R_ref)
    rows = [f"{t:.6f} 0.1 0.2 0.3 {x:.9f} {y:.9f} {z:.9f} {w:.9f}" for t, (x, y, z, w) in zip(t_ref, q, strict=True)]
    (seq / "groundtruth.txt").write_text(
        "# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n" + "\n".join(rows) + "\n"
    )
    (seq / "camera.txt").write_text(f"{intr.fx} {intr.fy} {intr.cx} {intr.cy}\n")
    return seq


T_BS = np.eye(4)
T_BS[:3, :3] = R_BC
T_BS[:3, 3] = (-0.02, 0.07, 0.0)  # the camera sits off the body's centre


def write_euroc_dataset(
    root: Path, frames, R, intr, *, name: str = "MH_99_synthetic", fps: float = FPS, centres=None
) -> Path:
    """A EuRoC MAV sequence of ``frames`` (BGR, written grey) with camera-to-world rotations ``R``
    (relative to frame 0) and camera centres ``centres`` (None: the body stays at one point)."""
    seq = root / name
    cam = seq / "mav0" / "cam0"
    (cam / "data").mkdir(parents=True)
    n = len(frames)
    times_ns = (1403636579763555584 + np.arange(n) * int(1e9 / fps)).astype(np.int64)
    rows = []
    for t, img in zip(times_ns, frames, strict=True):
        cv2.imwrite(str(cam / "data" / f"{t}.png"), cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
        rows.append(f"{t},{t}.png")
    (cam / "data.csv").write_text("#timestamp [ns],filename\n" + "\n".join(rows) + "\n")
    (cam / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: camera\ncomment: synthetic\nT_BS:\n  cols: 4\n  rows: 4\n  data: ["
        + ", ".join(f"{v:.12f}" for v in T_BS.ravel())
        + f"]\nrate_hz: {fps}\nresolution: [{frames[0].shape[1]}, {frames[0].shape[0]}]\ncamera_model: pinhole\n"
        f"intrinsics: [{intr.fx}, {intr.fy}, {intr.cx}, {intr.cy}]\ndistortion_model: radial-tangential\n"
        "distortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
    )
    t_cam = times_ns * 1e-9
    t_ref, R_WC = _fine_reference(WORLD @ R, t_cam, per_frame=5)
    R_WB = R_WC @ R_BC.T  # body orientation: the reference is of the body (IMU), not the camera
    if centres is None:
        p_WB = np.tile([1.0, 2.0, 0.5], (len(t_ref), 1))
    else:  # the body's centre: the camera's, less its offset on the body
        c = np.stack([np.interp(t_ref, t_cam, (centres @ WORLD.T)[:, k]) for k in range(3)], axis=1)
        p_WB = c - R_WB @ T_BS[:3, 3]
    q = _q_xyzw(R_WB)
    gt = seq / "mav0" / "state_groundtruth_estimate0"
    gt.mkdir(parents=True)
    lines = [
        f"{round(t * 1e9)},{p[0]:.12f},{p[1]:.12f},{p[2]:.12f},{w:.12f},{x:.12f},{y:.12f},{z:.12f}" + ",0.0" * 9
        for t, p, (x, y, z, w) in zip(t_ref, p_WB, q, strict=True)
    ]
    (gt / "data.csv").write_text(
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], ...\n"
        + "\n".join(lines)
        + "\n"
    )
    return seq


def write_kitti_dataset(root: Path, frames, R, intr) -> Path:
    seq = root / "dataset" / "sequences" / "07"
    (seq / "image_0").mkdir(parents=True)
    for k, img in enumerate(frames):
        cv2.imwrite(str(seq / "image_0" / f"{k:06d}.png"), cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    (seq / "times.txt").write_text("".join(f"{k / FPS:.6e}\n" for k in range(N)))
    P = f"{intr.fx:.12e} 0.0 {intr.cx:.12e} 0.0 0.0 {intr.fy:.12e} {intr.cy:.12e} 0.0 0.0 0.0 1.0 0.0"
    (seq / "calib.txt").write_text("".join(f"P{i}: {P}\n" for i in range(4)) + "Tr: " + " ".join(["0.0"] * 12) + "\n")
    poses = root / "dataset" / "poses"
    poses.mkdir(parents=True)
    lines = []
    for k, Rk in enumerate(R):  # KITTI poses: camera 0 to the first camera's frame, with translation
        M = np.hstack([Rk, [[0.0], [0.0], [0.8 * k]]])
        lines.append(" ".join(f"{v:.12e}" for v in M.ravel()))
    (poses / "07.txt").write_text("\n".join(lines) + "\n")
    return seq


def write_frames_dataset(root: Path, frames, R, intr) -> Path:
    seq = root / "my-frames"
    (seq / "images").mkdir(parents=True)
    for k, img in enumerate(frames):
        cv2.imwrite(str(seq / "images" / f"frame{k:04d}.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    times = 100.0 + np.arange(N) / FPS
    (seq / "times.txt").write_text("".join(f"{t:.6f}\n" for t in times))
    t_ref, R_ref = _fine_reference(WORLD @ R, times, per_frame=2)
    write_tum(seq / "trajectory.tum", Trajectory(t_ref, R_ref))
    (seq / "camera.txt").write_text(f"{intr.fx} 0 {intr.cx}\n0 {intr.fy} {intr.cy}\n0 0 1\n")
    return seq


WRITERS = {
    "tum": write_tum_dataset,
    "euroc": write_euroc_dataset,
    "kitti": write_kitti_dataset,
    "frames": write_frames_dataset,
}

# A VO that outputs the render's own rotations (timed, so matched to frames by timestamp).
TRUTH_CMD = 'truth={py} -c "import shutil, sys; shutil.copy(sys.argv[1], sys.argv[2])" {truth} {{out}} {{video}}'


def test_tum_euroc_kitti_and_frames_read_back_exactly_and_truth_scores_zero(tmp_path, render):
    frames, R, intr, truth_tum = render
    specs = [f"{fmt}:{w(tmp_path / fmt, frames, R, intr)}" for fmt, w in WRITERS.items()]
    out = tmp_path / "run"
    args = [
        "voeval",
        "run",
        "--out",
        out,
        "--no-synthetic",
        "--vo",
        "",
        "--levels",
        "lossless,crf36",
        "--real-factors",
        "blur,illumination",
        "--workers",
        "1",
        "--vo-cmd",
        TRUTH_CMD.format(py=sys.executable, truth=truth_tum),
    ]
    for s in specs:
        args += ["--sequence", s]
    r = run_cli(*args)
    assert r.returncode == 0, r.stderr
    names = {
        "tum": "rgbd_dataset_freiburg3_synthetic",
        "euroc": "MH_99_synthetic",
        "kitti": "07",
        "frames": "my-frames",
    }
    for fmt, name in names.items():
        meta = json.loads((out / "scenes" / "real" / f"{name}.json").read_text())
        assert meta["format"] == fmt and meta["frames"] == N, meta
        ref = read_tum(out / "scenes" / "real" / f"{name}.gt.tum")
        # The imported reference is the render's truth: world frame, camera-to-body transform and
        # timestamps undone (independent truth: the rotations the frames were rendered with).
        assert np.max(angle_deg(np.swapaxes(ref.R, 1, 2) @ R)) < 1e-4, fmt
        np.testing.assert_allclose(ref.times, np.arange(N) / FPS, atol=1e-6)
        # Positions, in the first camera's axes: KITTI's 0.8 m per frame along z; EuRoC's body stays
        # put, so its camera moves only by turning around the body (T_BS undone); TUM's and the
        # frame folder's reference never move (no positions).
        expected = {"kitti": np.outer(np.arange(N), [0, 0, 0.8])}
        p = WORLD @ R @ R_BC.T @ T_BS[:3, 3]  # camera centre = body centre + R_WB t_BS
        expected["euroc"] = (p - p[0]) @ (WORLD @ R[0])
        assert meta["has_translation"] == (fmt in expected), fmt
        if fmt in expected:
            np.testing.assert_allclose(ref.t, expected[fmt], atol=1e-6)
        for scene in (name, f"{name}+blur", f"{name}+illumination"):
            for level in ("lossless", "crf36"):
                c = json.loads((out / "results" / "truth" / "s0" / f"{scene}__{level}.json").read_text())
                assert c["status"] == "ok" and c["first_pose_frame"] == 0
                assert c["pose_error"] < 1e-4, (scene, level, c["pose_error"])
                assert c["oitf"] == pytest.approx(60.0) and c["ritf"] == pytest.approx(60.0)
    # Degraded copies differ from the original as intended.
    orig = next(iter_frames(out / "scenes" / "real" / "07.mkv")).image.astype(float)
    dark = next(iter_frames(out / "scenes" / "s0" / "07+illumination.mkv")).image.astype(float)
    assert 0.2 < dark.mean() / orig.mean() < 0.5
    report = (out / "report.md").read_text()
    assert "| 07 | blur |" in report and "rotation_07.png" in report
    assert "| 07 | as recorded | **truth**" in report and "| 07 | compression (crf36) | **truth**" in report


def test_match_reference_interpolates_and_refuses_gaps():
    t_ref = np.array([0.0, 0.1, 0.2, 0.3, 1.3, 1.4])
    R_ref = matrix_from_euler(10.0 * t_ref * 10, 0 * t_ref, 0 * t_ref)  # 10° per reference step in yaw
    R, ok = match_reference(np.array([-0.05, 0.05, 0.3, 0.8, 1.35, 1.5]), t_ref, R_ref, max_gap=0.15)
    assert ok.tolist() == [False, True, True, False, True, False]
    # Halfway between 0° and 10° of yaw is 5° (slerp), independent of how it was computed here.
    np.testing.assert_allclose(angle_deg(matrix_from_euler(5.0, 0, 0).T @ R[1]), 0, atol=1e-9)
    assert longest_run(ok) == (1, 3) and longest_run(np.zeros(3, bool)) == (0, 0)


def test_bad_sequences_are_one_clear_error(tmp_path, capsys):
    # Each fails in validation, so in this process (see invoke_cli).
    (tmp_path / "empty").mkdir()
    base = ["voeval", "run", "--out", tmp_path / "r", "--no-synthetic", "--vo", "ecc"]
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    assert_one_error(cli(*base, "--sequence", "tumx:/nowhere"), "known format")
    assert_one_error(cli(*base, "--sequence", f"tum:{tmp_path / 'missing'}"), "does not exist")
    assert_one_error(cli(*base, "--sequence", f"euroc:{tmp_path / 'empty'}"), "cam0/data.csv")
    assert_one_error(cli(*base, "--sequence", f"gyro:{tmp_path / 'empty'}"), "not a video file")
    no_gyro = real_clip("handheld-1080p-pan.mp4")  # a real phone clip without telemetry
    assert_one_error(cli(*base, "--sequence", f"gyro:{no_gyro}"), "no embedded gyro")
    assert not (tmp_path / "r").exists()  # every --sequence is checked before the run folder is made
    with pytest.raises(EgovidError, match="freiburg"):
        from egovid.voeval.datasets import read_tum

        d = tmp_path / "seq"
        d.mkdir()
        (d / "rgb.txt").write_text("1.0 a.png\n")
        (d / "a.png").write_bytes(b"")
        (d / "groundtruth.txt").write_text("1.0 0 0 0 0 0 0 1\n")
        read_tum(d)


def test_sequence_names_follow_folders_and_stay_unique(tmp_path):
    for n in ("a/seq", "b/seq"):
        (tmp_path / n).mkdir(parents=True)
    specs = parse_specs([f"tum:{tmp_path / 'a/seq'}", f"kitti:{tmp_path / 'b/seq'}"])
    assert [s.name for s in specs] == ["seq", "seq-2"]


def test_orbslam3_on_short_slow_euroc_sequences_initialises_or_says_why(tmp_path):
    """Two 40-frame EuRoC sequences (ORB-SLAM3 gets its EuRoC settings): a slow orbit it initialises
    on, and one that barely moves (parallax below a degree), where the cell fails and says why."""
    from egovid.core.camera.intrinsics import Intrinsics
    from egovid.voeval.adapters import ODOMETERS
    from egovid.voeval.scenes import LEARNED, mosaic, orbit_pose, relative_to_first, render_orbit

    if ODOMETERS["orbslam3"].missing():
        pytest.skip("pyorbslam3 installs only on x86-64 Linux")
    intr, picture, n = Intrinsics.from_hfov(376, 240, 70.0), mosaic(LEARNED), 40
    args = ["voeval", "run", "--out", tmp_path / "run", "--no-synthetic", "--vo", "orbslam3", "--levels", "lossless"]
    args += ["--real-factors", "", "--workers", "2"]
    for name, turn in (("V9_01_slow", 0.08), ("V9_02_still", 0.004)):  # share of a full orbit over the clip
        poses = [orbit_pose(k, 0.25, 1.0, 2 * np.pi * turn / n) for k in range(n)]
        frames = [render_orbit(picture, intr, c, Rk) for c, Rk in poses]
        R, t = relative_to_first(np.stack([p[1] for p in poses]), np.stack([p[0] for p in poses]))
        seq = write_euroc_dataset(tmp_path, frames, R, intr, name=name, fps=20.0, centres=t)
        args += ["--sequence", f"euroc:{seq}"]
    r = run_cli(*args)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "run" / "results" / "orbslam3" / "s0"
    slow, still = (json.loads((out / f"{s}__lossless.json").read_text()) for s in ("V9_01_slow", "V9_02_still"))
    assert slow["orb"]["from"] == "ORB-SLAM3 EuRoC.yaml"
    assert slow["tracked"] >= 20 and "initialised at frame" in slow["reason"], slow["reason"]
    assert still["outcome"] == "failed" and "never initialised" in still["reason"]
    assert "moves" in still["diagnosis"]["reference_motion"] and "parallax" in still["diagnosis"]["reference_motion"]
    report = (tmp_path / "run" / "report.md").read_text()
    assert "| V9_02_still | as recorded | none ran | none ran | none ran | orbslam3 (failed, 0 % tracked) |" in report
    assert "ORB-SLAM3 never initialised" in report and "parallax" in report
