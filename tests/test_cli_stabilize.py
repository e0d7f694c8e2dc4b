"""`egovid fpv stabilize` as a user runs it: outputs, report, bad input, interruption."""

import json
import os
import signal
import subprocess
import sys
import time

import av
import numpy as np

from egovid.io.video import VideoWriter, count_frames, iter_frames

from conftest import assert_one_error, run_cli


def test_stabilize_with_report_json_and_audio(tmp_path, shaky_clip):
    # Give the clip an audio track: the output must carry it through.
    src = tmp_path / "with_audio.mp4"
    _add_audio(shaky_clip, src)
    out = tmp_path / "out.mp4"
    r = run_cli("fpv", "stabilize", src, "-o", out, "--report", tmp_path / "r.html", "--json", tmp_path / "r.json")
    assert r.returncode == 0, r.stderr
    assert count_frames(out) == count_frames(src)
    with av.open(str(out)) as c:
        assert len(c.streams.audio) == 1
    s = json.loads((tmp_path / "r.json").read_text())
    mb, ma = s["measured"]["before"], s["measured"]["after"]
    assert ma["ve"] > mb["ve"] and ma["itf_db"] > mb["itf_db"] and ma["ve2d"] > mb["ve2d"]
    assert s["planned"]["after"]["ve"] > s["planned"]["before"]["ve"]
    assert 1.0 <= s["zoom"]["mean"] <= s["zoom"]["max"] <= 1.10 + 1e-9
    html = (tmp_path / "r.html").read_text()
    assert "data:image/png;base64," in html and "ITF" in html and "input | output" in html
    # Same input, same options: the same JSON (plan, path and encoding are deterministic; timings
    # are not in it). Given the motion and without re-measuring, so that the motion estimator's
    # own determinism is not what is tested here.
    assert run_cli("fpv", "motion", src, "-o", tmp_path / "m.csv").returncode == 0
    runs = []
    for k in range(2):
        args = ("-o", tmp_path / f"d{k}.mp4", "--motion", tmp_path / "m.csv", "--json", tmp_path / f"d{k}.json")
        r = run_cli("fpv", "stabilize", src, *args, "--no-measure")
        assert r.returncode == 0, r.stderr
        runs.append(json.loads((tmp_path / f"d{k}.json").read_text()))
    assert {**runs[0], "output": None} == {**runs[1], "output": None}

def _add_audio(video, dst):
    frames = list(iter_frames(video))
    with VideoWriter(dst, frames[0].image.shape[1], frames[0].image.shape[0], 30) as w:
        for f in frames:
            w.write(f.image, f.time)
    tmp = dst.with_name("a.mp4")
    c = av.open(str(tmp), "w")
    a = c.add_stream("aac", rate=48000)
    a.layout = "mono"
    samples = (0.1 * np.sin(np.arange(48000 * 3) / 48000 * 2 * np.pi * 300)).astype(np.float32)
    for k in range(0, len(samples), 1024):
        af = av.AudioFrame.from_ndarray(samples[None, k : k + 1024], format="flt", layout="mono")
        af.sample_rate, af.pts = 48000, k
        for p in a.encode(af):
            c.mux(p)
    for p in a.encode():
        c.mux(p)
    c.close()
    # Mux video and audio with PyAV stream copy.
    out = dst.with_name("m.mp4")
    with av.open(str(dst)) as v, av.open(str(tmp)) as au, av.open(str(out), "w") as o:
        vs = o.add_stream_from_template(v.streams.video[0])
        as_ = o.add_stream_from_template(au.streams.audio[0])
        for p in v.demux(v.streams.video[0]):
            if p.dts is not None:
                p.stream = vs
                o.mux(p)
        for p in au.demux(au.streams.audio[0]):
            if p.dts is not None:
                p.stream = as_
                o.mux(p)
    os.replace(out, dst)


def test_stabilize_bad_input(tmp_path, still_clip):
    out = tmp_path / "o.mp4"
    assert_one_error(run_cli("fpv", "stabilize", tmp_path / "none.mp4", "-o", out), "not found")
    assert_one_error(run_cli("fpv", "stabilize", still_clip, "-o", out, "--strength", "3"), "strength")
    assert_one_error(run_cli("fpv", "stabilize", still_clip, "-o", out, "--borders", "pink"), "border mode")
    assert_one_error(run_cli("fpv", "stabilize", still_clip, "-o", still_clip), "overwrite the input")
    m = tmp_path / "m.csv"
    m.write_text("frame,time,yaw,pitch,roll\n0,0,0,0,0\n1,0.03,0,0,0\n")
    assert_one_error(run_cli("fpv", "stabilize", still_clip, "-o", out, "--motion", m), "has 2 frames")
    short = tmp_path / "short.mp4"
    assert run_cli("synth", "fpv", short, "--frames", "6", "--size", "160x120").returncode == 0
    assert_one_error(run_cli("fpv", "stabilize", short, "-o", out), "fewer than one scoring window")
    assert not out.exists()


def _wait_for_partial(folder, proc, timeout=120.0):
    """Wait until the writer's temporary file exists, i.e. rendering is under way."""
    t0 = time.time()
    while time.time() - t0 < timeout and proc.poll() is None:
        if list(folder.glob(".o.part-*")):
            return True
        time.sleep(0.02)
    return False


def test_interrupted_stabilisation_leaves_no_output(tmp_path, shaky_clip):
    out = tmp_path / "o.mp4"
    cmd = [sys.executable, "-m", "egovid", "fpv", "stabilize", str(shaky_clip), "-o", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert _wait_for_partial(tmp_path, proc), "rendering never started"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode != 0
    assert "Traceback" not in err
    assert not out.exists()
    assert not list(tmp_path.glob(".o.part-*")), "temporary file left behind after Ctrl-C"
    # kill -9 cannot clean up, but the target path still never holds a partial video.
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    assert _wait_for_partial(tmp_path, proc)
    proc.kill()
    proc.wait()
    assert not out.exists()
