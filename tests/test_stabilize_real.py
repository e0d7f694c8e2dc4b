"""`egovid fpv stabilize` on the real clips of ../shared/data/real (SOURCES.md): it runs, keeps
what the camera wrote, stays under the zoom cap, and its measured (decoded) output shakes less
than its input; `fpv score` reads the result."""

import json

import av

from egovid.core.video import count_frames, probe

from conftest import run_cli


def _data_packets(path, handler: str) -> list[bytes]:
    with av.open(str(path)) as c:
        (s,) = [s for s in c.streams.data if s.metadata.get("handler_name", "").strip() == handler]
        return [bytes(p) for p in c.demux(s) if p.size]


def test_gopro_clip_stabilised_measured_and_kept(karma_clip, tmp_path):
    out = tmp_path / "karma.mp4"
    r = run_cli(
        "fpv", "stabilize", karma_clip, "-o", out, "--json", tmp_path / "k.json", "--report", tmp_path / "k.html"
    )
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "k.json").read_text())
    # What the camera wrote: full-range BT.709, timecode, creation time, audio, GPMF telemetry.
    src, got = probe(karma_clip), probe(out)
    assert got.colour == src.colour and got.colour.range == "pc"
    assert (got.timecode, got.creation_time, got.audio_streams) == (src.timecode, src.creation_time, 1)
    assert _data_packets(out, "GoPro MET") == _data_packets(karma_clip, "GoPro MET")
    assert count_frames(out) == count_frames(karma_clip)
    # Under the default zoom cap, and measured on the decoded output: less high-frequency jitter.
    assert s["zoom"]["max"] <= 1.10 + 1e-9
    mb, ma = s["measured"]["before"], s["measured"]["after"]
    assert ma["jitter_px"] < mb["jitter_px"], (mb, ma)
    assert ma["itf_db"] > mb["itf_db"]
    assert "input | output" in (tmp_path / "k.html").read_text()


def test_handheld_clip_stabilised_and_scored(handheld_clip, tmp_path):
    out = tmp_path / "hand.mp4"
    r = run_cli("fpv", "stabilize", handheld_clip, "-o", out, "--json", tmp_path / "h.json", "--no-measure")
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "h.json").read_text())
    assert "measured" not in s and s["zoom"]["max"] <= 1.10 + 1e-9
    assert s["planned"]["after"]["ve"] >= s["planned"]["before"]["ve"]
    assert probe(out).audio_streams == 1 and count_frames(out) == count_frames(handheld_clip)
    r = run_cli("fpv", "score", out, "--method", "ve2d", "--json", tmp_path / "score.json")
    assert r.returncode == 0, r.stderr
    assert 0.0 < json.loads((tmp_path / "score.json").read_text())["results"]["ve2d"]["score"] <= 1.0
