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
import numpy as np
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


def _gpx_fixes(path: Path) -> list[tuple[float, float, float]]:
    """(UTC seconds, lat, lon) of every fix of a GPX file, read with the standard library only."""
    import xml.etree.ElementTree as ET

    from egovid.core.times import iso_to_utc

    out = []
    for pt in ET.parse(path).getroot().iter():
        if pt.tag.endswith("trkpt"):
            when = next(c.text for c in pt if c.tag.endswith("time"))
            out.append((iso_to_utc(when), float(pt.get("lat")), float(pt.get("lon"))))
    return out


def _metres(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Great-circle distance (haversine, mean earth radius)."""
    import math

    p1, p2 = math.radians(lat1), math.radians(lat2)
    a = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(math.radians(lon2 - lon1) / 2) ** 2
    return 2 * 6371008.8 * math.asin(math.sqrt(a))


def _expected(fixes: dict, q: dict) -> set[str]:
    """The drives with a GPS fix (as recorded in their GPX files) inside the query's circle or box
    and time range: the independent truth for what the page lists."""
    from egovid.core.times import iso_to_utc

    t_from = iso_to_utc(q["from"]) if "from" in q else -1e18
    t_to = iso_to_utc(q["to"]) if "to" in q else 1e18
    near = [float(v) for v in q["near"].split(",")] if "near" in q else None
    bbox = [float(v) for v in q["bbox"].split(",")] if "bbox" in q else None
    hit = set()
    for name, pts in fixes.items():
        for t, lat, lon in pts:
            if not t_from <= t <= t_to:
                continue
            if near is not None and _metres(lat, lon, *near) > float(q["radius"]):
                continue
            if bbox is not None and not (bbox[0] <= lon <= bbox[2] and bbox[1] <= lat <= bbox[3]):
                continue
            hit.add(name)
    return hit


def test_find_by_drawing_and_lock_in_chromium(browser, serve_archive, tmp_path):  # noqa: F811
    """Find: a box and a circle dragged on the map with a time range list the drives whose GPS
    fixes (their GPX files) fall inside, the same stretches as the library's search; lock and
    unlock from the page change the catalogue (read back through the library)."""
    from urllib.parse import parse_qsl, urlsplit

    from egovid.core.times import iso_to_utc
    from egovid.dashcam.archive.fleetstore import FleetStore
    from egovid.dashcam.archive.store import open_archive
    from egovid.dashcam.find import Query, search

    root = copy_archive(serve_archive, tmp_path)
    fixes = {name: _gpx_fixes(serve_archive.parent / f"{name}.gpx") for name in ("monday", "tuesday")}
    with egovid_serve(root, tmp_path / "serve.log") as (url, proc):
        page = browser.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        wait_js(page, "document.body.dataset.ready === '1'", "the drive list")
        mbox = page.locator("#map").bounding_box()
        size = page.evaluate("egovid.map.getSize()")
        pts = [page.evaluate(f"egovid.map.latLngToContainerPoint([{lat}, {lon}])")
               for p in fixes.values() for _, lat, lon in p]  # fmt: skip
        xs, ys = [p["x"] for p in pts], [p["y"] for p in pts]

        def find(tool: str, a: tuple[float, float], b: tuple[float, float], t_from: str = "", t_to: str = ""):
            """Drag ``tool`` on the map from container point a to b with the time range; returns the
            query the page sent and the drive names it lists."""
            page.click("#find-clear")
            page.fill("#find-from", t_from)
            page.fill("#find-to", t_to)
            page.click(f"#find-{tool}")
            page.mouse.move(mbox["x"] + a[0], mbox["y"] + a[1])
            with page.expect_response(lambda r: "/api/find?" in r.url) as resp:
                page.mouse.down()
                page.mouse.move(mbox["x"] + b[0], mbox["y"] + b[1], steps=6)
                page.mouse.up()
            assert resp.value.status == 200, resp.value.text()
            q = dict(parse_qsl(urlsplit(resp.value.url).query))
            n = len(resp.value.json())
            wait_js(page, f"document.getElementById('find-what').textContent === '{n} stretch(es)'", "the stretches")
            assert page.evaluate("egovid.S.findLayer.getLayers().length") == n  # one mark each on the map
            return q, page.locator("#found li b").all_inner_texts()

        def library(q: dict) -> list[str]:
            near = tuple(float(v) for v in q["near"].split(",")) if "near" in q else None
            bbox = tuple(float(v) for v in q["bbox"].split(",")) if "bbox" in q else None
            ar = open_archive(root)
            try:
                got = search(ar, Query(near=near, radius=float(q.get("radius", 50)), bbox=bbox,
                                       t_from=iso_to_utc(q["from"]) if "from" in q else None,
                                       t_to=iso_to_utc(q["to"]) if "to" in q else None))  # fmt: skip
            finally:
                ar.close()
            return [s.drive for s in got]

        # A box around every fix, from tuesday's day on: tuesday alone.
        pad = 12
        q, listed = find("box", (min(xs) - pad, min(ys) - pad), (max(xs) + pad, max(ys) + pad), "2026-05-05T00:00")
        assert set(q) == {"bbox", "from"} and q["from"] == "2026-05-05T00:00:00Z"
        west, south, east, north = map(float, q["bbox"].split(","))
        sw = page.evaluate(f"egovid.map.containerPointToLatLng([{min(xs) - pad}, {max(ys) + pad}])")
        ne = page.evaluate(f"egovid.map.containerPointToLatLng([{max(xs) + pad}, {min(ys) - pad}])")
        assert np.allclose([west, south, east, north], [sw["lng"], sw["lat"], ne["lng"], ne["lat"]], atol=1e-6)
        assert _expected(fixes, q) == {"tuesday"} and listed == library(q) and set(listed) == {"tuesday"}, listed

        # A circle centred beside the middle of the track (off the line, which has click handlers
        # of its own), reaching over it, until tuesday's day: monday alone.
        mid = len(fixes["monday"]) // 2
        _, lat, lon = fixes["monday"][mid]
        c = page.evaluate(f"egovid.map.latLngToContainerPoint([{lat}, {lon}])")
        centre = (c["x"] + 10, c["y"] - 10)
        q, listed = find("circle", centre, (centre[0] + 40, centre[1]), "", "2026-05-05T00:00")
        assert set(q) == {"near", "radius", "to"}
        lat, lon = map(float, q["near"].split(","))
        drawn = page.evaluate(f"egovid.map.containerPointToLatLng([{centre[0]}, {centre[1]}])")
        assert abs(drawn["lat"] - lat) < 1e-6 and abs(drawn["lng"] - lon) < 1e-6
        assert _expected(fixes, q) == {"monday"} and listed == library(q) and set(listed) == {"monday"}, listed

        # A small circle where the map is farthest from every fix (right of Leaflet's zoom and scale
        # controls), any time: nothing.
        spots = [(x, y) for x in (size["x"] / 2, size["x"] - 50) for y in (50, size["y"] - 50)]
        far = max(spots, key=lambda p: min((p[0] - x) ** 2 + (p[1] - y) ** 2 for x, y in zip(xs, ys, strict=True)))
        q, listed = find("circle", far, (far[0] + 15, far[1]))
        assert _expected(fixes, q) == set() and library(q) == [] and listed == []

        # Lock monday with a note from the page, then unlock it: the catalogue says so each time.
        def lock_state() -> tuple[bool, str | None]:
            ar = open_archive(root)
            try:
                fleet = FleetStore(ar.catalogue)
                (d,) = [d for d in fleet.live_drives() if d.name == "monday"]
                meta = fleet.meta(d.id)
                return meta.locked, meta.lock_note
            finally:
                ar.close()

        assert lock_state() == (False, None)
        page.click("#drives li:has-text('monday')")
        page.fill("#lock-note", "near miss at the junction")
        page.click("#lock")
        # (the status line says so too, but the player's start may clear it: the button is the sign)
        wait_js(page, "document.getElementById('lock').textContent === 'unlock'", "the lock")
        assert lock_state() == (True, "near miss at the junction")
        assert page.locator("#drives li:has-text('monday') .badge.lock").count() == 1
        page.select_option("#f-locked", "yes")
        assert page.locator("#drives li b").all_inner_texts() == ["monday"]
        page.select_option("#f-locked", "")
        page.click("#lock")
        wait_js(page, "document.getElementById('lock').textContent === 'lock'", "the unlock")
        assert lock_state() == (False, None)
        assert page.locator("#drives .badge.lock").count() == 0
        assert not errors, errors
        assert proc.poll() is None


def test_every_address_without_a_token_gets_a_printed_one(serve_archive, tmp_path):  # noqa: F811
    """An address other than the exact loopback ones (here 127.0.0.2, so the test listens on this
    machine's loopback only, never on every interface) without `--token`, as docs/serve.md says for
    0.0.0.0: a random token in the printed address that every request needs: one without it is
    refused (401), one with it answered. No browser needed."""
    import json
    import urllib.error
    import urllib.request

    log = tmp_path / "serve.log"
    with egovid_serve(serve_archive, log, "--host", "127.0.0.2", "--read-only") as (url, _):
        m = re.fullmatch(r"http://127\.0\.0\.2:(\d+)/\?token=([A-Za-z0-9_-]+)", url)
        assert m and len(m.group(2)) >= 32, url
        port, token = m.groups()

        def get(path: str, headers: dict | None = None) -> int:
            req = urllib.request.Request(f"http://127.0.0.2:{port}{path}", headers=headers or {})
            try:
                with urllib.request.urlopen(req, timeout=30) as r:
                    assert len(json.loads(r.read())["drives"]) == 2
                    return r.status
            except urllib.error.HTTPError as e:
                return e.code

        assert get("/api/drives") == 401
        assert get("/api/drives", {"x-egovid-token": "x" * len(token)}) == 401
        assert get("/api/drives", {"x-egovid-token": token}) == 200
