"""`egovid fpv stabilize` stopped while it renders (SIGINT, SIGTERM, kill -9): no output, no partial
file. Real subprocesses, since the signal handling of the command is what is tested. (Apart from
test_cli_stabilize.py so that pytest-xdist's --dist loadfile can give the two to different workers.)"""

import signal
import subprocess
import sys

import numpy as np
import pytest

from egovid.core.trajectory import Trajectory, write_motion_csv
from egovid.core.video import VideoWriter
from egovid.core.video.colour import bgr_to_i420

from conftest import assert_interrupted, cli_env, partial_output_in, wait_until_running


@pytest.fixture(scope="module")
def long_clip(tmp_path_factory):
    """2560x1440, 300 frames (10 s) of one still picture, with a made-up motion CSV: quick to
    write (the picture converted once, x264 ultrafast) and to plan (planning grows with the frame
    count, so few large frames rather than many small ones), but far too long for `fpv stabilize
    --motion` to render before a signal arrives: its render is as much work as 1200 frames of
    1280x720 (600 of those were once rendered whole, on a loaded machine, before the test's poll
    saw the partial output); a render that ends first fails the test loudly (wait_until_running)."""
    folder = tmp_path_factory.mktemp("long")
    clip, n, width, height = folder / "long.mp4", 300, 2560, 1440
    y, x = np.mgrid[0:height, 0:width]
    picture = np.stack([x % 256, y % 256, (x // 40 + y // 40) % 2 * 255], axis=2).astype(np.uint8)
    with VideoWriter(clip, width, height, 30, preset="ultrafast") as w:
        planes = bgr_to_i420(picture, w.colour)
        for _ in range(n):
            w.write_i420(planes)
    t = np.arange(n) / 30.0
    angles = np.stack([5 * np.sin(t), 2 * np.sin(2.1 * t), np.zeros(n)], axis=1)
    write_motion_csv(folder / "long.csv", Trajectory.from_euler(t, angles))
    return clip, folder / "long.csv"


def _start_and_wait_for_render(tmp_path, clip, motion_csv, **kw) -> subprocess.Popen:
    """Start `fpv stabilize` and return once its output's temporary file exists (rendering is
    under way); fail loudly if the command ends first or the file never appears."""
    cmd = [sys.executable, "-m", "egovid", "fpv", "stabilize", str(clip), "-o", str(tmp_path / "o.mp4")]
    cmd += ["--motion", str(motion_csv), "--no-measure"]
    proc = subprocess.Popen(cmd, env=cli_env(), **kw)
    wait_until_running(proc, partial_output_in(tmp_path), "fpv stabilize started writing its output")
    return proc


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
def test_interrupted_stabilisation_leaves_no_output(tmp_path, long_clip, sig, code):
    proc = _start_and_wait_for_render(tmp_path, *long_clip, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert_interrupted(proc, sig, code)
    assert sorted(p.name for p in tmp_path.iterdir()) == [], "output or temporary file left behind"


def test_killed_stabilisation_never_leaves_a_partial_output(tmp_path, long_clip):
    # kill -9 cannot clean up, but the target path never holds a partial video.
    proc = _start_and_wait_for_render(tmp_path, *long_clip, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    proc.kill()
    proc.wait()
    assert not (tmp_path / "o.mp4").exists()
