"""What a car records beside its video (a Tesla's per-frame SEI: speed, acceleration, steering …)
is kept by the archive per drive, written out as CSV by `extract --readings`, summarised and drawn
by `report`, preferred by the web app's map marker, dropped by `forget`, carried by backup/restore;
archives without readings (every older one) are read as they are.

The truth is what synth.tesla wrote into each frame's SEI (drive_samples, recomputed here)."""

from __future__ import annotations

import datetime as dt
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from egovid.core.camera.tesla import CHANNELS
from egovid.dashcam.archive import readings as table
from egovid.dashcam.archive.readings import DriveReadings, decode, encode, join, summarise
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.readings import read_csv, write_csv
from egovid.synth.tesla import drive_samples, write_tesla_clip

from conftest import assert_one_error, invoke_cli, run_cli

FPS, SECONDS, N = 36.0, 2.0, 72
START = dt.datetime(2025, 11, 20, 14, 3, 12)
OLD = Path(__file__).parent / "data" / "archive-vp9-v1"


def _clip(folder: Path, k: int) -> Path:
    """The k-th front clip of a TeslaCam folder (2 s each, back to back; the first starts
    without a GPS fix for 3 frames)."""
    stamp = (START + dt.timedelta(seconds=SECONDS * k)).strftime("%Y-%m-%d_%H-%M-%S")
    path = folder / "TeslaCam" / "RecentClips" / f"{stamp}-front.mp4"
    path.parent.mkdir(parents=True, exist_ok=True)
    no_fix = 3 if k == 0 else 0
    write_tesla_clip(path, seconds=SECONDS, fps=FPS, size=(320, 240), start_seq=1000 + 1000 * k, no_fix=no_fix)
    return path


def _truth(clips: int) -> DriveReadings:
    """What the first ``clips`` clips hold, as the archive should keep it: each clip's samples
    placed 2 s after the one before (drive clock and UTC), a position absent (NaN) before a fix."""
    parts = []
    for k in range(clips):
        s = drive_samples(N, FPS, start_seq=1000 + 1000 * k, no_fix=3 if k == 0 else 0)
        ch = {name: s.channels[name].copy() for name in CHANNELS}
        nofix = (ch["lat"] == 0) & (ch["lon"] == 0)
        ch["lat"][nofix] = ch["lon"][nofix] = np.nan
        utc0 = START.replace(tzinfo=dt.UTC).timestamp() + SECONDS * k
        parts.append(DriveReadings(SECONDS * k + s.video_t, utc0 + s.video_t, ch))
    out = parts[0]
    for p in parts[1:]:
        out = join(out, p)
    return out


def _assert_same_values(got: DriveReadings, want: DriveReadings) -> None:
    assert list(got.channels) == list(CHANNELS)
    for name in CHANNELS:  # exactly the values written into the SEI, NaN where a message had none
        np.testing.assert_array_equal(got.channels[name], want.channels[name], err_msg=name)
    np.testing.assert_allclose(got.t, want.t, atol=1e-6)
    np.testing.assert_allclose(got.utc, want.utc, rtol=0, atol=1e-3)  # rtol 0: UTC is ~1.7e9 s


@pytest.fixture(scope="module")
def tesla_archive(tmp_path_factory) -> dict:
    """An archive of a TeslaCam folder: two clips ingested as one drive, a third appended by a
    later ingest of the same folder (the first two are known by content)."""
    base = tmp_path_factory.mktemp("tesla")
    root = base / "archive"
    assert run_cli("dashcam", "init", root).returncode == 0
    for k in range(2):
        _clip(base, k)
    r = run_cli("dashcam", "ingest", root, base / "TeslaCam", "--tz-offset", "0")
    assert r.returncode == 0, r.stderr
    ar = Archive(root)
    try:
        (first,) = ar.catalogue.drives()
        two = table.get(ar.catalogue, first.id)
    finally:
        ar.close()
    _clip(base, 2)
    r = run_cli("dashcam", "ingest", root, base / "TeslaCam", "--tz-offset", "0")
    assert r.returncode == 0, r.stderr
    return {"root": root, "name": first.name, "id": first.id, "two": two}


def test_readings_encode_join_and_summary_by_hand():
    t = np.array([0.0, 0.5, 1.0])
    a = DriveReadings(t, 1e9 + t, {"speed_mps": np.array([3.0, 7.5, 5.0]), "accel_x": np.array([1.0, -4.0, 2.0]),
                                   "accel_y": np.array([3.0, 0.0, np.nan])}, "Tesla SEI")  # fmt: skip
    names, data = encode(a)
    back = decode(3, names, data, "Tesla SEI")
    for k in a.channels:
        np.testing.assert_array_equal(back.channels[k], a.channels[k])
    np.testing.assert_array_equal(back.utc, a.utc)
    s = summarise(a)
    assert s["max_speed_mps"] == 7.5 and s["samples"] == 3 and s["seconds"] == 1.0
    assert s["max_abs_accel_mps2"] == {"x": 4.0, "y": 3.0, "z": None}
    assert s["max_horizontal_accel_mps2"] == 4.0 and s["max_abs_steering_deg"] is None
    # An appended file: its samples after the drive's, a channel only one has is NaN in the other.
    b = DriveReadings(np.array([1.0, 1.5]), 1e9 + np.array([1.0, 1.5]), {"speed_mps": np.array([9.0, 9.5]),
                                                                           "brake": np.array([1.0, 0.0])})  # fmt: skip
    j = join(a, b)
    np.testing.assert_array_equal(j.t, [0.0, 0.5, 1.0, 1.5])  # 1.0 was the drive's already
    np.testing.assert_array_equal(j.channels["speed_mps"], [3.0, 7.5, 5.0, 9.5])
    np.testing.assert_array_equal(j.channels["brake"], [np.nan, np.nan, np.nan, 0.0])
    np.testing.assert_array_equal(j.channels["accel_x"], [1.0, -4.0, 2.0, np.nan])


def test_csv_reads_back_the_same_floats(tmp_path):
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.01, 0.05, 50))
    ch = {"speed_mps": np.float32(rng.uniform(0, 40, 50)).astype(float), "lat": rng.uniform(-90, 90, 50),
          "gear": rng.integers(0, 4, 50).astype(float)}  # fmt: skip
    ch["lat"][3] = np.nan
    r = DriveReadings(t, 1.7e9 + np.round(t, 3), ch)
    back = read_csv(write_csv(r, tmp_path / "r.csv"))
    for k in ch:
        np.testing.assert_array_equal(back.channels[k], ch[k])
    np.testing.assert_array_equal(back.t, t)
    np.testing.assert_allclose(back.utc, r.utc, rtol=0, atol=5e-4)  # ISO 8601 to the millisecond


def test_tesla_drive_keeps_its_readings_exactly(tesla_archive):
    """Ingest keeps every decoded channel, exactly as written; the third clip's readings follow
    the first two's on the drive's clock after the append."""
    _assert_same_values(tesla_archive["two"], _truth(2))
    ar = Archive(tesla_archive["root"])
    try:
        (d,) = ar.catalogue.drives()
        assert d.frames == 3 * N and len(d.name) and d.id == tesla_archive["id"]
        got = table.get(ar.catalogue, d.id)
    finally:
        ar.close()
    assert got.source == "Tesla SEI"
    _assert_same_values(got, _truth(3))


def test_extract_writes_the_readings_as_csv(tesla_archive, tmp_path, capsys):
    # The refusals end in validation, so in this process (see invoke_cli).
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    root, name = tesla_archive["root"], tesla_archive["name"]
    out = tmp_path / "all.csv"
    r = run_cli("dashcam", "extract", root, name, "--readings", out)  # readings only: no video decoded
    assert r.returncode == 0, r.stderr
    assert out.read_text().splitlines()[0].split(",")[:3] == ["t_s", "utc", "version"]
    _assert_same_values(read_csv(out), _truth(3))
    # A stretch: the samples of [1 s, 3 s) of the drive, beside its video.
    part, video = tmp_path / "part.csv", tmp_path / "part.mkv"
    r = run_cli("dashcam", "extract", root, name, "--start", "1", "--duration", "2", "-o", video, "--readings", part)
    assert r.returncode == 0, r.stderr
    assert video.stat().st_size > 0
    _assert_same_values(read_csv(part), _truth(3).between(1.0 - 1e-9, 3.0 - 1e-9))
    assert_one_error(cli("dashcam", "extract", root, name), "nothing to write")
    assert_one_error(cli("dashcam", "extract", root, name, "--readings", tmp_path / "x.txt"), ".csv")


def test_report_summarises_and_draws_the_readings(tesla_archive, tmp_path):
    figs, rep = tmp_path / "figures", tmp_path / "report.json"
    r = run_cli("dashcam", "report", tesla_archive["root"], "--json", rep, "--figures", figs)
    assert r.returncode == 0, r.stderr
    (drive,) = json.loads(rep.read_text())["drives"]
    s = drive["readings"]
    truth = _truth(3).channels
    # The maxima by hand, from what was written into the SEI.
    assert s["max_speed_mps"] == max(truth["speed_mps"]) and s["samples"] == 3 * N
    assert s["max_abs_accel_mps2"] == {"x": 0.5, "y": max(truth["accel_y"]), "z": 9.81}
    assert s["max_horizontal_accel_mps2"] == max(np.hypot(truth["accel_x"], truth["accel_y"]))
    assert s["max_abs_steering_deg"] == max(abs(truth["steering_deg"]))
    assert "max speed 46.7 km/h" in r.stdout
    fig = Path(s["figure"])
    assert fig.parent == figs and fig.name == f"{tesla_archive['name']}-readings.png"
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image

    img = matplotlib.image.imread(fig)
    assert img.shape[0] > 400 and img.shape[1] > 600 and img[..., :3].std() > 0.05  # drawn, not blank


def test_map_marker_prefers_the_recorded_speed(tesla_archive):
    from egovid.serve.archive_ops import ArchiveOps

    ops = ArchiveOps(tesla_archive["root"])
    try:
        tr = ops.track(tesla_archive["id"])
    finally:
        ops.close()
    assert tr["speed_source"] == "recorded (Tesla SEI)"
    truth = _truth(3)
    t = np.array(tr["t"])
    np.testing.assert_allclose(tr["speed"], np.interp(t, truth.t, truth.channels["speed_mps"]), atol=0.006)
    np.testing.assert_allclose(tr["accel"], 0.5)


def test_forget_drops_and_backup_carries_the_readings(tesla_archive, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(tesla_archive["root"], root)
    backup = tmp_path / "cat.sqlite"
    assert run_cli("dashcam", "backup", root, backup).returncode == 0
    new = tmp_path / "restored"
    assert run_cli("dashcam", "init", new).returncode == 0
    r = run_cli("dashcam", "restore", backup, new)
    assert r.returncode == 0, r.stderr
    ar = Archive(new)
    try:
        _assert_same_values(table.get(ar.catalogue, tesla_archive["id"]), _truth(3))
    finally:
        ar.close()
    r = run_cli("dashcam", "forget", root, tesla_archive["name"], "--no-verify")
    assert r.returncode == 0, r.stderr
    ar = Archive(root)
    try:
        assert table.summaries(ar.catalogue) == {} and not ar.catalogue.dangling_rows()
    finally:
        ar.close()


def test_an_archive_without_readings_is_read_as_it_is(tmp_path, capsys):
    # The refusals end in validation, so in this process (see invoke_cli).
    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    """tests/data/archive-vp9-v1 (made before readings existed): report and extract work, say
    nothing of readings, and write nothing to its catalogue."""
    root = tmp_path / "old"
    shutil.copytree(OLD, root, ignore=shutil.ignore_patterns("expected.json"))
    before = (root / "catalogue.sqlite").read_bytes()
    rep = tmp_path / "rep.json"
    r = run_cli("dashcam", "report", root, "--json", rep, "--figures", tmp_path / "figs")
    assert r.returncode == 0, r.stderr
    assert [d["readings"] for d in json.loads(rep.read_text())["drives"]] == [None, None]
    assert "no drive has recorded readings" in r.stdout and not (tmp_path / "figs").exists()
    assert_one_error(cli("dashcam", "extract", root, "a", "--readings", tmp_path / "a.csv"), "no recorded readings")
    assert (root / "catalogue.sqlite").read_bytes() == before
    ar = Archive(root)
    try:
        assert not table.has_table(ar.catalogue) and table.get(ar.catalogue, 1) is None
    finally:
        ar.close()
