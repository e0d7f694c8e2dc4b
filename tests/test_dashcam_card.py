"""The archive a dashcam owner keeps for years, as a sync job runs it: the same card ingested again
(files known by content, not by name), a loop file that continues an archived trip (appended to
that drive), two different files of the same name from two cards."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from egovid.core.video import iter_frames
from egovid.synth.drive import DriveSpec, Light, render_drive
from test_dashcam_fleet_archive import FPS, H, W, _split_lossless

from conftest import _wait_for, assert_one_error, run_cli

DAY = dt.datetime(2026, 6, 1, 9, 0, 0, tzinfo=dt.UTC)


def _rows(root: Path) -> dict:
    return _rows_of(root / "catalogue.sqlite")


def _rows_of(file: Path) -> dict:
    db = sqlite3.connect(str(file))
    try:
        return {t: db.execute(f"SELECT * FROM {t} ORDER BY 1").fetchall() for t in
                ("drives", "segments", "sequences", "drive_parts", "file_digests")}  # fmt: skip
    finally:
        db.close()


@pytest.fixture(scope="module")
def card(tmp_path_factory):
    """One drive recorded as three loop files: the first two on a card ingested first, the third
    synced later; one GPS log for the day."""
    d = tmp_path_factory.mktemp("card")
    spec = DriveSpec(legs=[("main", 380.0, 500.0)], cruise=10.0, seed=5, light=Light.preset("noon"), start_time=DAY)
    video, gps, truth = render_drive(spec, d / "whole.mp4", width=W, height=H, fps=FPS, gps_format="gpx")
    n = len(truth.times)
    loops = d / "loops"
    loops.mkdir()
    files = _split_lossless(video, loops, [n // 3, 2 * n // 3], DAY)
    first = d / "card1"
    first.mkdir()
    for f in files[:2]:
        shutil.copy(f, first / f.name)
    root = d / "archive"
    assert run_cli("dashcam", "init", root).returncode == 0
    r = run_cli("dashcam", "ingest", root, first, "--gps", gps, "--codec", "vp9")
    assert r.returncode == 0, r.stderr
    return {"dir": d, "root": root, "files": files, "gps": gps, "card1": first, "n": n}


@pytest.mark.slow
def test_the_same_card_again_is_a_no_op_that_says_so(card):
    root, d = card["root"], card["dir"]
    before = _rows(root)
    assert len(before["file_digests"]) == 2 and {r[3] for r in before["file_digests"]} == {
        f.name for f in card["files"][:2]
    }
    r = run_cli("dashcam", "ingest", root, card["card1"], "--gps", card["gps"])
    assert r.returncode == 0, r.stderr
    assert "2 file(s) already archived" in r.stdout and "nothing new" in r.stdout, r.stdout
    assert r.stderr.strip() == ""  # counted, not listed one by one
    # The same file copied under another name is the same file.
    other = d / "renamed"
    other.mkdir()
    shutil.copy(card["files"][0], other / "COPY.MP4")
    r = run_cli("dashcam", "ingest", root, other / "COPY.MP4", "--gps", card["gps"])
    assert r.returncode == 0 and "1 file(s) already archived" in r.stdout, r.stdout + r.stderr
    assert _rows(root) == before


HEAVY = ("cv2", "scipy", "numba", "av", "egovid.dashcam.ingest")  # the ingest pipeline and what it loads


def _imported(stderr: str) -> set[str]:
    """The modules a run of ``python -X importtime`` imported (its stderr), by full name."""
    return {ln.rsplit("|", 1)[1].strip() for ln in stderr.splitlines() if ln.startswith("import time:")} - {
        "imported package"
    }


@pytest.mark.slow
@pytest.mark.parametrize("verify", [False, True])
def test_the_same_card_again_does_not_load_the_ingest_pipeline(card, tmp_path, verify):
    """A card synced again is answered by the light first step (egovid.dashcam.archive.identity):
    the decoders, numerics and codecs of the ingest are never imported; --verify-known (full
    SHA-256 of every file) answers the same."""
    root = card["root"]
    before = _rows(root)
    out = tmp_path / "report.json"
    extra = ["--verify-known"] if verify else []
    r = run_cli("dashcam", "ingest", root, card["card1"], "--gps", card["gps"], "--json", out, *extra,
                env={"PYTHONPROFILEIMPORTTIME": "1"})  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    assert "2 file(s) already archived" in r.stdout and "nothing new" in r.stdout, r.stdout
    mods = _imported(r.stderr)
    assert "egovid.dashcam.archive.identity" in mods  # the importtime listing is what it should be
    loaded = sorted(m for m in mods if m.split(".")[0] in HEAVY or m.startswith(HEAVY[-1]))
    assert loaded == [], loaded
    rep = json.loads(out.read_text())
    assert rep["drives"] == [] and rep["failed"] == []
    assert sorted(Path(x["file"]).name for x in rep["skipped"]) == sorted(f.name for f in card["files"][:2])
    assert all(x["reason"].startswith("already in the archive") for x in rep["skipped"])
    assert _rows(root) == before


@pytest.mark.parametrize(
    ("option", "needle"),
    [(("--preset", "nope"), "unknown preset"), (("--joint-codec", "x"), "cannot code against"),
     (("--aligner", "nope"), "unknown aligner")],
)  # fmt: skip
def test_bad_coding_options_are_refused_even_when_the_card_holds_nothing_new(card, option, needle):
    """The light first step answers a known card without the ingest pipeline, but coding options
    that were given are checked first: a sync job's typo is one error line, not 'nothing new'."""
    root = card["root"]
    before = _rows(root)
    r = run_cli("dashcam", "ingest", root, card["card1"], "--gps", card["gps"], *option)
    assert_one_error(r, needle)
    assert _rows(root) == before


@pytest.mark.slow
def test_a_kill_mid_append_leaves_the_archive_as_it_was(card, tmp_path):
    """kill -9 once the append has written a bitstream, before its commit (held back by a write
    transaction the test keeps open, so the kill cannot come too late): the catalogue is as it
    was, check is clean (the leftover blob is a note for gc), and the file is appended later."""
    root, files = card["root"], card["files"]
    before = _rows(root)
    folder = tmp_path / "card2"
    folder.mkdir()
    shutil.copy(files[2], folder / files[2].name)
    blobs = lambda: {p.name for p in (root / "blobs").rglob("*") if p.is_file()}  # noqa: E731
    had = blobs()
    args = ["dashcam", "ingest", root, folder, "--gps", card["gps"], "--preset", "archive"]
    hold = sqlite3.connect(str(root / "catalogue.sqlite"), isolation_level=None)
    hold.execute("BEGIN IMMEDIATE")  # the append's commit waits for this (SQLite's 30 s busy timeout)
    proc = subprocess.Popen([sys.executable, "-m", "egovid", *map(str, args)], stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        _wait_for(lambda: bool(blobs() - had) or proc.poll() is not None, "the append's first bitstream", 600)
        time.sleep(1.0)  # the piece written whole, the commit waiting
        assert proc.poll() is None, f"the append ended (status {proc.returncode}) before it could be killed"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
        hold.rollback()
        hold.close()
    assert _rows(root) == before
    r = run_cli("dashcam", "check", root)
    assert r.returncode == 0, r.stdout + r.stderr
    assert run_cli("dashcam", "gc", root).returncode == 0
    assert blobs() == had


@pytest.mark.slow
def test_a_later_loop_file_is_appended_and_the_other_card_is_stored_apart(card):
    root, d, files = card["root"], card["dir"], card["files"]
    (drive_before,) = _rows(root)["drives"]
    later = d / "card2"
    later.mkdir()
    shutil.copy(files[2], later / files[2].name)
    r = run_cli("dashcam", "ingest", root, later, "--gps", card["gps"], "--codec", "vp9")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "appended to drive" in r.stdout, r.stdout
    rows = _rows(root)
    (drive,) = rows["drives"]
    assert drive[0] == drive_before[0] and drive[9] == card["n"]  # one drive, all frames
    assert [p[2] for p in rows["drive_parts"]] == [0, 1, 2]
    assert sorted(s[2] for s in rows["segments"])[0] == 0
    assert run_cli("dashcam", "check", root).returncode == 0
    # extract sees the whole trip: each frame closest to the source frame it came from
    out = d / "trip.mkv"
    assert run_cli("dashcam", "extract", root, drive[1], "-o", out).returncode == 0
    got = [f.image[:H].astype(float) for f in iter_frames(out, i420=True)]
    src = [f.image[:H].astype(float) for p in files for f in iter_frames(p, i420=True)]
    assert len(got) == len(src) == card["n"]
    k = 2 * card["n"] // 3  # the appended file's first frame
    err = [np.mean((got[k] - src[j]) ** 2) for j in (k - 1, k, k + 1)]
    assert int(np.argmin(err)) == 1
    # clip over the join, by time
    moment = DAY + dt.timedelta(seconds=k / FPS)
    clip = d / "join.mp4"
    r = run_cli("dashcam", "clip", root, "--at", moment.isoformat(), "--before", "1", "--after", "1", "-o", clip)
    assert r.returncode == 0, r.stderr
    assert sum(1 for _ in iter_frames(clip)) == 21
    # The same name from another card, other bytes: stored too, under a name of its own.
    card3 = d / "card3"
    card3.mkdir()
    spec = DriveSpec(legs=[("main", 380.0, 440.0)], cruise=10.0, seed=9, light=Light.preset("noon"),
                     start_time=DAY + dt.timedelta(days=3))  # fmt: skip
    video, gps, _ = render_drive(spec, d / "other.mp4", width=W, height=H, fps=FPS, gps_format="gpx")
    shutil.copy(video, card3 / files[0].name)
    r = run_cli("dashcam", "ingest", root, card3 / files[0].name, "--gps", gps, "--codec", "vp9")
    assert r.returncode == 0, r.stdout + r.stderr
    names = [x[1] for x in _rows(root)["drives"]]
    assert len(names) == 2 and names[0] == files[0].stem and names[1].startswith(files[0].stem + "-")


def _frames(path: Path) -> list[str]:
    return [hashlib.sha256(f.image.tobytes()).hexdigest() for f in iter_frames(path, i420=True)]


def _extract_all(root: Path, names: list[str], out_dir: Path) -> dict[str, list[str]]:
    """The drives extracted, as hashes of their frames."""
    out_dir.mkdir()
    got = {}
    for name in names:
        out = out_dir / f"{name}.mkv"
        r = run_cli("dashcam", "extract", root, name, "-o", out)
        assert r.returncode == 0, r.stderr
        got[name] = _frames(out)
    return got


def _core_rows(root: Path) -> dict:
    return _rows(root)


@pytest.mark.slow
def test_backup_and_restore_sqlite_and_postgresql(card, pg_url, tmp_path):
    root = card["root"]
    names = [d[1] for d in _rows(root)["drives"]]
    want = _extract_all(root, names, tmp_path / "want")
    backup = tmp_path / "cat.backup"
    r = run_cli("dashcam", "backup", root, backup)
    assert r.returncode == 0 and backup.is_file(), r.stderr
    # Bad input: one error line, nothing changed.
    assert_one_error(run_cli("dashcam", "backup", root, backup), "exists")
    assert_one_error(run_cli("dashcam", "restore", backup, root), "not empty")
    assert_one_error(run_cli("dashcam", "restore", card["files"][0], tmp_path), "not an egovid archive")
    # Into an empty SQLite archive, the bitstreams copied as they are: bit-exact, check clean.
    new = tmp_path / "restored"
    assert run_cli("dashcam", "init", new).returncode == 0
    assert_one_error(run_cli("dashcam", "restore", card["files"][0], new), "not a catalogue backup")
    assert_one_error(run_cli("dashcam", "restore", tmp_path / "nothing", new), "does not exist")
    assert _rows(new)["drives"] == []
    r = run_cli("dashcam", "restore", backup, new)
    assert r.returncode == 0, r.stderr
    assert _core_rows(new) == _core_rows(root)
    r = run_cli("dashcam", "check", new)  # the bitstreams are not copied yet: check says so
    assert r.returncode == 2 and "missing" in r.stdout + r.stderr, r.stdout + r.stderr
    shutil.rmtree(new / "blobs")
    shutil.copytree(root / "blobs", new / "blobs")
    r = run_cli("dashcam", "check", new)
    assert r.returncode == 0, r.stdout + r.stderr
    assert _extract_all(new, names, tmp_path / "got") == want
    # Into a PostgreSQL catalogue (the real server), and its own backup back into SQLite.
    pg = tmp_path / "pg"
    assert run_cli("dashcam", "init", pg, "--db", pg_url).returncode == 0
    shutil.rmtree(pg / "blobs")
    shutil.copytree(root / "blobs", pg / "blobs")
    r = run_cli("dashcam", "restore", backup, pg)
    assert r.returncode == 0, r.stderr
    r = run_cli("dashcam", "check", pg)
    assert r.returncode == 0, r.stdout + r.stderr
    r = run_cli("dashcam", "find", pg, "--bbox", "-180,-90,180,90", "--json", "-")
    assert r.returncode == 0 and len(json.loads(r.stdout)) >= 1, r.stdout + r.stderr  # the track index rebuilt
    pg_backup = tmp_path / "pg.backup"
    assert run_cli("dashcam", "backup", pg, pg_backup).returncode == 0
    back = tmp_path / "back"
    assert run_cli("dashcam", "init", back).returncode == 0
    assert run_cli("dashcam", "restore", pg_backup, back).returncode == 0
    assert _core_rows(back) == _core_rows(root)


@pytest.mark.slow
def test_check_lists_missing_and_orphan_blobs_on_s3(card, s3_server, tmp_path):
    import s3fs

    root = card["root"]
    backup = tmp_path / "cat.backup"
    assert run_cli("dashcam", "backup", root, backup).returncode == 0
    s3 = tmp_path / "s3"
    r = run_cli("dashcam", "init", s3, "--blobs", "s3://egovid/restored", env=s3_server)
    assert r.returncode == 0, r.stderr
    assert run_cli("dashcam", "restore", backup, s3, env=s3_server).returncode == 0
    env = s3_server
    fs = s3fs.S3FileSystem(
        key=env["AWS_ACCESS_KEY_ID"],
        secret=env["AWS_SECRET_ACCESS_KEY"],
        client_kwargs={"endpoint_url": env["AWS_ENDPOINT_URL"]},
        skip_instance_cache=True,
    )
    blobs = sorted(p for p in (root / "blobs").rglob("*") if p.is_file())
    for p in blobs:
        fs.put_file(str(p), f"egovid/restored/{p.relative_to(root / 'blobs')}")
    r = run_cli("dashcam", "check", s3, env=s3_server)
    assert r.returncode == 0 and "no drive uses" not in r.stdout, r.stdout + r.stderr
    # One bitstream lost, one nobody uses: both named.
    gone = blobs[0]
    fs.rm(f"egovid/restored/{gone.relative_to(root / 'blobs')}")
    orphan = b"not a segment of any drive"
    name = hashlib.sha256(orphan).hexdigest()
    fs.pipe(f"egovid/restored/{name[:2]}/{name}", orphan)
    r = run_cli("dashcam", "check", s3, env=s3_server)
    assert r.returncode == 2, r.stdout + r.stderr
    assert gone.name[:12] in r.stdout + r.stderr and name in r.stdout, r.stdout


@pytest.mark.slow
def test_backups_taken_while_an_ingest_runs_are_consistent(card, tmp_path):
    """Backups taken over and over while another process ingests a drive: each is the catalogue
    before that drive's commit or after it, never in between."""
    root = card["root"]
    before = _core_rows(root)
    args = ["dashcam", "ingest", root, card["dir"] / "whole.mp4", "--gps", card["gps"], "--preset", "archive"]
    proc = subprocess.Popen([sys.executable, "-m", "egovid", *map(str, args)], stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    states = []
    try:
        deadline = time.monotonic() + 600
        k = 0
        while proc.poll() is None:
            assert time.monotonic() < deadline, "the ingest did not end in 10 minutes"
            k += 1
            b = tmp_path / f"b{k}.sqlite"
            r = run_cli("dashcam", "backup", root, b)
            assert r.returncode == 0, r.stderr
            db = sqlite3.connect(str(b))
            assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
            db.close()
            states.append(_rows_of(b))
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=60)
    assert proc.returncode == 0
    after = _core_rows(root)
    assert after != before and states
    assert all(s in (before, after) for s in states)


@pytest.mark.slow
def test_append_and_skip_on_a_postgresql_catalogue(card, pg_url, tmp_path):
    """The same sync on a PostgreSQL catalogue (the real server): a card, the same card again,
    then the loop file that continues its trip."""
    root, files = tmp_path / "pg", card["files"]
    assert run_cli("dashcam", "init", root, "--db", pg_url).returncode == 0
    r = run_cli("dashcam", "ingest", root, card["card1"], "--gps", card["gps"], "--codec", "vp9")
    assert r.returncode == 0, r.stdout + r.stderr
    r = run_cli("dashcam", "ingest", root, card["card1"], "--gps", card["gps"])
    assert r.returncode == 0 and "2 file(s) already archived" in r.stdout, r.stdout + r.stderr
    later = tmp_path / "card2"
    later.mkdir()
    shutil.copy(files[2], later / files[2].name)
    r = run_cli("dashcam", "ingest", root, later, "--gps", card["gps"], "--codec", "vp9")
    assert r.returncode == 0 and "appended to drive" in r.stdout, r.stdout + r.stderr
    r = run_cli("dashcam", "check", root)
    assert r.returncode == 0, r.stdout + r.stderr
    out = tmp_path / "trip.mkv"
    assert run_cli("dashcam", "extract", root, files[0].stem, "-o", out).returncode == 0
    assert sum(1 for _ in iter_frames(out)) == card["n"]
