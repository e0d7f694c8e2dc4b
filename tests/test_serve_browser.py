"""egovid serve in a real browser: Debian's headless Chromium driven by Playwright (never a
downloaded browser). `egovid serve` runs as a user starts it, on 127.0.0.1 and a free port; the
page plays a joint drive (the video's clock advances, the map marker moves, its speed shows),
seeks from the scrub bar, the timeline and the map, downloads a clip, and forgets a drive after
saying what else changes."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import av
import pytest

from test_serve_api import copy_archive, serve_archive  # noqa: F401 - the shared test archive

from conftest import cli_env

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--autoplay-policy=no-user-gesture-required",
]


def wait_js(page, expr: str, what: str, timeout: float = 30.0):
    """Poll the page until ``expr`` is truthy and return its value; fail loudly after ``timeout``
    seconds. (Playwright's wait_for_function evaluates strings, which the page's CSP forbids.)"""
    deadline = time.monotonic() + timeout
    while True:
        got = page.evaluate(expr)
        if got:
            return got
        if time.monotonic() > deadline:
            status = page.evaluate("document.getElementById('status').textContent")
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what} (page status: {status!r})")
        time.sleep(0.1)


@contextlib.contextmanager
def egovid_serve(archive: Path, log: Path, *args: str):
    """``egovid serve ARCHIVE --port 0`` in its own process group; yields the address it printed.
    Stopped with SIGTERM (killed if it does not stop in 20 s)."""
    with open(log, "w") as fh:
        proc = subprocess.Popen(
            [sys.executable, "-m", "egovid", "serve", str(archive), "--port", "0", "--tiles", "none", *args],
            stdout=subprocess.PIPE,
            stderr=fh,
            text=True,
            env=cli_env(),
            start_new_session=True,
        )
    try:
        line = ""
        deadline = time.monotonic() + 120
        while "serving" not in line:
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"egovid serve did not start (rc {proc.poll()}): {log.read_text()[-2000:]}")
            line = proc.stdout.readline()
        yield re.search(r"http://\S+", line).group(0), proc
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    pw = pytest.importorskip("playwright.sync_api")
    if not CHROMIUM.exists():
        pytest.skip("no /usr/bin/chromium (make test installs Debian's chromium)")
    with pw.sync_playwright() as p:
        ctx = p.chromium.launch_persistent_context(
            str(tmp_path_factory.mktemp("chromium-profile")),
            executable_path=str(CHROMIUM),
            args=CHROMIUM_ARGS,
            headless=True,
            viewport={"width": 1280, "height": 800},
            accept_downloads=True,
        )
        ctx.set_default_timeout(30_000)
        try:
            yield ctx
        finally:
            ctx.close()


def test_play_seek_clip_and_forget_in_chromium(browser, serve_archive, tmp_path):  # noqa: F811
    root = copy_archive(serve_archive, tmp_path)
    with egovid_serve(root, tmp_path / "serve.log") as (url, proc):
        assert url.startswith("http://127.0.0.1:") and "token" not in url
        page = browser.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        wait_js(page, "document.body.dataset.ready === '1'", "the drive list")
        assert page.locator("#drives li").count() == 2
        assert page.locator("path.egovid-track").count() == 2  # both tracks on the map
        assert page.locator("#tl rect.drive").count() == 2  # and on the timeline

        # Play the joint drive from the list: the clock advances, the marker moves, speed shows.
        page.click("#drives li:has-text('tuesday')")
        wait_js(page, "document.getElementById('video').currentTime > 0.3", "tuesday to play")
        t1, p1 = page.evaluate("[video.currentTime, egovid.marker.getLatLng()]")
        time.sleep(1.0)
        t2, p2 = page.evaluate("[video.currentTime, egovid.marker.getLatLng()]")
        assert t2 > t1 + 0.3, (t1, t2)
        assert (p1["lat"], p1["lng"]) != (p2["lat"], p2["lng"])
        assert re.search(r"\d+ km/h · [+-]\d+\.\d m/s²", page.locator(".egovid-speed").inner_text())
        assert page.evaluate("video.videoWidth") == 320
        page.screenshot(path=str(tmp_path / "playing.png"))

        # Seek from the scrub bar, then from the timeline (monday's bar opens monday there).
        duration = page.evaluate("egovid.Player.manifest.duration")
        box = page.locator("#scrub").bounding_box()
        page.mouse.click(box["x"] + 0.75 * box["width"], box["y"] + box["height"] / 2)
        wait_js(page, f"Math.abs(video.currentTime - {0.75 * duration}) < 0.6 && !video.seeking", "the seek")
        bar = page.locator("#tl rect.drive").first.bounding_box()
        page.mouse.click(bar["x"] + 0.5 * bar["width"], bar["y"] + bar["height"] / 2)
        wait_js(page, "document.body.dataset.playing === '1' && video.currentTime > 2", "monday from the timeline")
        # Seek from the map: a click on the playing drive's track near its start.
        first = page.evaluate(
            "egovid.map.latLngToContainerPoint([egovid.Player.track.lat[0], egovid.Player.track.lon[0]])"
        )
        mbox = page.locator("#map").bounding_box()
        page.mouse.click(mbox["x"] + first["x"], mbox["y"] + first["y"])
        wait_js(page, "video.currentTime < 1.5 && !video.seeking", "the seek from the map")

        # A clip around the moment: two links; the video downloads and decodes.
        page.fill("#clip-before", "1")
        page.fill("#clip-after", "1")
        page.click("#clip")
        page.wait_for_selector("#clip-links a")
        with page.expect_download() as dl:
            page.click("#clip-links a:has-text('clip.mp4')")
        saved = tmp_path / "clip.mp4"
        dl.value.save_as(saved)
        with av.open(str(saved)) as c:
            assert c.streams.video[0].codec_context.name == "h264" and sum(1 for _ in c.decode(video=0)) >= 10
        assert page.locator("#clip-links a:has-text('clip.gpx')").count() == 1

        # Forget monday: the dialog says what else changes; cancel keeps it, confirming removes it.
        page.click("#forget")
        page.wait_for_selector("#confirm[open]")
        text = page.locator("#confirm-text").inner_text()
        assert "Forget monday?" in text and "Frees" in text and "tuesday is coded against monday" in text, text
        page.screenshot(path=str(tmp_path / "forget.png"))
        page.click("#confirm-cancel")
        assert page.locator("#drives li").count() == 2
        page.click("#forget")
        page.wait_for_selector("#confirm[open]")
        page.click("#confirm-ok")
        wait_js(page, "document.querySelectorAll('#drives li').length === 1", "monday to leave the list")
        assert "tuesday" in page.locator("#drives").inner_text()
        # tuesday still plays (its reference frames were kept).
        page.click("#drives li:has-text('tuesday')")
        wait_js(page, "document.body.dataset.playing !== '' && video.currentTime > 0.3", "tuesday after the forget")
        assert not errors, errors
        assert proc.poll() is None


def test_read_only_hides_changes_and_token_guards_the_page(browser, serve_archive, tmp_path):  # noqa: F811
    with egovid_serve(serve_archive, tmp_path / "serve.log", "--read-only", "--host", "127.0.0.2") as (url, _):
        assert "?token=" in url
        page = browser.new_page()
        r = page.goto(url.split("?")[0])
        assert r.status == 401
        page.goto(url)  # sets the cookie, redirects to / without the token
        wait_js(page, "document.body.dataset.ready === '1'", "the drive list")
        assert "token" not in page.url
        page.click("#drives li:has-text('monday')")
        wait_js(page, "video.currentTime > 0.3", "monday to play")
        assert not page.locator("#forget").is_visible() and not page.locator("#lock").is_visible()
        assert page.locator("#clip").is_visible()
