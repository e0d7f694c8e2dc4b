"""Two-camera dashcams: a front and a rear file of the same minutes become one drive with two
channels, each coded against the same camera of older drives; extract and clip write one camera
(``--channel NAME``) or all of them in sync (``--channel all``).

The rear camera's pictures are the front's mirrored with the light inverted, so which source
frame an output frame came from (and of which camera) is told by the pictures themselves: the
independent truth the sync is measured against. Day 2's rear camera is two loop files with a
2 s gap between them, so its frame numbers and the front's part ways after the gap and only
the frame times keep them together."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import shutil
import sqlite3
from pathlib import Path

import av
import numpy as np
import pytest

from egovid.core.video import iter_frames
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.codec import segment as codec
from egovid.dashcam.report import list_drives
from egovid.synth.drive import DriveSpec, Light, render_drive

from conftest import assert_one_error, invoke_cli, run_cli

W, H, FPS = 160, 96, 10.0
DAY = dt.datetime(2026, 7, 1, 9, 0, 0, tzinfo=dt.UTC)
GAP = (30, 50)  # day 2's rear camera recorded nothing over these frames (2 s)


def _write(path: Path, frames: list[np.ndarray], t: dt.datetime) -> Path:
    """A lossless H.264 file with the creation_time of its first frame (a camera's own clock)."""
    with av.open(str(path), "w") as c:
        c.metadata["creation_time"] = t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        s = c.add_stream("libx264", rate=int(FPS))
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        s.options = {"qp": "0", "preset": "ultrafast"}
        for i, img in enumerate(frames):
            vf = av.VideoFrame.from_ndarray(img, format="yuv420p")
            vf.pts = i
            for p in s.encode(vf):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


def _rear(img: np.ndarray) -> np.ndarray:
    """The rear camera's picture of a front I420 frame: mirrored, luma inverted."""
    y = 255 - img[:H, ::-1]
    u, v = (img[H + k * H // 4 : H + (k + 1) * H // 4].reshape(H // 2, W // 2)[:, ::-1] for k in (0, 1))
    return np.ascontiguousarray(np.vstack([y, u.reshape(H // 4, W), v.reshape(H // 4, W)]))


def _card(d: Path, day: dt.datetime, seed: int, split_rear: bool) -> dict:
    spec = DriveSpec(legs=[("main", 380.0, 440.0)], cruise=10.0, seed=seed, light=Light.preset("noon"), start_time=day)
    video, gps, _ = render_drive(spec, d / f"day{seed}.mp4", width=W, height=H, fps=FPS, gps_format="gpx")
    front = [f.image for f in iter_frames(video, i420=True)]
    rear = [_rear(f) for f in front]
    card = d / f"card{seed}"
    card.mkdir()
    stamp = f"{day:%Y_%m%d_%H%M%S}"
    files = [_write(card / f"{stamp}_0001F.MP4", front, day)]
    if split_rear:  # two loop files, 2 s apart (the second has no front file of its moment)
        t2 = day + dt.timedelta(seconds=GAP[1] / FPS)
        files.append(_write(card / f"{stamp}_0001R.MP4", rear[: GAP[0]], day))
        files.append(_write(card / f"{t2:%Y_%m%d_%H%M%S}_0002R.MP4", rear[GAP[1] :], t2))
    else:
        files.append(_write(card / f"{stamp}_0001R.MP4", rear, day))
    return {"card": card, "gps": gps, "front": front, "rear": rear, "name": f"{stamp}_0001F", "files": files}


def _rows(root: Path) -> dict:
    db = sqlite3.connect(str(root / "catalogue.sqlite"))
    try:
        return {t: db.execute(f"SELECT * FROM {t} ORDER BY 1").fetchall() for t in
                ("drives", "segments", "drive_channels", "file_digests")}  # fmt: skip
    finally:
        db.close()


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """An archive of two days of the same street, each recorded by a front and a rear camera."""
    d = tmp_path_factory.mktemp("channels")
    days = [_card(d, DAY, 1, False), _card(d, DAY + dt.timedelta(days=1), 2, True)]
    root = d / "archive"
    assert run_cli("dashcam", "init", root).returncode == 0
    for k, day in enumerate(days):
        r = run_cli("dashcam", "ingest", root, day["card"], "--gps", day["gps"], "--codec", "vp9",
                    "--json", d / f"ingest{k}.json")  # fmt: skip
        assert r.returncode == 0, r.stdout + r.stderr
    return {"dir": d, "root": root, "days": days}


def _frames(path: Path) -> list[np.ndarray]:
    return [f.image for f in iter_frames(path, i420=True)]


def _closest(frame: np.ndarray, sources: list[np.ndarray]) -> int:
    """Index of the source picture most like ``frame`` (mean squared error of the luma)."""
    y = frame[:H].astype(np.float32)
    return int(np.argmin([np.mean((y - s[:H].astype(np.float32)) ** 2) for s in sources]))


def test_a_front_and_rear_pair_is_one_drive_with_two_channels(pair, capsys):
    # The reading commands and refusals run in this process (see invoke_cli).
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    root, days = pair["root"], pair["days"]
    page = pair["dir"] / "map.html"
    r = cli("dashcam", "report", root, "--json", pair["dir"] / "report.json", "--html", page)
    assert r.returncode == 0 and "map of 2 drive(s)" in r.stdout, r.stdout + r.stderr
    assert page.read_text().count('"cameras":"front (main), rear (') == 2
    rep = {x["drive"]: x for x in json.loads((pair["dir"] / "report.json").read_text())["drives"]}
    for day in days:
        main = rep[day["name"]]
        assert main["channels"] == {"front": day["name"], "rear": f"{day['name']}~rear"}
        assert rep[f"{day['name']}~rear"]["channel_of"] == day["name"]
    r = run_cli("dashcam", "list", root, env={"COLUMNS": "200"})  # the user sees two drives, not four
    assert r.returncode == 0 and days[1]["name"] in r.stdout and "~rear" not in r.stdout, r.stdout
    assert r.stdout.count("front, rear") == 2, r.stdout  # the cameras column
    # each row's bytes are those of both its cameras (the catalogue's segment rows, summed here)
    ar = Archive(root)
    try:
        listed = {row.drive.name: row.bytes for row in list_drives(ar)}
        cat = ar.catalogue
        per_camera = {nm: sum(s.bytes for s in cat.segments(cat.drive(nm).id))
                      for x in days for nm in (x["name"], f"{x['name']}~rear")}  # fmt: skip
    finally:
        ar.close()
    assert listed == {x["name"]: per_camera[x["name"]] + per_camera[f"{x['name']}~rear"] for x in days}
    assert all(v > 0 for v in per_camera.values())
    ingest = json.loads((pair["dir"] / "ingest1.json").read_text())  # one drive, its rear camera beside it
    assert [ingest["camera"], *(x["camera"] for x in ingest["channels"])] == ["front", "rear"]
    assert ingest["channels"][0]["channel_of"] == days[1]["name"]
    for rep_ in (ingest["channels"][0], json.loads((pair["dir"] / "ingest0.json").read_text())["channels"][0]):
        assert rep_["new_paths"] == [] and rep_["split_paths"] == []  # a camera follows its drive's paths
    # Each camera is coded against the same camera of the older drive (never across cameras).
    rows = _rows(root)
    ids = {x[1]: x[0] for x in rows["drives"]}
    second = days[1]["name"]
    refs = {ch: {s[5] for s in rows["segments"] if s[1] == ids[nm]}
            for ch, nm in (("front", second), ("rear", f"{second}~rear"))}  # fmt: skip
    assert refs == {"front": {ids[days[0]["name"]]}, "rear": {ids[f"{days[0]['name']}~rear"]}}, refs
    assert sorted((c[0], c[1]) for c in rows["drive_channels"]) == [
        (ids[f"{x['name']}~rear"], ids[x["name"]]) for x in days
    ]
    # The rear drive holds both loop files, the gap between them kept in its frame times.
    frames = {x[1]: x[9] for x in rows["drives"]}
    assert frames[f"{second}~rear"] == frames[second] - (GAP[1] - GAP[0]) == len(days[1]["front"]) - 20
    r = cli("dashcam", "check", root, "--deep")
    assert r.returncode == 0 and "4 drive(s)" in r.stdout, r.stdout + r.stderr


def test_each_channel_extracts_bit_exact(pair, tmp_path):
    """Each camera of the drive coded against the older one, written whole: its frames are the
    encoder's reconstruction (the digests it stored), and they are that camera's pictures."""
    root, day = pair["root"], pair["days"][1]
    rows = _rows(root)
    ids = {x[1]: x[0] for x in rows["drives"]}
    for channel, name, source in (("front", day["name"], day["front"]),
                                  ("rear", f"{day['name']}~rear", day["rear"])):  # fmt: skip
        out = tmp_path / f"{channel}.mkv"
        r = run_cli("dashcam", "extract", root, day["name"], "--channel", channel, "-o", out)
        assert r.returncode == 0, r.stderr
        got = _frames(out)
        segs = sorted((s for s in rows["segments"] if s[1] == ids[name]), key=lambda s: s[2])
        assert len(got) == segs[-1][3]
        for s in segs:
            h = hashlib.sha256()
            for f in got[s[2] : s[3]]:
                codec.digest_update(h, f)
            assert h.hexdigest() == json.loads(s[10])["recon_digest"], (channel, s[0])
        other = day["rear"] if channel == "front" else day["front"]
        k = 5
        assert _closest(got[k], [source[k], other[k]]) == 0  # the camera asked for, not the other


def test_channel_all_writes_every_camera_in_sync(pair, tmp_path):
    """Past the rear camera's gap its frame numbers are 20 behind the front's: both outputs still
    start and go on at the same moment (≤ 1 frame, told by the pictures)."""
    root, day = pair["root"], pair["days"][1]
    out = tmp_path / "x.mkv"
    r = run_cli("dashcam", "extract", root, day["name"], "--channel", "all", "--start", "5.2", "--duration", "0.6",
                "-o", out)  # fmt: skip
    assert r.returncode == 0, r.stderr
    front, rear = _frames(tmp_path / "x-front.mkv"), _frames(tmp_path / "x-rear.mkv")
    assert len(front) == len(rear) == 6 and not out.exists()
    seen_f = [_closest(f, day["front"]) for f in front]
    seen_r = [_closest(f, day["rear"]) for f in rear]
    assert seen_f == list(range(52, 58))
    assert max(abs(a - b) for a, b in zip(seen_f, seen_r, strict=True)) <= 1, (seen_f, seen_r)
    # A clip of both cameras around a moment after the gap, each with its GPX.
    moment = (DAY + dt.timedelta(days=1, seconds=5.5)).isoformat()
    clip = tmp_path / "c.mp4"
    r = run_cli("dashcam", "clip", root, "--at", moment, "--before", "0.3", "--after", "0.3", "--channel", "all",
                "--lossless", "-o", clip)  # fmt: skip
    assert r.returncode == 0, r.stderr
    cf, cr = _frames(tmp_path / "c-front.mp4"), _frames(tmp_path / "c-rear.mp4")
    assert len(cf) == len(cr) > 0 and (tmp_path / "c-rear.gpx").is_file()
    assert max(abs(_closest(a, day["front"]) - _closest(b, day["rear"])) for a, b in zip(cf, cr, strict=True)) <= 1


def test_an_unknown_channel_is_an_error_naming_the_cameras(pair, tmp_path, capsys):
    # The reading commands and refusals run in this process (see invoke_cli).
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    root, day = pair["root"], pair["days"][0]
    before = _rows(root)
    r = cli("dashcam", "extract", root, day["name"], "--channel", "interior", "-o", tmp_path / "x.mkv")
    assert_one_error(r, "no channel 'interior'")
    assert "front, rear" in r.stderr
    moment = (DAY + dt.timedelta(seconds=3)).isoformat()
    r = cli("dashcam", "clip", root, "--at", moment, "--channel", "side", "-o", tmp_path / "c.mp4")
    assert_one_error(r, "no channel 'side'")
    assert_one_error(cli("dashcam", "extract", root, f"{day['name']}~rear", "-o", tmp_path / "y.mkv"), "no drive")
    assert list(tmp_path.iterdir()) == [] and _rows(root) == before


def test_the_pair_again_is_a_no_op(pair, tmp_path):
    root, day = pair["root"], pair["days"][0]
    before = _rows(root)
    copy = tmp_path / "again"
    shutil.copytree(day["card"], copy)
    r = run_cli("dashcam", "ingest", root, copy, "--gps", day["gps"])
    assert r.returncode == 0, r.stdout + r.stderr
    assert "2 file(s) already archived" in r.stdout and "nothing new" in r.stdout, r.stdout
    assert _rows(root) == before


def test_forget_takes_the_cameras_with_their_drive(pair, tmp_path, capsys):
    # The reading commands and refusals run in this process (see invoke_cli).
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    root = tmp_path / "copy"
    shutil.copytree(pair["root"], root)
    second = pair["days"][1]["name"]
    r = run_cli("dashcam", "forget", root, second)
    assert r.returncode == 0 and f"{second}~rear" in r.stdout, r.stdout + r.stderr
    rows = _rows(root)
    assert {x[1] for x in rows["drives"]} == {pair["days"][0]["name"], f"{pair['days'][0]['name']}~rear"}
    assert len(rows["drive_channels"]) == 1
    assert cli("dashcam", "check", root).returncode == 0


def test_a_camera_comes_later_and_a_rear_loop_file_continues_its_channel(pair, tmp_path, capsys):
    """As after a kill between a drive's commit and its camera's: the front file archived alone,
    then the card again adds the rear camera to that drive. And a rear loop file synced later
    continues the rear channel (appended), not a drive of its own."""
    # The reading commands and refusals run in this process (see invoke_cli).
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    root = tmp_path / "archive"
    assert run_cli("dashcam", "init", root).returncode == 0
    one, two = pair["days"]
    r = run_cli("dashcam", "ingest", root, one["files"][0], "--gps", one["gps"], "--codec", "vp9")
    assert r.returncode == 0, r.stdout + r.stderr
    r = run_cli("dashcam", "ingest", root, one["card"], "--gps", one["gps"], "--codec", "vp9")
    assert r.returncode == 0 and "1 file(s) already archived" in r.stdout, r.stdout + r.stderr
    assert f"rear camera of drive '{one['name']}'" in r.stdout, r.stdout
    first = tmp_path / "first"
    first.mkdir()
    for f in two["files"][:2]:  # the front file and the rear camera's first loop file
        shutil.copy(f, first / f.name)
    assert run_cli("dashcam", "ingest", root, first, "--gps", two["gps"], "--codec", "vp9").returncode == 0
    r = run_cli("dashcam", "ingest", root, two["files"][2], "--gps", two["gps"], "--codec", "vp9")
    assert r.returncode == 0 and f"appended to drive '{two['name']}~rear'" in r.stdout, r.stdout + r.stderr
    rows = _rows(root)
    assert sorted(x[1] for x in rows["drives"]) == sorted(
        [one["name"], f"{one['name']}~rear", two["name"], f"{two['name']}~rear"]
    )
    assert len(rows["drive_channels"]) == 2
    out = tmp_path / "r.mkv"
    r = run_cli("dashcam", "extract", root, two["name"], "--channel", "rear", "--start", "5", "-o", out)
    assert r.returncode == 0, r.stderr
    got = _frames(out)
    assert [_closest(f, two["rear"]) for f in got[:3]] == [50, 51, 52]  # after the gap, by its time
    assert cli("dashcam", "check", root).returncode == 0


def _held(lock: Path) -> bool:
    """Whether another process holds the archive's maintenance lock (a restore is under way)."""
    import fcntl

    with open(lock, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(fh, fcntl.LOCK_UN)
        return False


@pytest.mark.slow
def test_a_kill_mid_restore_leaves_the_archive_empty_then_it_restores_whole(pair, tmp_path):
    """kill -9 while a restore copies rows inside its transaction (the backup padded with 400000
    known-file rows so the copy takes seconds; killed once the restore holds the archive's
    maintenance lock and has been copying for a while): the catalogue is as empty as before (or,
    should the commit beat the signal on a loaded machine, complete) and check is clean; the
    restore run again gives every row, the cameras included."""
    import subprocess
    import sys
    import time

    from conftest import _wait_for

    backup = tmp_path / "b.sqlite"
    assert run_cli("dashcam", "backup", pair["root"], backup).returncode == 0
    db = sqlite3.connect(str(backup))
    digests = np.random.default_rng(30).bytes(32 * 400_000).hex()  # in one call: 400000 calls took 15 s
    db.executemany("INSERT INTO file_digests(sha256, bytes, name) VALUES(?,?,?)",
                   ((digests[64 * k : 64 * k + 64], 1000 + k, f"FILE{k:06d}.MP4") for k in range(400_000)))  # fmt: skip
    db.commit()
    db.close()
    new = tmp_path / "new"
    assert run_cli("dashcam", "init", new).returncode == 0
    empty = _rows(new)
    proc = subprocess.Popen([sys.executable, "-m", "egovid", "dashcam", "restore", str(backup), str(new)],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        _wait_for(lambda: _held(new / ".lock") or proc.poll() is not None, "the restore's transaction", 300)
        time.sleep(0.5)  # copying rows
        assert proc.poll() is None, f"the restore ended (status {proc.returncode}) before it could be killed"
    finally:
        proc.send_signal(9)
        proc.wait(timeout=60)
    # One transaction: the kill leaves the catalogue as it was, or (when the commit came first, as
    # it can on a loaded machine between the check above and the signal) complete; never between.
    committed = _rows(new) != empty
    want = _rows(pair["root"])
    shutil.rmtree(new / "blobs")
    shutil.copytree(pair["root"] / "blobs", new / "blobs")
    r = run_cli("dashcam", "check", new)
    assert r.returncode == 0, r.stdout + r.stderr
    if not committed:
        r = run_cli("dashcam", "restore", backup, new)
        assert r.returncode == 0, r.stderr
    got = _rows(new)
    assert len(got["file_digests"]) == len(want["file_digests"]) + 400_000
    assert {k: v for k, v in got.items() if k != "file_digests"} == {
        k: v for k, v in want.items() if k != "file_digests"
    }
    r = run_cli("dashcam", "check", new)
    assert r.returncode == 0, r.stdout + r.stderr
    out = tmp_path / "r.mkv"
    assert run_cli("dashcam", "extract", new, pair["days"][1]["name"], "--channel", "rear", "-o", out).returncode == 0
