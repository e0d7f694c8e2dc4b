"""The dashcam archive end to end, as a user runs it: three drives around a junction, joint
compression, path splitting, bit-exact extraction in a fresh process, crash safety and bad input."""

import itertools
import json
import signal
import sqlite3
import subprocess
import sys

import numpy as np
import pytest

from egovid.core.video import iter_frames
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.codec import segment as codec
from egovid.dashcam.extract import extract_video
from egovid.dashcam.ingest import IngestOptions, ingest_videos
from egovid.synth.drive import DriveSpec, Light, render_drive

from conftest import _wait_for, assert_one_error, invoke_cli, run_cli

W, H = 320, 180


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """a, b: the same stretch of the main road (b slower, with a stop); c: turns off onto the side
    street half-way; all at noon; a GPS log as GPX, NMEA and CSV respectively."""
    d = tmp_path_factory.mktemp("drives")
    noon = Light.preset("noon")
    specs = {
        "a": (DriveSpec(legs=[("main", 380.0, 480.0)], cruise=11.0, seed=1, light=noon), "gpx"),
        "b": (DriveSpec(legs=[("main", 380.0, 480.0)], cruise=9.0, stops=[(40.0, 1.5)], seed=2, light=noon), "nmea"),
        "c": (DriveSpec(legs=[("main", 380.0, 445.0), ("side", 5.0, 60.0)], cruise=10.0, seed=3, light=noon), "csv"),
    }
    out = {}
    for name, (spec, fmt) in specs.items():
        video, gps, truth = render_drive(spec, d / f"{name}.mp4", width=W, height=H, gps_format=fmt)
        out[name] = (video, gps, truth)
    return out


@pytest.fixture(scope="module")
def archive(drives, tmp_path_factory):
    root = tmp_path_factory.mktemp("arch") / "archive"
    r = run_cli("dashcam", "init", root)
    assert r.returncode == 0, r.stderr
    reports = {}
    for name in ("a", "b", "c"):
        video, gps, _ = drives[name]
        # b's saving is asserted: its joint piece's standalone encode runs to the end. (a has no
        # joint piece; c's may stop its losing encode early, as a user's ingest does.)
        savings = ["--measure-savings"] if name == "b" else []
        r = run_cli(
            "dashcam",
            "ingest",
            root,
            video,
            "--gps",
            gps,
            "--codec",
            "vp9",
            *savings,
            "--json",
            root.parent / f"{name}.json",
        )
        assert r.returncode == 0, r.stderr
        reports[name] = json.loads((root.parent / f"{name}.json").read_text())
    return root, reports


def test_first_drive_is_a_root_and_later_ones_are_joint(archive):
    _, rep = archive
    assert [p["mode"] for p in rep["a"]["pieces"]] == ["intra"]
    assert rep["a"]["new_paths"] == [1]
    b = rep["b"]["pieces"]
    assert [p["mode"] for p in b] == ["joint"] and b[0]["ref_drive"] == "a"
    assert b[0]["stopped_frames"] > 20  # the 1.5 s stop
    assert b[0]["saving"] > 0.0  # smaller than standalone at the same quantiser


def test_drive_leaving_the_path_splits_it(archive):
    root, rep = archive
    c = rep["c"]
    assert c["split_paths"] == [1]
    modes = [(p["mode"], p["ref_drive"]) for p in c["pieces"]]
    assert modes[0][0] == "joint" and modes[0][1] in ("a", "b")
    assert modes[-1] == ("intra", None)  # the side street is new
    ar = Archive(root)
    paths = {p.id for p in ar.catalogue.paths()}
    assert len(paths) >= 3
    # Drive a now lies on two paths (before and after the junction), its frames intact.
    seq_a = ar.catalogue.sequences(drive_id=1)
    assert len({s.path_id for s in seq_a}) == 2
    assert seq_a[0].frame_start == 0 and seq_a[-1].frame_end == ar.catalogue.drive("a").frames
    assert all(x.frame_end == y.frame_start for x, y in itertools.pairwise(seq_a))


def test_extract_in_a_fresh_process_is_bit_exact(archive, drives, tmp_path):
    root, _ = archive
    out = tmp_path / "b.mkv"
    r = run_cli("dashcam", "extract", root, "b", "-o", out)
    assert r.returncode == 0, r.stderr
    ar = Archive(root)
    segs = ar.catalogue.segments(ar.catalogue.drive("b").id)
    frames = [f.image for f in iter_frames(out, i420=True)]
    assert len(frames) == ar.catalogue.drive("b").frames
    import hashlib

    for seg in segs:  # the extracted pictures are the encoder's reconstruction, bit for bit
        h = hashlib.sha256()
        for f in frames[seg.frame_start : seg.frame_end]:
            codec.digest_update(h, f)
        assert h.hexdigest() == seg.params["recon_digest"]
    # A stretch from the middle (--start/--duration) decodes from the nearest random-access point
    # in b and in a, and gives the same pictures.
    fps = ar.catalogue.drive("b").fps
    part = tmp_path / "b-part.mp4"
    r = run_cli("dashcam", "extract", root, "b", "-o", part, "--start", 2.0, "--duration", 1.0)
    assert r.returncode == 0, r.stderr
    f0 = round(2.0 * fps)
    got = [f.image for f in iter_frames(part, i420=True)]
    assert len(got) == round(fps) and all(np.array_equal(a, b) for a, b in zip(got, frames[f0:], strict=False))
    # Each run of a partial extract is checked against its own digest: a wrong digest for the run
    # holding frame 60 (in a copy of the archive) fails the stretch that needs it, not the others.
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    cp = Archive(copy)
    seg = next(g for g in segs if g.frame_start <= 60 < g.frame_end)
    k = (60 - seg.frame_start) // seg.params["refresh"]
    assert len(seg.params["run_digests"]) == -(-(seg.frame_end - seg.frame_start) // seg.params["refresh"])
    seg.params["run_digests"][k] = "0" * codec.RUN_DIGEST_CHARS
    cp.catalogue._q("UPDATE segments SET params = ? WHERE id = ?", (json.dumps(seg.params), seg.id))
    r = run_cli("dashcam", "extract", copy, "b", "-o", tmp_path / "bad.mp4", "--start", 60 / fps, "--duration", 0.1)
    assert_one_error(r, "do not decode to what was encoded")
    assert not (tmp_path / "bad.mp4").exists()
    r = run_cli("dashcam", "extract", copy, "b", "-o", tmp_path / "ok.mp4", "--start", 0, "--duration", 1.0)
    assert r.returncode == 0, r.stderr
    r = run_cli("dashcam", "extract", root, "b", "-o", tmp_path / "late.mkv", "--start", 1e4)
    assert_one_error(r, "past the end")
    assert not (tmp_path / "late.mkv").exists()
    # ... and close to the source drive.
    src = [f.image for f in iter_frames(drives["b"][0], i420=True)]
    mse = np.mean([np.mean((a[:H].astype(float) - b[:H]) ** 2) for a, b in zip(frames, src, strict=True)])
    assert 10 * np.log10(255**2 / mse) > 30.0


def test_list_show_report(archive, capsys):
    # Reading commands, in this process (a process start is not what is tested here).
    root, _ = archive
    r = invoke_cli(["dashcam", "list", root], capsys)
    assert r.returncode == 0 and "joint" in r.stdout and "intra" in r.stdout
    r = invoke_cli(["dashcam", "show", root, "c"], capsys)
    assert r.returncode == 0 and "segment" in r.stdout
    r = invoke_cli(["dashcam", "report", root, "--json", root.parent / "rep.json"], capsys)
    assert r.returncode == 0, r.stderr
    rep = json.loads((root.parent / "rep.json").read_text())
    assert {d["drive"] for d in rep["drives"]} == {"a", "b", "c"}
    assert sum(p["frames"] for p in rep["paths"]) == sum(d["frames"] for d in rep["drives"])


def _state(root):
    """Row counts of the catalogue's tables, read with the database's own client (not egovid's)."""
    cat = json.loads((root / "egovid-archive.json").read_text()).get("catalogue", {})
    tables = ("drives", "paths", "sequences", "segments")
    if cat.get("backend") == "postgresql":
        import psycopg

        with psycopg.connect(cat["url"]) as db:
            return [db.execute(f'SELECT count(*) FROM "{cat["schema"]}".{t}').fetchone()[0] for t in tables]
    db = sqlite3.connect(str(root / "catalogue.sqlite"))
    try:
        return [db.execute(f"SELECT count(*) FROM {t}").fetchone()[0] for t in tables]
    finally:
        db.close()


def test_bad_input_changes_nothing(archive, drives, tmp_path, capsys):
    # Each command ends in validation (or a no-op), so in this process (see invoke_cli).
    root, _ = archive
    before = _state(root)
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    video_a, gps_a, _ = drives["a"]
    # GPS of another time: the same track shifted by a day does not overlap the video.
    shifted = tmp_path / "late.csv"
    lines = drives["c"][1].read_text().splitlines()
    import datetime as dt

    out = [lines[0]]
    for ln in lines[1:]:
        t, rest = ln.split(",", 1)
        out.append((dt.datetime.fromisoformat(t) + dt.timedelta(days=1)).isoformat() + "," + rest)
    shifted.write_text("\n".join(out) + "\n")
    assert_one_error(cli("dashcam", "ingest", root, video_a, "--gps", shifted, "--name", "x"), "covers 0%")
    assert_one_error(cli("dashcam", "ingest", root, video_a, "--gps", video_a, "--name", "x"), "binary")
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(video_a.read_bytes()[:2000])
    assert_one_error(cli("dashcam", "ingest", root, broken, "--gps", gps_a, "--name", "x"), "")
    r = cli("dashcam", "ingest", root, video_a, "--gps", gps_a)  # the same file again: a no-op that says so
    assert r.returncode == 0 and "1 file(s) already archived" in r.stdout, r.stdout + r.stderr
    assert_one_error(cli("dashcam", "extract", root, "nobody", "-o", tmp_path / "x.mkv"), "no drive")
    assert_one_error(cli("dashcam", "ingest", tmp_path, video_a, "--gps", gps_a), "not an egovid archive")
    args = ("dashcam", "ingest", root, video_a, "--gps", gps_a, "--name", "x", "--random-access", 1)
    assert_one_error(cli(*args), "random-access period 1")
    assert _state(root) == before
    # A GPS log of NaNs into a new archive: refused, and the archive keeps no origin (it used to
    # record a NaN origin that broke every later ingest).
    fresh = tmp_path / "fresh"
    assert cli("dashcam", "init", fresh).returncode == 0
    nan = tmp_path / "nan.csv"
    nan.write_text("time,lat,lon\n" + "".join(f"{1777881600 + i},nan,nan\n" for i in range(30)))
    assert_one_error(cli("dashcam", "ingest", fresh, video_a, "--gps", nan), "0 valid GPS fix")
    assert Archive(fresh).origin is None and _state(fresh) == [0, 0, 0, 0]
    assert "nan" not in (fresh / "egovid-archive.json").read_text().lower()


def _kill_mid_ingest(root, video, gps) -> None:
    """Start an ingest in another process and kill -9 it once it has written a new bitstream (its
    first piece; the drive has a second piece still to encode, and nothing is committed before the
    last). The slowest preset keeps that second piece's encode long (seconds, against a 0.2 s
    poll), so the kill lands mid-encode also on a loaded machine. Fails loudly if the bitstream
    never comes or the ingest ends first."""
    blobs_before = {p.name for p in (root / "blobs").rglob("*") if p.is_file()}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "egovid",
            "dashcam",
            "ingest",
            *map(str, (root, video, "--gps", gps, "--name", "killed", "--preset", "archive")),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        new_blob = lambda: bool({p.name for p in (root / "blobs").rglob("*") if p.is_file()} - blobs_before)  # noqa: E731
        _wait_for(lambda: new_blob() or proc.poll() is not None, "the ingest to write its first bitstream", 600)
        assert proc.poll() is None, f"the ingest ended (status {proc.returncode}) before it could be killed"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()


def _collect_the_killed_ingests_blobs(root) -> None:
    """`gc` deletes the blobs the killed ingest left behind, and nothing a segment refers to."""
    files = lambda: {p for p in (root / "blobs").rglob("*") if p.is_file()}  # noqa: E731
    ar = Archive(root)
    used = {g.blob for d in ar.catalogue.drives() for g in ar.catalogue.segments(d.id)}
    orphans = {p for p in files() if p.name not in used}
    assert orphans  # the killed ingest had written at least one bitstream
    r = run_cli("dashcam", "gc", root, "--dry-run")
    assert r.returncode == 0 and f"would delete {len(orphans)} " in r.stdout and files() >= orphans
    r = run_cli("dashcam", "gc", root)
    assert r.returncode == 0 and f"deleted {len(orphans)} " in r.stdout, r.stderr
    assert {p.name for p in files()} == used


def test_kill_during_ingest_leaves_archive_consistent(archive, drives, tmp_path):
    root, _ = archive
    before = _state(root)
    video, gps, _ = drives["c"]
    _kill_mid_ingest(root, video, gps)
    assert _state(root) == before
    db = sqlite3.connect(str(root / "catalogue.sqlite"))
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    db.close()
    _collect_the_killed_ingests_blobs(root)
    # Earlier drives are still extractable.
    ar = Archive(root)
    extract_video(ar, ar.drive_or_fail("a"), tmp_path / "a.mkv")
    assert sum(1 for _ in iter_frames(tmp_path / "a.mkv")) == ar.catalogue.drive("a").frames
    # And the same drive can be ingested afterwards.
    opts = IngestOptions(measure_savings=False, codec="vp9")
    (rep,) = ingest_videos(ar, [video], gps=gps, options=opts, name="after-crash").reports
    assert rep.pieces[0].mode == "joint"


def test_postgresql_catalogue(archive, drives, pg_url, tmp_path, capsys):
    """The same archive with its catalogue in PostgreSQL: the same bitstreams as with SQLite,
    extract in a fresh process is bit-exact, a killed ingest changes nothing, a bad URL is refused
    before anything is created."""
    root = tmp_path / "pg-archive"
    r = run_cli("dashcam", "init", root, "--db", pg_url)
    assert r.returncode == 0 and "PostgreSQL" in r.stdout, r.stderr
    for name in ("a", "b"):
        video, gps, _ = drives[name]
        r = run_cli("dashcam", "ingest", root, video, "--gps", gps, "--codec", "vp9")
        assert r.returncode == 0, r.stderr
    assert _state(root) == [2, 1, 2, 2]
    # Drive b was coded against a alone in both archives: the catalogue changes no bit.
    pg, lite = Archive(root), Archive(archive[0])
    segs = pg.catalogue.segments(pg.catalogue.drive("b").id)
    assert [s.blob for s in segs] == [s.blob for s in lite.catalogue.segments(lite.catalogue.drive("b").id)]
    assert segs[0].mode == "joint"
    out = tmp_path / "b.mkv"
    r = run_cli("dashcam", "extract", root, "b", "-o", out)
    assert r.returncode == 0, r.stderr
    import hashlib

    h = hashlib.sha256()
    for f in iter_frames(out, i420=True):
        codec.digest_update(h, f.image)
    assert len(segs) == 1 and h.hexdigest() == segs[0].params["recon_digest"]
    # kill -9 in the middle of an ingest: the server rolls the transaction back.
    _kill_mid_ingest(root, *drives["c"][:2])
    assert _state(root) == [2, 1, 2, 2]
    _collect_the_killed_ingests_blobs(root)
    r = invoke_cli(["dashcam", "list", root], capsys)
    assert r.returncode == 0 and "killed" not in r.stdout
    # A server that is not there, or a database kind egovid does not know: one error, no folder.
    host = pg_url.split("host=")[1].split("&")[0]
    bad = pg_url.replace(host, str(tmp_path / "nowhere"))
    assert_one_error(invoke_cli(["dashcam", "init", tmp_path / "x", "--db", bad], capsys), "cannot connect")
    assert_one_error(invoke_cli(["dashcam", "init", tmp_path / "y", "--db", "mysql://db/x"], capsys), "not understood")
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
