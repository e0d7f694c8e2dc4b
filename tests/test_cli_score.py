"""`egovid fpv score` as a user runs it."""

import json

import numpy as np

from egovid.core.trajectory import Trajectory, write_motion_csv
from egovid.synth import motions

from conftest import assert_one_error, invoke_cli, run_cli


def test_score_video_all_methods_json_and_plot(shaky_clip, tmp_path):
    r = run_cli("fpv", "score", shaky_clip, "--json", tmp_path / "s.json", "--plot", tmp_path / "s.png")
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "s.json").read_text())
    assert set(doc["results"]) == {"ve", "sve", "ve2d"}
    ve = doc["results"]["ve"]
    assert 0 <= ve["score"] <= 1 and set(ve["axis_scores"]) == {"yaw", "pitch", "roll"}
    assert len(ve["combined"]) == 90 - 9 - 2  # K - N - 2 windows (eq. 8.13), N + 1 = 10
    assert (tmp_path / "s.png").read_bytes()[:4] == b"\x89PNG"


def test_score_motion_csv(tmp_path):
    a = motions.running(120, 1.0, 0.3, 24)
    write_motion_csv(tmp_path / "m.csv", Trajectory.from_euler(np.arange(120) / 30.0, a))
    r = run_cli("fpv", "score", "--motion", tmp_path / "m.csv", "--method", "ve", "--json", tmp_path / "o.json")
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "o.json").read_text())["results"]["ve"]["score"] > 0.5


def test_score_bad_motion_files(tmp_path, capsys):
    # Each fails in validation, so in this process (test_fuzz_cli.py runs a sample as real processes).
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    p = tmp_path / "m.csv"
    p.write_text("frame,time,yaw,pitch\n0,0,0,0\n")
    assert_one_error(cli("fpv", "score", "--motion", p), "lacks column")
    p.write_text("frame,time,yaw,pitch,roll\n" + "".join(f"{i},{i / 30},0,nan,0\n" for i in range(40)))
    assert_one_error(cli("fpv", "score", "--motion", p), "NaN")
    p.write_text("frame,time,yaw,pitch,roll\n" + "".join(f"{i},{i / 30},0,0,0\n" for i in range(6)))
    assert_one_error(cli("fpv", "score", "--motion", p), "fewer than one scoring window")
    assert_one_error(cli("fpv", "score", "--motion", p, "--method", "ve2d"), "needs the video")
    assert_one_error(cli("fpv", "score"), "either a VIDEO or --motion")
    assert_one_error(cli("fpv", "score", "--motion", p, "--bias", "0.5"), "bias")
