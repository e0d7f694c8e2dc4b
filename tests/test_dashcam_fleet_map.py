"""The archive's HTML map, opened in a real headless Chromium (Debian's, installed by `make`)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest

from egovid.dashcam.mapview import DRIVE_COLOURS, MapDrive, MapStretch, render_map, saving_colour


def chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("no chromium (make test installs Debian's chromium)")
    return exe


def browse(page: Path, tmp: Path, timeout_s: float = 90.0, tries: int = 2) -> str:
    """The DOM of ``page`` after its scripts ran, from headless Chromium (offline: no network here).

    Chromium runs in its own session and, past ``timeout_s`` seconds, its whole process group is
    killed (killing only the browser process left its zygotes spinning on a loaded machine); a
    timed-out try is tried once more with a fresh profile, and a second one fails the test."""
    for attempt in range(tries):
        profile = tmp / f"profile-{attempt}"
        proc = subprocess.Popen(
            [chromium(), "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={profile}",
             "--virtual-time-budget=5000", "--window-size=1000,700", "--dump-dom", page.as_uri()],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        )  # fmt: skip
        try:
            out, err = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate(timeout=30)
            continue
        assert proc.returncode == 0, err[-2000:]
        return out
    pytest.fail(f"headless Chromium did not render {page.name} within {timeout_s:.0f} s, {tries} tries")


def _drives() -> list[MapDrive]:
    t = np.linspace(0.0, 1.0, 400)
    north = MapStretch(48.1000 + 0.004 * t, np.full_like(t, 11.5000), None, {"frames": "0-199"})
    east = MapStretch(np.full_like(t, 48.1040), 11.5000 + 0.006 * t, 0.31, {"frames": "200-399"})
    event = MapStretch(48.1000 + 0.002 * t, np.full_like(t, 11.5003), 0.12)
    return [MapDrive("monday <b>", [north, east], info={"start": "2026-05-04 08:00"}),
            MapDrive("crash", [event], kind="event")]  # fmt: skip


def _paths(dom: str) -> list[tuple[str, list[tuple[float, float]]]]:
    """(stroke colour, vertices in pixels) of every track Leaflet drew as SVG."""
    out = []
    for tag in re.findall(r"<path [^>]*egovid-track[^>]*>", dom):
        d = re.search(r' d="([^"]+)"', tag).group(1)
        stroke = re.search(r' stroke="([^"]+)"', tag).group(1)
        pts = [(float(x), float(y)) for x, y in re.findall(r"(-?\d+(?:\.\d+)?)[ ,](-?\d+(?:\.\d+)?)", d)]
        out.append((stroke, pts))
    return out


def test_map_draws_tracks_offline_in_chromium(tmp_path):
    page = tmp_path / "report.html"
    page.write_text(render_map(_drives(), tiles=None))
    dom = browse(page, tmp_path)
    assert 'data-tracks="3"' in dom, dom[-3000:]
    paths = _paths(dom)
    assert len(paths) == 3
    (c1, north), (c2, east), (c3, event) = paths
    # Coloured by drive: both stretches of the first drive in its colour, the event in the next one.
    assert c1 == c2 == DRIVE_COLOURS[0] and c3 == DRIVE_COLOURS[1]
    # Drawn where they are: the northward stretch goes up the screen (y falls, x stays), the
    # eastward one goes right, and both lie inside the 1000x700 window.
    for pts in (north, east, event):
        xy = np.array(pts)
        assert len(xy) >= 2 and np.all((xy > -5) & (xy < [1005, 705]))
    n = np.array(north)
    assert n[-1, 1] < n[0, 1] - 100 and abs(n[-1, 0] - n[0, 0]) < 2
    e = np.array(east)
    assert e[-1, 0] > e[0, 0] + 100 and abs(e[-1, 1] - e[0, 1]) < 2
    # 0.004° of latitude is 445 m, 0.006° of longitude at 48.1° is 446 m: equal lengths on screen.
    assert abs((n[0, 1] - n[-1, 1]) - (e[-1, 0] - e[0, 0])) < 0.02 * (n[0, 1] - n[-1, 1])
    # Names are text, never markup.
    assert "<b>" not in dom.split('id="plain"')[0].split("<script")[0]


def test_map_colours_by_saving_and_falls_back_without_scripts(tmp_path):
    page = tmp_path / "report.html"
    page.write_text(render_map(_drives(), colour_by="saving"))
    dom = browse(page, tmp_path)
    assert 'data-tracks="3"' in dom
    assert re.search(r'data-tiles="(offline|online)"', dom)  # tiles configured; the page copes without them
    strokes = [c for c, _ in _paths(dom)]
    assert strokes == [saving_colour(None), saving_colour(0.31), saving_colour(0.12)]
    assert saving_colour(0.0) == "#440154" and saving_colour(0.5) == saving_colour(0.9) == "#fde725"
    # Where the map library cannot run, the plain projected SVG drawn in Python is what shows.
    html = page.read_text()
    start = html.index("<script>/* @preserve")
    page.write_text(html[:start] + html[html.index("</script>", start) + 9 :])
    dom = browse(page, tmp_path)
    assert 'data-tracks="0"' in dom and '<div id="plain">' in dom
    assert len(re.findall(r'<polyline class="egovid-track"', dom)) == 3
