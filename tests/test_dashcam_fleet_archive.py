"""The fleet archive end to end, as a user runs it: a drive cut into three loop-recording files
joined into one trip, find, incident clips, lock / forget (a root drive with dependents, and a
kill -9 mid-forget), the HTML map in Chromium."""

from __future__ import annotations

import datetime as dt
import hashlib
import itertools
import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import threading
from pathlib import Path

import av
import numpy as np
import pytest

from egovid.core.errors import EgovidError
from egovid.core.video import iter_frames
from egovid.dashcam.route.tracks import read_track
from egovid.synth.drive import DriveSpec, Light, render_drive
from test_dashcam_fleet_map import browse

from conftest import _wait_for, assert_one_error, invoke_cli, run_cli

W, H, FPS = 320, 180, 10.0
DAY = dt.datetime(2026, 5, 4, 8, 0, 0, tzinfo=dt.UTC)


def _utc(d: dt.datetime) -> float:
    return d.timestamp()


def _frames_hash(path: Path) -> list[str]:
    return [hashlib.sha256(f.image.tobytes()).hexdigest() for f in iter_frames(path, i420=True)]


def _split_lossless(video: Path, out_dir: Path, cuts: list[int], start: dt.datetime) -> list[Path]:
    """Cut a video into files at frame indices ``cuts`` (lossless H.264, so the pixels stay), each
    with the creation_time of its first frame, named like a Viofo's loop files."""
    frames = [f.image for f in iter_frames(video, i420=True)]
    edges = [0, *cuts, len(frames)]
    out = []
    for k, (a, b) in enumerate(itertools.pairwise(edges)):
        t = start + dt.timedelta(seconds=a / FPS)
        path = out_dir / f"{t:%Y_%m%d_%H%M%S}_{k + 1:04d}F.MP4"
        with av.open(str(path), "w") as c:
            c.metadata["creation_time"] = t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
            s = c.add_stream("libx264", rate=int(FPS))
            s.width, s.height, s.pix_fmt = W, H, "yuv420p"
            s.options = {"qp": "0", "preset": "ultrafast"}
            for i, img in enumerate(frames[a:b]):
                vf = av.VideoFrame.from_ndarray(img, format="yuv420p")
                vf.pts = i
                for p in s.encode(vf):
                    c.mux(p)
            for p in s.encode():
                c.mux(p)
        out.append(path)
    return out


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """An archive of three drives of one street on three days: a (the root, twice as long), b
    (coded against a) and c, recorded as three loop files sharing one GPS log, joined into one
    trip."""
    d = tmp_path_factory.mktemp("fleet")
    noon = Light.preset("noon")
    specs = {
        "a": DriveSpec(legs=[("main", 380.0, 560.0)], cruise=11.0, seed=1, light=noon, start_time=DAY),
        "b": DriveSpec(legs=[("main", 380.0, 470.0)], cruise=9.0, seed=2, light=noon,
                       start_time=DAY + dt.timedelta(days=1)),
        "c": DriveSpec(legs=[("main", 380.0, 470.0)], cruise=10.0, seed=3, light=noon,
                       start_time=DAY + dt.timedelta(days=2)),
    }  # fmt: skip
    drives = {}
    for name, spec in specs.items():
        drives[name] = render_drive(spec, d / f"{name}.mp4", width=W, height=H, fps=FPS, gps_format="gpx")
    loops = d / "loops"
    loops.mkdir()
    c_video, c_gps, c_truth = drives["c"]
    n_c = len(c_truth.times)
    files = _split_lossless(c_video, loops, [n_c // 3, 2 * n_c // 3], specs["c"].start_time)
    shutil.copy(c_gps, d / "day3.gpx")
    (loops / "2026_0506_080009_0004F.MP4").write_bytes(b"\x00" * 4096)  # a damaged loop file
    event = d / "RO"  # b was kept by the camera as an event (a Viofo's read-only folder)
    event.mkdir()
    shutil.copy(drives["b"][0], event / "b.mp4")
    shutil.copy(drives["b"][1], event / "b.gpx")
    root = d / "archive"
    assert run_cli("dashcam", "init", root).returncode == 0
    # --codec vp9: standalone pieces in VP9 as before AV1, so that b and the trip are coded against a
    # (the forget tests below need those dependents; with AV1 they would be stored standalone).
    r = run_cli("dashcam", "ingest", root, drives["a"][0], "--gps", drives["a"][1], "--codec", "vp9")
    assert r.returncode == 0, r.stderr
    # One batch: the day-3 log covers the loop files; the event file, outside it, keeps its own log.
    r = run_cli(
        "dashcam", "ingest", root, loops, event, "--gps", d / "day3.gpx", "--codec", "vp9", "--json", d / "batch.json"
    )
    assert r.returncode == 0, r.stderr
    assert "event (locked)" in r.stdout and "skipped" in r.stderr and "0004F.MP4" in r.stderr
    batch = json.loads((d / "batch.json").read_text())
    (trip,) = [x for x in batch["drives"] if x["kind"] == "drive"]
    trip["skipped"] = batch["skipped"]
    for name in ("a", "b"):
        assert run_cli("dashcam", "extract", root, name, "-o", d / f"{name}-ref.mkv").returncode == 0
    r = run_cli("dashcam", "ingest", root, loops, "--gps", d / "day3.gpx")  # the same card again
    assert r.returncode == 0 and "nothing new" in r.stdout and "0004F.MP4" in r.stderr, r.stdout + r.stderr
    return {"root": root, "dir": d, "drives": drives, "files": files, "trip": trip}


def test_three_loop_files_make_one_trip(fleet):
    files = fleet["files"]
    trip = fleet["trip"]  # one drive: its report (with the files it was made of, and what was left out)
    skipped = [x["file"].rsplit("/", 1)[-1] for x in trip["skipped"]]
    assert skipped == ["2026_0506_080009_0004F.MP4"]  # listed with the reason, not dropped silently
    assert trip["files"] == [str(f.resolve()) for f in files] and trip["kind"] == "drive"
    assert trip["gaps_s"] == pytest.approx([0.0, 0.0], abs=1.5 / FPS)
    # Frames in order across the joins: each extracted frame is closest to the source frame it
    # came from (lossy, so by PSNR), not to its neighbours.
    out = fleet["dir"] / "trip.mkv"
    r = run_cli("dashcam", "extract", fleet["root"], trip["name"], "-o", out)
    assert r.returncode == 0, r.stderr
    got = [f.image[:H].astype(float) for f in iter_frames(out, i420=True)]
    src = [f.image[:H].astype(float) for p in files for f in iter_frames(p, i420=True)]
    assert len(got) == len(src)
    for k in (len(src) // 3 - 1, len(src) // 3, 2 * len(src) // 3):
        err = [np.mean((got[k] - src[j]) ** 2) for j in (k - 1, k, k + 1)]
        assert int(np.argmin(err)) == 1


def test_a_log_beside_the_first_loop_file_covers_the_next_ones(fleet, tmp_path):
    from egovid.dashcam.ingest.sources import ClockOptions, examine

    files = fleet["files"]
    for f in files:
        (tmp_path / f.name).symlink_to(f)
    log = tmp_path / (files[0].stem + ".gpx")  # a logger's one file per drive, named after its first file
    shutil.copy(fleet["dir"] / "day3.gpx", log)
    src = examine(tmp_path / files[2].name, None, ClockOptions())
    assert src.gps_source == str(log) and src.clock.source == "creation_time"
    shutil.copy(fleet["drives"]["a"][0], tmp_path / "other.mp4")  # recorded two days before the log
    with pytest.raises(EgovidError, match="--gps"):  # so not placed in it
        examine(tmp_path / "other.mp4", None, ClockOptions())


def test_find_near_box_and_time(fleet, capsys):
    # Reading commands, in this process (a process start is not what is tested here).
    root = fleet["root"]
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    track = read_track(fleet["drives"]["a"][1])
    lat, lon = float(track.lat[len(track) // 2]), float(track.lon[len(track) // 2])
    r = cli("dashcam", "find", root, "--near", f"{lat},{lon}", "--radius", "15", "--json", "-")
    assert r.returncode == 0, r.stderr
    found = json.loads(r.stdout)
    assert sorted(s["drive"] for s in found) == ["2026_0506_080000_0001F", "a", "b"]
    for s in found:
        assert s["distance_m"] < 15 and s["frames"] > 0
    # The first day only, by time; a box around the point gives the same drives.
    r = cli("dashcam", "find", root, "--near", f"{lat},{lon}", "--from", "2026-05-04T00:00Z",
                "--to", "2026-05-05T00:00Z", "--json", "-")  # fmt: skip
    assert [s["drive"] for s in json.loads(r.stdout)] == ["a"]
    d = 0.0003
    r = cli("dashcam", "find", root, "--bbox", f"{lon - d},{lat - d},{lon + d},{lat + d}", "--json", "-")
    assert len(json.loads(r.stdout)) == 3
    r = cli("dashcam", "find", root, "--near", "0,0")
    assert r.returncode == 0 and "0 stretch" in r.stdout
    assert_one_error(cli("dashcam", "find", root, "--bbox", "1,2,3"), "--bbox")
    assert_one_error(cli("dashcam", "find", root), "--near")


def test_clip_around_a_moment(fleet, capsys):
    root, d = fleet["root"], fleet["dir"]
    moment = DAY + dt.timedelta(days=1, seconds=4)  # drive b, 4 s in
    out = d / "incident.mp4"
    r = run_cli("dashcam", "clip", root, "--at", moment.isoformat(), "--before", "2", "--after", "3", "-o", out,
                "--lossless")  # fmt: skip
    assert r.returncode == 0, r.stderr
    clip = _frames_hash(out)
    assert len(clip) == 51  # 2 s before and 3 s after at 10 fps, and the frame of the moment
    whole = _frames_hash(d / "b-ref.mkv")
    assert clip == whole[20:71]  # frames exactly as archived
    gpx = read_track(out.with_suffix(".gpx"))
    assert gpx.t[0] <= _utc(moment) - 2 + 1 and gpx.t[-1] >= _utc(moment) + 3 - 1
    # The shareable kind: H.264 that players take, same frames to within coding loss.
    out2 = d / "incident2.mp4"
    r = run_cli("dashcam", "clip", root, "--near", f"{gpx.lat[len(gpx) // 2]},{gpx.lon[len(gpx) // 2]}",
                "--drive", "b", "-o", out2)  # fmt: skip
    assert r.returncode == 0, r.stderr
    with av.open(str(out2)) as c:
        assert c.streams.video[0].codec_context.name == "h264" and c.streams.video[0].codec_context.pix_fmt == "yuv420p"
    refused = invoke_cli(["dashcam", "clip", root, "--at", "2020-01-01T00:00Z", "-o", d / "x.mp4"], capsys)
    assert_one_error(refused, "not recorded")


def _catalogue_state(root: Path) -> dict:
    db = sqlite3.connect(str(root / "catalogue.sqlite"))
    try:
        return {t: db.execute(f"SELECT * FROM {t} ORDER BY 1").fetchall() for t in
                ("drives", "segments", "sequences", "drive_meta", "drive_parts")}  # fmt: skip
    finally:
        db.close()


def test_lock_and_forget_a_root_with_dependents(fleet, tmp_path, capsys):
    # The refusals, dry runs and listings run in this process (invoke_cli); what changes the
    # archive runs as a process of its own.
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    src = fleet["root"]
    root = tmp_path / "archive"
    shutil.copytree(src, root)
    trip = fleet["trip"]["name"]
    before = {}
    for name in ("b", trip):
        assert run_cli("dashcam", "extract", root, name, "-o", tmp_path / f"{name}-before.mkv").returncode == 0
        before[name] = _frames_hash(tmp_path / f"{name}-before.mkv")
    before_frames_a = (
        sqlite3.connect(str(root / "catalogue.sqlite"))
        .execute("SELECT frames FROM drives WHERE name = 'a'")
        .fetchone()[0]
    )
    assert run_cli("dashcam", "lock", root, "a", "--note", "insurance claim").returncode == 0
    assert_one_error(cli("dashcam", "forget", root, "a"), "locked (insurance claim)")
    # Policies pass locked drives over: a (locked by hand) and b (an event file, locked at ingest).
    r = cli("dashcam", "forget", root, "--older-than", "0d", "--dry-run")
    assert "kept a: locked" in r.stderr and "kept b: locked" in r.stderr
    assert f"would forget 1 drive(s): {trip}" in r.stdout
    r = cli("dashcam", "forget", root, "--keep-bytes", "1K", "--dry-run", "--json", "-")
    assert json.loads(r.stdout)["forgotten"] == [trip] and f"would forget 1 drive(s): {trip}" in r.stderr
    assert run_cli("dashcam", "unlock", root, "a", "b").returncode == 0
    r = run_cli("dashcam", "forget", root, "a", "--json", tmp_path / "forget.json")
    assert r.returncode == 0, r.stderr
    rep = json.loads((tmp_path / "forget.json").read_text())
    assert rep["forgotten"] == ["a"] and set(rep["verified"]) >= {"b"}
    # a keeps only the random-access runs b and c are predicted from: its second half goes.
    assert sorted(rep["kept_as_reference"]["a"]) == ["2026_0506_080000_0001F", "b"]
    assert 0 < rep["frames_kept"]["a"] < 0.75 * before_frames_a and rep["bytes_freed"] > 0
    r = cli("dashcam", "list", root)
    assert " a " not in r.stdout and " b " in r.stdout
    db = sqlite3.connect(str(root / "catalogue.sqlite"))
    (hidden,) = db.execute("SELECT name FROM drives WHERE name LIKE 'a~%'").fetchone()
    db.close()
    for key in ("a", hidden):  # the hidden reference is no drive of the user's any more
        assert_one_error(cli("dashcam", "extract", root, key, "-o", tmp_path / "a.mkv"), f"no drive {key!r}")
    for name in ("b", trip):
        out = tmp_path / f"{name}-after.mkv"
        assert run_cli("dashcam", "extract", root, name, "-o", out).returncode == 0
        assert _frames_hash(out) == before[name]  # every remaining drive decodes bit for bit as before
    assert "would delete 0" in cli("dashcam", "gc", root, "--dry-run").stdout
    # Forget every drive: the hidden reference goes too, and every bitstream with it.
    r = run_cli("dashcam", "forget", root, "b", trip)
    assert r.returncode == 0, r.stderr
    assert _catalogue_state(root)["drives"] == []
    assert not [p for p in (root / "blobs").rglob("*") if p.is_file()]


def test_kill_during_forget_leaves_archive_consistent(fleet, tmp_path):
    root = tmp_path / "archive"
    shutil.copytree(fleet["root"], root)
    before = _catalogue_state(root)
    # Hold the forget inside its transaction, deterministically: one bitstream of b (coded against
    # a, so verified before the commit) becomes a named pipe, and reading it blocks until we write.
    db = sqlite3.connect(str(root / "catalogue.sqlite"))
    sha = db.execute("SELECT s.blob FROM segments s JOIN drives d ON d.id = s.drive_id WHERE d.name = 'b' "
                     "ORDER BY s.frame_start DESC").fetchone()[0]  # fmt: skip
    db.close()
    (blob,) = (root / "blobs").glob(f"*/{sha}")
    data = blob.read_bytes()
    blob.unlink()
    os.mkfifo(blob)
    proc = subprocess.Popen([sys.executable, "-m", "egovid", "dashcam", "forget", str(root), "a"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    started = lambda: any("verifying" in ln for ln in lines) or proc.poll() is not None  # noqa: E731
    try:
        _wait_for(started, "forget to start verifying", 300)
        assert proc.poll() is None, f"forget ended before it could be killed: {''.join(lines)}"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
        blob.unlink()
        blob.write_bytes(data)
    assert _catalogue_state(root) == before  # killed inside its transaction: nothing changed
    db = sqlite3.connect(str(root / "catalogue.sqlite"))
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    db.close()
    # What it wrote before its commit (the trimmed part of a) is unreferenced: gc takes it, and
    # every drive still extracts as archived.
    r = run_cli("dashcam", "gc", root)
    assert r.returncode == 0 and "deleted 0 " not in r.stdout, r.stdout + r.stderr
    for name in ("a", "b"):
        out = tmp_path / f"{name}.mkv"
        assert run_cli("dashcam", "extract", root, name, "-o", out).returncode == 0
        assert _frames_hash(out) == _frames_hash(fleet["dir"] / f"{name}-ref.mkv")
    r = run_cli("dashcam", "forget", root, "a")
    assert r.returncode == 0, r.stderr


def test_report_html_draws_every_drive_in_chromium(fleet, tmp_path):
    page = tmp_path / "report.html"
    r = run_cli("dashcam", "report", fleet["root"], "--html", page, "--tiles", "none")
    assert r.returncode == 0, r.stderr
    dom = browse(page, tmp_path)
    assert 'data-tracks="3"' in dom  # one stretch per stored segment: one segment per drive here
    for name in ("a", "b", "2026_0506_080000_0001F"):
        assert name in page.read_text()
