"""The VO evaluation method (thesis Part IV): metrics on hand-made rotations and against evo,
scene geometry, factor matrices on hand-made results, and a small grid run end to end."""

import json
import math
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.metrics.pose_error import pair_errors, pose_error
from egovid.core.metrics.visual_error import visual_errors
from egovid.core.rotations import angle_deg, matrix_from_euler, rot_y
from egovid.synth import motions
from egovid.synth.photos import photo
from egovid.voeval.matrices import factor_matrices
from egovid.voeval.scenes import orbit_pose

from conftest import assert_one_error, run_cli


def _motion(n=40):
    a = motions.running(n, 6, 1.5, 20, 0.5)
    return matrix_from_euler(a[:, 0], a[:, 1], a[:, 2])


def test_pose_error_by_hand():
    R = _motion()
    assert pose_error(R, R) == pytest.approx(0.0, abs=1e-12)
    # Only the last frame wrong by theta about y: every pair (t, K) has error Ry(theta);
    # x and z axes move by the chord 2 sin(theta/2), y does not: 4 sin(theta/2) per pair.
    theta = 3.0
    est = R.copy()
    est[-1] = est[-1] @ rot_y(theta)
    expected = (len(R) - 1) * 4 * math.sin(math.radians(theta) / 2)
    assert pose_error(R, est) == pytest.approx(expected, rel=1e-9)
    assert pose_error(R, est, step=3) == pytest.approx(
        len(range(0, len(R) - 1, 3)) * 4 * math.sin(math.radians(theta) / 2)
    )
    assert pose_error(R, est, aggregate="mean") == pytest.approx(4 * math.sin(math.radians(theta) / 2))


def test_pose_error_matches_evo_rpe_where_definitions_coincide():
    from evo.core import metrics
    from evo.core.trajectory import PoseTrajectory3D
    from scipy.spatial.transform import Rotation

    R = _motion()
    rng = np.random.default_rng(0)
    est = R @ np.stack([matrix_from_euler(*rng.normal(0, 0.3, 3)) for _ in range(len(R))])

    def traj(Rs):
        q = Rotation.from_matrix(Rs).as_quat()[:, [3, 0, 1, 2]]  # evo: w x y z
        return PoseTrajectory3D(np.zeros((len(Rs), 3)), q, np.arange(len(Rs), dtype=float))

    rpe = metrics.RPE(metrics.PoseRelation.rotation_angle_deg, delta=1, delta_unit=metrics.Unit.frames)
    rpe.process_data((traj(R), traj(est)))
    E, _ = pair_errors(R, est, pairs="consecutive", delta=1)
    np.testing.assert_allclose(angle_deg(E), rpe.error, atol=1e-6)


def test_visual_errors_distinguish_drift_from_jitter():
    intr = Intrinsics.from_hfov(240, 180, 60)
    imgs = [photo("astronaut"), photo("coffee")]
    R = _motion(36)
    o, r = visual_errors(imgs, R, R, intr)
    assert o == pytest.approx(60.0) and r == pytest.approx(60.0)  # the cap
    drift = R @ rot_y(0.25 * np.arange(len(R)))
    od, rd = visual_errors(imgs, R, drift, intr)
    assert od > rd + 5.0  # case (1): good for stabilisation, not for AR
    rng = np.random.default_rng(1)
    jitter = R @ np.stack([matrix_from_euler(*rng.normal(0, 0.4, 3)) for _ in range(len(R))])
    oj, rj = visual_errors(imgs, R, jitter, intr)
    assert abs(oj - rj) < 2.0  # case (2): no accumulated error, OITF ~ RITF
    assert rj > rd


def test_visual_errors_equal_the_itf_of_each_picture_warped_alone():
    # Independent path: each picture warped by itself (stabilised_frames) and its ITF taken frame
    # by frame (metrics.itf), against the grid's batched warps of up to four pictures at once.
    from egovid.core.metrics.itf import itf
    from egovid.core.metrics.visual_error import stabilised_frames

    intr = Intrinsics.from_hfov(160, 120, 60)
    names = ("astronaut", "coffee", "rocket", "chelsea", "cat")  # two warp batches (4 + 1)
    R = _motion(24)
    rng = np.random.default_rng(2)
    est = R @ np.stack([matrix_from_euler(*rng.normal(0, 0.5, 3)) for _ in range(len(R))]) @ rot_y(0.1)
    R, est = R[0].T @ R, est[0].T @ est  # visual_errors takes rotations relative to the first frame
    order = np.random.default_rng(0).permutation(len(R))
    o_ref, r_ref = [], []
    for name in names:
        frames, masks = stabilised_frames(photo(name), R, est, intr)
        o_ref.append(itf(frames, masks, cap_db=60.0))
        r_ref.append(itf(frames, masks, order=order, cap_db=60.0))
    o, r = visual_errors([photo(n) for n in names], R, est, intr, cap_db=60.0)
    assert (o, r) == (float(np.mean(o_ref)), float(np.mean(r_ref)))  # bit for bit


def test_orbslam_worker_grey_is_what_png_frames_gave():
    # ORB-SLAM3 used to read each frame from a PNG file as grey; its worker now converts the
    # decoded frame itself and must give the same pixels.
    import cv2

    from egovid.voeval.orbslam_worker import grey

    img = np.random.default_rng(3).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    ok, png = cv2.imencode(".png", img)
    assert ok
    np.testing.assert_array_equal(grey(img), cv2.imdecode(png, cv2.IMREAD_GRAYSCALE))


def test_orbit_pose_is_eq_21_3():
    r, d, w = 0.25, 1.0, 2 * math.pi / 48
    for t in (0.0, 7.0, 19.0):
        c, R = orbit_pose(t, r, d, w)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        # Optical axis through the picture's centre.
        ray = R @ np.array([0, 0, 1.0])
        np.testing.assert_allclose(np.cross(ray, -c / np.linalg.norm(c)), 0, atol=1e-12)
        # Camera x axis = eq. 21.3's R_x (our picture lies below the camera, so Z is flipped).
        s_, c_ = math.sin(w * t), math.cos(w * t)
        rx = np.array([d * d + r * r * s_ * s_, r * r * c_ * s_, -d * r * c_])
        np.testing.assert_allclose(R[:, 0], rx / np.linalg.norm(rx), atol=1e-12)


def _hand_results():
    res = {}
    for vo, bad in (("a", 2.0), ("b", 1.0)):
        for c, extra in (("lossless", 0.0), ("crf30", 1.0)):
            for s in ("orbit-ideal", "pano-ideal"):
                res[(vo, s, c)] = {"pose_error": 1.0 + extra, "oitf": 30.0, "ritf": 20.0}
            for s in ("orbit-fog", "orbit-unseen", "orbit-sensor", "pano-motion"):
                res[(vo, s, c)] = {"pose_error": 1.0 + extra + bad, "oitf": 30.0 - bad, "ritf": 20.0 - bad}
    return res


def test_factor_matrices_by_hand():
    from egovid.voeval.layout import Factor
    from egovid.voeval.scenes import FACTORS

    factors = [Factor("synthetic", f, a, b) for f, (a, b) in FACTORS.items()]
    vos, crfs = ["a", "b"], ["lossless", "crf30"]
    res = _hand_results()
    res[("a", "pano-motion", "lossless")] = {"pose_error": 11.0, "oitf": 25.0, "ritf": 25.0}  # OITF = RITF
    m = factor_matrices(res, vos, crfs, factors)
    pe = m["pose_error"]
    assert pe["difference"][0, 0, 0] == pytest.approx(2.0) and pe["difference"][1, 0, 0] == pytest.approx(1.0)
    # Relative (eq. 22.2): divided by ΔITF = OITF - RITF of the ideal scene (10 dB).
    assert pe["relative"][0, 0, 0] == pytest.approx(0.2 / 1.0)  # normalised by the largest factor (motion)
    # Absolute (eq. 22.6): normalised over VOs per factor.
    assert pe["absolute"][0, 0, 0] == pytest.approx(1.0) and pe["absolute"][1, 0, 0] == pytest.approx(0.5)
    oitf = m["oitf"]
    # OITF: m = ideal; ΔITF of the challenging scene; pano-motion has OITF = RITF: floored, finite.
    assert oitf["difference"][0, 3, 0] == pytest.approx(5.0)
    assert oitf["relative"][0, 3, 0] == pytest.approx(1.0) and np.isfinite(oitf["relative"]).all()
    assert m["pose_error"]["compression"].shape == (2, 4)


def test_normalisation_follows_eq_22_2_to_22_4_and_the_old_choice_differs():
    """|max E| (eq. 22.4) against max|E|, and ΔITF = OITF - RITF (eq. 22.3) against |OITF - RITF|,
    on a case where no factor hurts (all differences negative) and ΔITF is negative."""
    from egovid.voeval.layout import Factor

    factors = [Factor("synthetic", "feature", "i", "f"), Factor("synthetic", "sensor", "i", "s")]
    res = {
        ("a", "i", "lossless"): {"pose_error": 5.0, "oitf": 30.0, "ritf": 20.0},
        ("a", "f", "lossless"): {"pose_error": 4.0, "oitf": 31.0, "ritf": 33.0},  # better, ΔITF = -2
        ("a", "s", "lossless"): {"pose_error": 3.0, "oitf": 32.0, "ritf": 21.0},  # better still
    }
    th = factor_matrices(res, ["a"], ["lossless"], factors, norm="thesis")["pose_error"]
    old = factor_matrices(res, ["a"], ["lossless"], factors, norm="max_abs")["pose_error"]
    # Pose error: n = the ideal scene (ΔITF 10 dB): E = (-1/10, -2/10); |max E| = 0.1 -> (-1, -2).
    np.testing.assert_allclose(th["relative"][0, :, 0], [-1.0, -2.0])
    np.testing.assert_allclose(old["relative"][0, :, 0], [-0.5, -1.0])  # max|E| = 0.2
    oit = factor_matrices(res, ["a"], ["lossless"], factors, norm="thesis")["oitf"]
    oit_old = factor_matrices(res, ["a"], ["lossless"], factors, norm="max_abs")["oitf"]
    # OITF: n = the challenging scene; feature's ΔITF = -2 dB: floored at 0.5 (thesis) or |−2| = 2 (old).
    assert oit["difference"][0, 0, 0] == pytest.approx(-1.0)
    assert oit["relative"][0, 0, 0] / oit["relative"][0, 1, 0] == pytest.approx((-1.0 / 0.5) / (-2.0 / 11.0))
    assert oit_old["relative"][0, 0, 0] / oit_old["relative"][0, 1, 0] == pytest.approx((-1.0 / 2.0) / (-2.0 / 11.0))


def test_recommendation_ranks_in_domain_vos_and_calls_ties():
    from egovid.voeval.recommend import answer, in_domain

    assert not in_domain("egovid", "translating") and in_domain("egovid", "rotating")
    assert in_domain("colmap", "translating") and in_domain("mycmd", "translating")
    cells = {}
    for seed, noise in ((0, 0.0), (1, 0.4)):
        for vo, pe in (("egovid", 0.1), ("colmap", 1.0), ("monovo", 1.3 + noise), ("orbslam3", 5.0)):
            cells[(vo, "hard", "lossless", seed)] = {"pose_error": pe, "status": "ok", "tracked": 10, "frames": 10}
    vos = ["egovid", "colmap", "monovo", "orbslam3"]
    a = answer(cells, vos, [0, 1], "synthetic", "feature", "hard", "lossless", "translating", "pose_error")
    assert a.out_of_domain == ["egovid"]  # best score, but it cannot work there by design
    assert a.best == "colmap" and a.margin == pytest.approx(0.5) and a.spread == pytest.approx(0.2)
    assert not a.tie
    b = answer(cells, vos, [0, 1], "synthetic", "motion", "hard", "lossless", "rotating", "pose_error")
    assert b.best == "egovid" and not b.out_of_domain
    cells[("monovo", "hard", "lossless", 1)]["pose_error"] = 0.2  # monovo: 1.3 then 0.2, colmap 1.0 twice
    c = answer(cells, vos, [0, 1], "s", "f", "hard", "lossless", "translating", "pose_error")
    assert c.best == "monovo" and c.tie  # mean 0.75 vs 1.0, but the paired difference swings by ±0.55


def test_a_failed_or_partial_odometer_is_never_ranked_and_floors_are_given():
    from egovid.voeval.recommend import answer

    def cell(pe, tracked=10, status="ok"):
        return {"pose_error": pe, "status": status, "tracked": tracked, "frames": 10}

    cells = {
        ("good", "s", "lossless", 0): cell(2.0),
        ("worse", "s", "lossless", 0): cell(3.0),
        ("nothing", "s", "lossless", 0): cell(0.5, 0, "failed"),  # identity: scores like "no motion"
        ("late", "s", "lossless", 0): cell(0.7, 4, "lost-tracking"),  # 40 % tracked
        ("floor-stationary", "s", "lossless", 0): cell(0.5),
        ("floor-constant-velocity", "s", "lossless", 0): cell(0.6),
    }
    floors = ("floor-stationary", "floor-constant-velocity")
    a = answer(cells, ["good", "worse", "nothing", "late"], [0], "x", "f", "s", "lossless", "rotating", "pose_error",
               floors=floors)  # fmt: skip
    assert [v for v, _ in a.ranking] == ["good", "worse"]
    assert a.not_run == [("nothing", "failed", 0.0), ("late", "partial", 0.4)]
    assert a.floors == {"floor-stationary": 0.5, "floor-constant-velocity": 0.6}
    assert a.no_better_than == "floor-stationary"  # the winner (2.0) does not beat doing nothing (0.5)
    cells[("good", "s", "lossless", 0)]["pose_error"] = 0.4
    assert (
        answer(cells, ["good"], [0], "x", "f", "s", "lossless", "rotating", "pose_error", floors).no_better_than is None
    )


def test_factor_matrices_leave_out_pairs_that_did_not_run():
    from egovid.voeval.layout import Factor
    from egovid.voeval.matrices import factor_matrices, mean_over_seeds

    def cell(pe, tracked=10):
        return {"pose_error": pe, "oitf": 30.0, "ritf": 20.0, "status": "ok", "tracked": tracked, "frames": 10}

    cells = {("a", "i", "lossless", 0): cell(1.0), ("a", "h", "lossless", 0): cell(2.0)}
    cells |= {("b", "i", "lossless", 0): cell(1.0), ("b", "h", "lossless", 0): cell(0.1, tracked=2)}
    m = factor_matrices(mean_over_seeds(cells), ["a", "b"], ["lossless"], [Factor("synthetic", "feature", "i", "h")])
    assert m["pose_error"]["difference"][0, 0, 0] == pytest.approx(1.0)
    assert np.isnan(m["pose_error"]["difference"][1, 0, 0])  # b tracked 20 % of "h": no value, not "better"
    assert m["left_out"] == [
        {"vo": "b", "factor": "feature", "level": "lossless", "scene": "h", "outcome": "partial", "tracked_share": 0.2}
    ]


def test_compression_limits_by_hand():
    from egovid.voeval.limits import compression_limits

    def r(pe, ate, how="ran"):
        return {"pose_error": pe, "ate_rot_deg": ate, "outcome": how}

    levels = ["lossless", "crf18", "crf30", "crf48"]
    means = {
        ("a", "s", lv): r(*v) for lv, v in zip(levels, [(1.0, 2.0), (1.05, 2.3), (1.2, 2.1), (9.0, 9.0)], strict=True)
    }
    means |= {
        ("b", "s", "lossless"): r(1.0, 1.0),
        ("b", "s", "crf18"): r(1.0, 1.0),
        ("b", "s", "crf30"): r(0, 0, "failed"),
    }
    means[("c", "s", "lossless")] = r(0.0, 0.0, "partial")
    [a, b, c] = compression_limits(means, ["a", "b", "c"], ["s"], levels)
    assert a.grows == {"pose_error": "crf30", "ate_rot_deg": "crf18"} and a.fails is None
    assert b.grows == {"pose_error": None, "ate_rot_deg": None} and b.fails == "crf30"
    assert c.fails == "lossless" and c.grows == {"pose_error": None, "ate_rot_deg": None}


def test_ate_rpe_by_hand_and_the_floors():
    from egovid.voeval.evo_errors import ate_rpe
    from egovid.voeval.floors import CONSTANT_VELOCITY, STATIONARY, floor_trajectory
    from egovid.voeval.scenes import SceneTruth

    n, theta = 30, 2.0
    R = _motion(n)
    R = R[0].T @ R
    times = np.arange(n) / 30.0
    est = R.copy()
    est[10:] = rot_y(theta) @ R[10:]  # a jump of theta at frame 10, right after it the motion is exact again
    e = ate_rpe(times, R, est)
    assert e["ate_rot_deg"] == pytest.approx(theta * math.sqrt((n - 10) / n), abs=1e-9)
    assert e["rpe_rot_deg"] == pytest.approx(theta / math.sqrt(n - 1), abs=1e-9)  # one pair in n - 1
    assert e["ate_trans"] is None and e["translation_note"] == "the reference has no positions"
    t = np.stack([np.cos(times), np.sin(times), 0.3 * times], axis=1)  # a helix
    t -= t[0]
    A = matrix_from_euler(20.0, -10.0, 5.0)  # the same poses in another world frame, at another scale
    e = ate_rpe(times, R, A @ R, t, 2.5 * t @ A.T + [1.0, 2.0, 3.0])
    assert e["ate_trans"] < 1e-9 and e["rpe_trans"] < 1e-9
    assert "line" in ate_rpe(times, R, R, t, np.outer(times, [1.0, 0, 0]))["translation_note"]
    # Floors: stationary is the identity; constant velocity is exact on a constant-rate motion.
    truth = SceneTruth("s", rot_y(1.5 * np.arange(n)), Intrinsics.from_hfov(64, 48, 60), 30.0, t=None)
    Rs, ts = floor_trajectory(STATIONARY, truth)
    assert np.allclose(Rs, np.eye(3)) and ts is None
    v = np.array([0.1, 0.0, 0.05])  # the same step in the camera's own axes every frame: a helix
    truth.t = np.concatenate([np.zeros((1, 3)), np.cumsum(truth.R[:-1] @ v, axis=0)])
    Rc, tc = floor_trajectory(CONSTANT_VELOCITY, truth)
    assert np.max(angle_deg(np.swapaxes(Rc, 1, 2) @ truth.R)) < 1e-5  # arccos near 1: 1e-6° resolution
    np.testing.assert_allclose(tc, truth.t, atol=1e-9)


# Odometers that read the scene's truth (numpy only: they start fast): the truth itself, the truth
# with a steady drift of 0.3° per frame about y, and the truth from frame 5 on (a late starter).
FAKE_VO = """
import pathlib, sys
import numpy as np

mode, video, out = sys.argv[1], pathlib.Path(sys.argv[2]), sys.argv[3]
scene = video.name.split("__")[0].removesuffix(".mkv")
rows = np.loadtxt(video.parents[2] / "scenes" / "s0" / (scene + ".gt.tum"), ndmin=2)
if mode == "drift":  # q * (rotation of 0.3 k degrees about y), quaternions x y z w
    h = np.radians(0.3 * np.arange(len(rows))) / 2
    x, y, z, w = rows[:, 4:8].T
    c, s = np.cos(h), np.sin(h)
    rows[:, 4:8] = np.stack([x * c - z * s, y * c + w * s, z * c + x * s, w * c - y * s], axis=1)
if mode == "late":  # frames 5.. relative to frame 5: q5^-1 * q
    rows = rows[5:].copy()
    x0, y0, z0, w0 = -rows[0, 4], -rows[0, 5], -rows[0, 6], rows[0, 7]
    x, y, z, w = rows[:, 4:8].T
    rows[:, 4:8] = np.stack([w0 * x + x0 * w + y0 * z - z0 * y, w0 * y - x0 * z + y0 * w + z0 * x,
                             w0 * z + x0 * y - y0 * x + z0 * w, w0 * w - x0 * x - y0 * y - z0 * z], axis=1)
np.savetxt(out, rows, fmt="%.9f")
"""


def _evo_cli(tool: str, ref: Path, est: Path, *args: str) -> float:
    """The RMSE that evo's own command (``evo_ape`` / ``evo_rpe``) reports for two TUM files."""
    res = ref.parent / "evo-result.zip"
    res.unlink(missing_ok=True)  # evo asks before it overwrites
    exe = Path(sys.executable).parent / tool
    subprocess.run(
        [str(exe), "tum", str(ref), str(est), *args, "--save_results", str(res)], check=True, capture_output=True
    )
    return json.loads(zipfile.ZipFile(res).read("stats.json"))["rmse"]


def test_grid_run_with_truth_drift_failure_and_resume(tmp_path):
    fake = tmp_path / "fake_vo.py"
    fake.write_text(FAKE_VO)
    vo = f"{sys.executable} {fake}"
    out = tmp_path / "run"
    args = [
        "voeval",
        "run",
        "--out",
        out,
        "--vo",
        "ecc,monovo",
        "--frames",
        "16",
        "--size",
        "160x120",
        "--levels",
        "lossless,crf30",
        "--scenes",
        "orbit-ideal,orbit-fog,pano-ideal,pano-motion",
        "--workers",
        "2",
        "--vo-cmd",
        f"truth={vo} truth {{video}} {{out}}",
        "--vo-cmd",
        f"drift={vo} drift {{video}} {{out}}",
        "--vo-cmd",
        "broken=sh -c 'echo starting; echo tracker lost: no features >&2; exit 3' {video} {out}",
        "--vo-cmd",
        f"late={vo} late {{video}} {{out}}",
    ]
    r = run_cli(*args)
    assert r.returncode == 0, r.stderr
    from egovid.voeval.results import load_results

    run = load_results(out)
    res = run.cells
    assert set(run.vos) == {"ecc", "monovo", "truth", "drift", "broken", "late"}
    assert run.floors == ["floor-stationary", "floor-constant-velocity"]
    assert len(run.scenes) == 4 and run.levels == ["lossless", "crf30"]
    assert [f.name for f in run.factors] == ["feature", "motion"]
    assert len(list((out / "results").glob("*/s0/*.json"))) == 6 * 4 * 2 + 2 * 4  # floors: once per scene
    hand_ate = 0.3 * math.sqrt(np.mean(np.arange(16) ** 2))  # drift: 0.3 k degrees at frame k
    for (vo, scene, _l, _seed), c in res.items():
        if vo == "truth":
            assert c["status"] == "ok" and c["outcome"] == "ran" and c["pose_error"] < 1e-6
            assert c["oitf"] == pytest.approx(60.0) and c["ritf"] == pytest.approx(60.0)
            assert c["ate_rot_deg"] < 1e-4 and c["rpe_rot_deg"] < 1e-4
            if scene.startswith("orbit"):  # positions on a circle: Sim(3) aligned exactly
                assert c["ate_trans"] < 1e-6 and c["rpe_trans"] < 1e-6
            else:  # the pano camera dollies on a straight line: no unique Sim(3) alignment
                assert c["ate_trans"] is None and "line" in c["translation_note"]
        if vo == "drift":
            assert c["oitf"] > c["ritf"] + 3.0
            assert c["ate_rot_deg"] == pytest.approx(hand_ate, abs=1e-4)
        if vo == "broken":  # recorded, not dropped, with why
            assert c["status"] == "failed" and c["outcome"] == "failed" and c["first_pose_frame"] == 16
            d = c["diagnosis"]
            assert d["exit_status"] == 3 and d["log_tail"] == ["tracker lost: no features", "starting"]
            assert "status 3" in d["reason"] and not d["timed_out"]
            # It scored what it gave, "no motion": exactly the stationary floor.
            assert c["pose_error"] == pytest.approx(res[("floor-stationary", scene, _l, 0)]["pose_error"])
        if vo == "late":  # the truth from frame 5 on, relative to frame 5: an odometer that starts late
            assert c["status"] == "lost-tracking" and c["first_pose_frame"] == 5 and c["tracked"] == 11
            assert c["outcome"] == "partial" and c["tracked_share"] == pytest.approx(11 / 16)
            if scene.startswith("orbit"):  # a steady turn: anchoring to the truth hides most of the late start
                assert 0 < c["pose_error_other_anchor"] < 0.8 * c["pose_error"]
    # ATE / RPE are evo's, on the very files of the cell: evo's own commands agree to 1e-6.
    for vo, scene in (("monovo", "orbit-ideal"), ("drift", "pano-motion")):
        c = res[(vo, scene, "lossless", 0)]
        ref, est = out / "scenes" / "s0" / f"{scene}.gt.tum", out / "results" / vo / "s0" / f"{scene}__lossless.tum"
        rot, pairs = ("--pose_relation", "angle_deg"), ("--delta", "1", "--delta_unit", "f")
        assert _evo_cli("evo_ape", ref, est, *rot, "--align_origin") == pytest.approx(c["ate_rot_deg"], abs=1e-6)
        assert _evo_cli("evo_rpe", ref, est, *rot, *pairs) == pytest.approx(c["rpe_rot_deg"], abs=1e-6)
        if c["ate_trans"] is not None:
            assert _evo_cli("evo_ape", ref, est, "-as") == pytest.approx(c["ate_trans"], abs=1e-6)
            assert _evo_cli("evo_rpe", ref, est, "-as", *pairs) == pytest.approx(c["rpe_trans"], abs=1e-6)
    assert res[("monovo", "orbit-ideal", "lossless", 0)]["ate_trans"] is not None  # the translation case ran
    # No cell that did not run is ranked, though "broken" (no motion) out-scores working ones on the pano.
    m = json.loads((out / "matrices.json").read_text())
    for a in m["answers"]:
        ranked = [v for v, _ in a["ranking"]]
        assert "broken" not in ranked and "late" not in ranked, a
        assert {v for v, *_ in a["not_run"]} >= {"broken", "late"} and set(a["floors"]) == set(run.floors)
    motion = next(a for a in m["answers"] if a["factor"] == "motion" and a["metric"] == "pose_error")
    assert motion["ranking"][0][0] == "truth" and "monovo" in [v for v, _ in motion["ranking"]]
    pe = {v: res[(v, "pano-motion", "lossless", 0)]["pose_error"] for v in ("broken", "monovo")}
    assert pe["broken"] < pe["monovo"]  # what made failed odometers rank first before
    assert {d["vo"] for d in m["left_out"]} == {"broken", "late"}  # the factor matrices say what they dropped
    assert len(m["failures"]) == 16 and all(f["reason"] for f in m["failures"])  # every one says why
    report = (out / "report.md").read_text()
    assert "| broken | pano-ideal | lossless | 0 | failed (0 %) | the command exited with status 3" in report
    assert "| floor: stationary |" in report and "tracker lost: no features" in report
    assert "| pano-ideal | ecc |" in report  # the compression table
    assert (out / "report.html").exists()
    r = run_cli(*args, "--no-report")  # resume: nothing left to compute
    assert r.returncode == 0 and "(0 computed now)" in r.stdout


def test_odometer_timeout_is_recorded(tmp_path):
    from egovid.voeval.adapters import CommandVO
    from egovid.voeval.scenes import render_scene

    truth = render_scene("pano-ideal", tmp_path / "p.mkv", frames=10, width=96, height=72)
    vo = CommandVO("sh -c 'echo waiting >&2; sleep 20' {video} {out}", "slow", timeout=1.0)
    res = vo.run(tmp_path / "p.mkv", truth.intrinsics, tmp_path)
    assert res.status == "timeout" and not res.valid.any()
    assert res.diagnosis.timed_out and res.diagnosis.exit_status is None
    assert "timed out after 1 s" in res.diagnosis.reason and res.diagnosis.log_tail == ["waiting"]


def test_bad_vo_arguments(tmp_path):
    r = run_cli("voeval", "run", "--out", tmp_path / "x", "--vo", "nonsense")
    assert r.returncode == 2 and "unknown visual odometer" in r.stderr
    r = run_cli("voeval", "run", "--out", tmp_path / "x", "--vo", "egovid", "--vo-cmd", "tool")
    assert r.returncode == 2 and "{video}" in r.stderr
    assert not (tmp_path / "x").exists()  # refused before the run folder is made
    r = run_cli("voeval", "report", tmp_path / "nothing")
    assert r.returncode == 2 and "no results" in r.stderr
    # Without --vo every available odometer is asked for (it crashed before): here the run stops at
    # the bad sequence, after the odometer list was built.
    r = run_cli("voeval", "run", "--out", tmp_path / "y", "--sequence", "kitti:/nowhere")
    assert_one_error(r, "does not exist")
    assert not (tmp_path / "y").exists()


def test_default_odometers_are_every_available_one():
    from egovid.voeval.adapters import ODOMETERS
    from egovid.voeval.runner import GridConfig

    expected = [n for n, cls in ODOMETERS.items() if cls.missing() is None]
    assert GridConfig().vos == expected and len(expected) >= 4
    assert list(ODOMETERS)[:3] == ["egovid", "ecc", "monovo"]  # the default order
    cfg = GridConfig()
    assert (cfg.frames, cfg.width, cfg.height) == (300, 640, 480) and len(cfg.levels) == 7


@pytest.mark.parametrize("name", ["colmap", "orbslam3"])
def test_sfm_and_slam_adapters_recover_the_orbit(tmp_path, name):
    from egovid.voeval.adapters import ODOMETERS, anchor_to_truth, make_vos, timed_run
    from egovid.voeval.evo_errors import ate_rpe
    from egovid.voeval.scenes import render_scene

    if ODOMETERS[name].missing():
        pytest.skip(f"{name} is not installed here ({ODOMETERS[name].missing()})")
    truth = render_scene("orbit-ideal", tmp_path / "orbit.mkv", frames=48)
    res = timed_run(make_vos([name])[0], tmp_path / "orbit.mkv", truth.intrinsics, tmp_path / "work")
    assert res.status in ("ok", "lost-tracking"), res.diagnosis
    assert res.valid.sum() >= 36
    # Where tracked, the rotations agree with the ground truth (one camera convention; a wrong
    # convention is off by tens of degrees). ORB-SLAM3 is multi-threaded and not deterministic:
    # its error on this planar scene varies between runs around a degree.
    R = anchor_to_truth(res.R, res.valid, truth.R)
    err = angle_deg(np.swapaxes(R, 1, 2) @ truth.R)
    assert np.median(err[res.valid]) < (1.0 if name == "colmap" else 3.0)
    # Positions too: after a Sim(3) alignment (monocular: no scale) the orbit's circle comes back to
    # within a few percent of its radius (0.25) where tracked.
    k = res.valid
    t = ate_rpe(truth.times[k], truth.R[k], res.R[k], truth.t[k], res.t[k])
    assert t["ate_trans"] < 0.03, t


DIE_ONCE = """
import os, pathlib, shutil, signal, sys

video, out, mark = pathlib.Path(sys.argv[1]), sys.argv[2], pathlib.Path(sys.argv[3])
pid = os.getppid()  # the shell of subprocess.run(shell=True); above it, the Dask worker process
while not pathlib.Path(f"/proc/{pid}/comm").read_text().startswith("python"):
    pid = int(pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
if not mark.exists():
    mark.write_text(str(pid))
    os.kill(pid, signal.SIGKILL)
scene = video.name.split("__")[0].removesuffix(".mkv")
shutil.copy(video.parents[2] / "scenes" / "s0" / (scene + ".gt.tum"), out)
"""


def test_grid_on_a_dask_cluster_retries_the_cell_of_a_killed_worker(dask_scheduler, tmp_path):
    """The grid on a real scheduler + 2 workers: the odometer kills the worker running its cell
    the first time; Dask runs the cell again on a live worker and the grid completes."""
    from egovid.core.engine import EngineConfig
    from egovid.voeval.results import load_results
    from egovid.voeval.runner import GridConfig, run_grid

    mark, script = tmp_path / "killed", tmp_path / "die_once.py"
    script.write_text(DIE_ONCE)
    cmd = f"dies={sys.executable} {script} {{video}} {{out}} {mark}"
    cfg = GridConfig(vos=[], commands=[cmd], scenes=["pano-ideal"], frames=12, width=96, height=72, levels=["lossless"])
    r = run_grid(tmp_path / "run", cfg, EngineConfig(scheduler=dask_scheduler))
    assert r["computed"] == 1 + 2 and mark.exists()  # the cell and the two floors; it did kill its worker
    cell = load_results(tmp_path / "run").cells[("dies", "pano-ideal", "lossless", 0)]
    assert cell["status"] == "ok" and cell["pose_error"] < 1e-6
    assert int(mark.read_text()) != os.getpid()  # it was a worker, not this test process
