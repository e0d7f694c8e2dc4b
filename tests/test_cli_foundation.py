"""The CLI as a user runs it: outputs exist and are readable; bad input gives one clear line."""

import re
import subprocess
import sys

import av
import numpy as np
import pytest

from egovid.core.trajectory import read_motion_csv, read_tum
from egovid.core.video import VideoWriter

from conftest import cli_env, run_cli


def test_synth_then_motion_with_plot(tmp_path):
    v = tmp_path / "clip.mp4"
    r = run_cli("synth", "fpv", v, "--frames", "30", "--size", "320x180")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "clip.gt.csv").exists() and (tmp_path / "clip.gt.tum").exists()
    r = run_cli("fpv", "motion", v, "-o", tmp_path / "m.csv", "--plot", tmp_path / "m.png")
    assert r.returncode == 0, r.stderr
    m = read_motion_csv(tmp_path / "m.csv")
    assert len(m) == 30
    assert len(read_tum(tmp_path / "m.tum")) == 30
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"


def _one_frame(path):
    with VideoWriter(path, 64, 48, 30) as w:
        w.write(np.zeros((48, 64, 3), np.uint8))


def _no_frames(path):
    c = av.open(str(path), "w")
    s = c.add_stream("libx264", rate=30)
    s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
    c.start_encoding()
    c.close()


def test_motion_of_one_frame_is_one_identity_row(tmp_path):
    v = tmp_path / "in.mp4"
    _one_frame(v)
    r = run_cli("fpv", "motion", v, "-o", tmp_path / "m.csv")
    assert r.returncode == 0, r.stderr
    m = read_motion_csv(tmp_path / "m.csv")
    assert len(m) == 1 and np.allclose(m.euler(), 0.0)


@pytest.mark.parametrize(
    "make,extra,needle",
    [
        (None, (), "not found"),
        (lambda p: p.write_text("hello\n" * 50), (), "not a readable video"),
        (lambda p: p.write_bytes(b""), (), "empty"),
        (_no_frames, (), "no video stream|no frames"),
        (_one_frame, ("--focal", "1"), "absurd"),
        (_one_frame, ("--hfov", "200"), "out of range"),
    ],
)
def test_motion_bad_input_is_one_line_and_nonzero(tmp_path, make, extra, needle):
    v = tmp_path / "in.mp4"
    if make is not None:
        make(v)
    r = run_cli("fpv", "motion", v, "-o", tmp_path / "m.csv", *extra)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and re.search(needle, lines[0]), r.stderr
    assert not (tmp_path / "m.csv").exists()


def test_ingest_leaves_its_coding_defaults_to_the_library_and_its_help_shows_the_library_s(monkeypatch):
    """``--q``, ``--gop`` and ``--random-access`` default to None (IngestOptions fills them in from
    ARCHIVE_DEFAULTS, their one copy); ``ingest --help`` shows those values, whatever they are,
    and still does not load OpenCV or the rest of the library to show them."""
    from click.testing import CliRunner

    from egovid.cli import command
    from egovid.dashcam.codec import settings
    from egovid.dashcam.ingest.options import IngestOptions

    ingest = command().commands["dashcam"].commands["ingest"]
    params = {p.name: p for p in ingest.params}
    assert [params[n].default for n in ("q", "gop", "random_access")] == [None] * 3
    assert IngestOptions.from_preset(None, q=None, gop=None, refresh=None) == IngestOptions()
    d = IngestOptions()
    assert {"q": d.q, "gop": d.gop, "refresh": d.refresh} == settings.ARCHIVE_DEFAULTS

    def shown() -> dict[str, str]:
        out = CliRunner().invoke(command(), ["dashcam", "ingest", "--help"], env={"COLUMNS": "200"}).output
        found = {}
        for name in ("--q", "--gop", "--random-access"):
            after = out[out.index(f"│ {name} ") :]
            found[name] = re.search(r"\[default: (\S+)\]", after).group(1)
        return found

    assert shown() == {"--q": str(d.q), "--gop": str(d.gop), "--random-access": str(d.refresh)}
    monkeypatch.setattr(settings, "ARCHIVE_DEFAULTS", {"q": 41, "gop": 5, "refresh": 17})
    assert shown() == {"--q": "41", "--gop": "5", "--random-access": "17"}
    assert all(params[n].default is None for n in ("q", "gop", "random_access"))  # the help changed nothing
    probe = (
        "import contextlib, io, sys\n"
        "from egovid.cli import run\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    run(['dashcam', 'ingest', '--help'])\n"
        "print(sorted(m for m in ('cv2', 'numpy', 'scipy', 'av') if m in sys.modules))\n"
    )
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=cli_env(), timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "[]", (r.stdout, r.stderr)
