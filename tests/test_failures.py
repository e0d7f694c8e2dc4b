"""Faults and the one error path: read-only folders, a full disk, signals mid-write, truncated
videos, internal errors, and the mapping of OS and database errors to one ``error:`` line."""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from egovid.core.errors import EgovidError, user_error
from egovid.core.files import atomic_write_text, output_transaction
from egovid.core.video import count_frames, iter_frames, probe
from egovid.synth.fpv import render_fpv

from conftest import (
    assert_interrupted,
    assert_one_error,
    cli_env,
    invoke_cli,
    partial_output_in,
    run_cli,
    wait_until_running,
)


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("failclip") / "clip.mp4"
    n = 30
    render_fpv(p, np.c_[np.linspace(0, 6, n), np.zeros(n), np.zeros(n)], width=160, height=120, noise_std=2.0)
    return p


@contextlib.contextmanager
def _tmpfs(size: str) -> Path:
    """A small tmpfs, mounted for the block (root only)."""
    if os.geteuid() != 0:
        pytest.skip("a tmpfs needs root (the tests run as root in CI); not root here")
    d = Path(tempfile.mkdtemp(prefix="egovid-tmpfs-"))
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(d)], capture_output=True, text=True)
    if r.returncode != 0:
        d.rmdir()
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip()})")
    try:
        yield d
    finally:
        subprocess.run(["umount", "-l", str(d)], check=False)
        d.rmdir()


@pytest.fixture
def read_only_dir():
    """A folder nobody can write to: a read-only tmpfs as root, a mode 555 folder otherwise."""
    if os.geteuid() == 0:
        with _tmpfs("1m") as d:
            (d / "existing.csv").write_text("keep me\n")
            subprocess.run(["mount", "-o", "remount,ro", str(d)], check=True)
            yield d
    else:
        with tempfile.TemporaryDirectory() as t:
            d = Path(t) / "ro"
            d.mkdir()
            (d / "existing.csv").write_text("keep me\n")
            d.chmod(0o555)
            yield d
            d.chmod(0o755)


@pytest.fixture
def full_dir():
    """A tmpfs with no space left at all."""
    with _tmpfs("256k") as d:
        with contextlib.suppress(OSError), open(d / "filler", "wb", buffering=0) as fh:
            while True:
                fh.write(b"\0" * 4096)
        yield d


def _invoke(args, capsys) -> tuple[int, str]:
    r = invoke_cli(args, capsys)
    return r.returncode, r.stderr


def _assert_error(code: int, err: str, needle: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert needle in lines[0], lines[0]


def _ro_cases(clip: Path, d: Path) -> list[list]:
    return [
        ["fpv", "motion", clip, "-o", d / "m.csv"],
        ["fpv", "motion", clip, "-o", d / "existing.csv"],
        ["fpv", "score", clip, "--json", d / "s.json"],
        ["fpv", "stabilize", clip, "-o", d / "o.mp4"],
        ["synth", "fpv", d / "o.mp4", "--frames", "5", "--size", "64x48"],
        ["synth", "drive", d / "o.mp4"],
        ["voeval", "run", "--out", d / "run"],
        ["dashcam", "init", d / "arc"],
        ["demo", "--out", d / "demo"],
    ]


def test_read_only_folder(clip, read_only_dir, capsys):
    before = _listing(read_only_dir)
    for args in _ro_cases(clip, read_only_dir):
        code, err = _invoke(args, capsys)
        _assert_error(code, err, "read-only" if os.geteuid() == 0 else "not writable")
    assert _listing(read_only_dir) == before
    assert (read_only_dir / "existing.csv").read_text() == "keep me\n"


def test_full_disk_is_refused_before_any_work(clip, full_dir, capsys):
    before = _listing(full_dir)
    for args in _ro_cases(clip, full_dir):
        code, err = _invoke(args, capsys)
        _assert_error(code, err, "no space left")
    assert _listing(full_dir) == before


def test_disk_filling_up_mid_write_leaves_nothing(capsys):
    """Enough space to start, not to finish: the video fails while being written; its temporary
    file and the outputs already written are gone, and the line names the file the user asked for."""
    with _tmpfs("200k") as d:
        code, err = _invoke(["synth", "fpv", d / "o.mp4", "--size", "320x240", "--frames", "90"], capsys)
        _assert_error(code, err, "no space left")
        assert str(d / "o.mp4") in err
        assert _listing(d) == []


def test_output_transaction_restores_what_it_replaced(tmp_path):
    (tmp_path / "old.csv").write_text("old\n")
    with pytest.raises(RuntimeError), output_transaction():
        atomic_write_text(tmp_path / "new.csv", "new\n")
        atomic_write_text(tmp_path / "old.csv", "replaced\n")
        assert (tmp_path / "old.csv").read_text() == "replaced\n"  # in place while the command runs
        raise RuntimeError("a later step fails")
    assert _listing(tmp_path) == ["old.csv"]
    assert (tmp_path / "old.csv").read_text() == "old\n"
    with output_transaction():
        atomic_write_text(tmp_path / "old.csv", "kept\n")
    assert _listing(tmp_path) == ["old.csv"] and (tmp_path / "old.csv").read_text() == "kept\n"


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)], ids=["SIGTERM", "SIGINT"])
def test_signal_mid_write_removes_partial_output(tmp_path, sig, code):
    proc = subprocess.Popen(
        [sys.executable, "-m", "egovid", "synth", "fpv", "o.mp4", "--frames", "20000", "--size", "320x240"],
        cwd=tmp_path,
        env=cli_env(),
        stdout=subprocess.DEVNULL,  # nobody reads it before the stop: a full pipe would block the command
        stderr=subprocess.PIPE,
        text=True,
    )
    wait_until_running(proc, partial_output_in(tmp_path), "it started writing its output")
    time.sleep(0.3)  # some frames into the file
    assert_interrupted(proc, sig, code)
    assert _listing(tmp_path) == []


def test_version_needs_no_command():
    r = run_cli("--version")
    assert r.returncode == 0 and r.stdout.startswith("egovid "), r.stderr


def test_internal_error_keeps_exit_1_and_asks_for_a_report(monkeypatch, capsys):
    def boom(*a, **k):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr("egovid.cli.synth.outputs", boom)
    code, err = _invoke(["synth", "fpv", "o.mp4"], capsys)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 1 and len(lines) == 1 and lines[0].startswith("internal error: ZeroDivisionError"), err
    assert "report" in lines[0]


def test_os_and_database_errors_become_one_clear_error(tmp_path):
    cases = [
        (OSError(errno.ENOSPC, "No space left on device", str(tmp_path / ".o.part-12.mp4")), "no space left"),
        (OSError(errno.EROFS, "Read-only file system", "/mnt/x.csv"), "read-only"),
        (PermissionError(errno.EACCES, "Permission denied", "/root/x"), "permission denied"),
        (FileNotFoundError(errno.ENOENT, "No such file", "gone.mp4"), "does not exist"),
    ]
    for exc, needle in cases:
        found = user_error(exc)
        assert found is not None and needle in found.one_line(), (exc, found)
    assert ".part-" not in user_error(cases[0][0]).one_line() and "o.mp4" in user_error(cases[0][0]).one_line()
    assert user_error(ValueError("a bug")) is None
    assert user_error(OSError(errno.EBADF, "Bad file descriptor")) is None  # a bug, not the user's

    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database" * 100)
    with pytest.raises(sqlite3.DatabaseError) as info:
        sqlite3.connect(junk).execute("select * from sqlite_master").fetchall()
    assert "repair" in user_error(info.value).one_line()
    good = tmp_path / "good.sqlite"
    sqlite3.connect(good).execute("create table t(x)").connection.commit()
    with pytest.raises(sqlite3.OperationalError) as info:
        con = sqlite3.connect(f"file:{good}?mode=ro", uri=True)
        con.execute("insert into t values (1)")
    assert "read-only" in user_error(info.value).one_line()
    wrapped = RuntimeError("task failed")
    wrapped.__cause__ = OSError(errno.ENOSPC, "No space left on device")
    assert "no space left" in user_error(wrapped).one_line()


# -- truncated videos ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cut_videos(clip, tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("cut")
    out = {}
    for name, args in {"mp4": ["-c", "copy", "-movflags", "+faststart"], "mkv": ["-c:v", "ffv1"]}.items():
        whole = d / f"whole.{name}"
        subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", clip, *args, whole], check=True)
        data = whole.read_bytes()
        cut = d / f"cut.{name}"
        cut.write_bytes(data[: len(data) // 2])
        out[name], out[f"cut-{name}"] = whole, cut
    return out


@pytest.mark.parametrize("kind", ["mp4", "mkv"])
def test_truncated_video_is_reported_with_its_real_frame_count(cut_videos, kind):
    whole, cut = cut_videos[kind], cut_videos[f"cut-{kind}"]
    assert not probe(whole).truncated and probe(whole).frame_count == 30
    with pytest.raises(EgovidError, match=r"truncated: it holds (\d+) frames .* of the") as info:
        probe(cut)
    held = int(info.value.problem.split("holds ")[1].split()[0])
    assert 5 < held < 30
    assert "--allow-truncated" in info.value.one_line()
    info = probe(cut, allow_truncated=True)
    assert info.truncated and info.frame_count == held
    assert sum(1 for _ in iter_frames(cut, gray=True)) == held == count_frames(cut)


def test_allow_truncated_processes_what_is_there(cut_videos, tmp_path):
    r = run_cli("fpv", "motion", cut_videos["cut-mp4"], "-o", tmp_path / "m.csv")
    assert_one_error(r, "truncated")
    assert _listing(tmp_path) == []
    r = run_cli("fpv", "motion", cut_videos["cut-mp4"], "-o", tmp_path / "m.csv", "--allow-truncated")
    assert r.returncode == 0, r.stderr
    held = probe(cut_videos["cut-mp4"], allow_truncated=True).frame_count
    assert len((tmp_path / "m.csv").read_text().splitlines()) == held + 1


@pytest.mark.parametrize("fixture", ["karma_clip", "handheld_clip"])
def test_real_camera_files_are_not_flagged_truncated(fixture, request):
    info = probe(request.getfixturevalue(fixture))
    assert not info.truncated and info.frame_count > 100
