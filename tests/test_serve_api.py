"""egovid serve without a browser: the stream chunks against the archive's own extract, the cache,
the access policy (token, host, POST-only changes), path traversal, bad ids, concurrent streams,
a damaged stream next to sound ones, find, clip, lock and forget through the API."""

from __future__ import annotations

import concurrent.futures
import dataclasses
import datetime as dt
import fcntl
import io
import os
import shutil
import socket
import time
from pathlib import Path

import av
import numpy as np
import pytest

from egovid.core.video import iter_frames
from egovid.serve.access import AccessPolicy, is_loopback
from egovid.serve.fragments import encode_chunk, mime_codec, output_size
from egovid.serve.streams import ChunkCache

from conftest import run_cli

W, H, FPS = 320, 180, 10.0
DAY = dt.datetime(2026, 5, 4, 8, 0, 0, tzinfo=dt.UTC)


def _build(folder: Path) -> Path:
    """Two short drives of one street on two days: monday (root) and tuesday (coded against it)."""
    from egovid.synth.drive import DriveSpec, Light, render_drive

    noon = Light.preset("noon")
    specs = {
        "monday": DriveSpec(legs=[("main", 380.0, 450.0)], cruise=11.0, seed=1, light=noon, start_time=DAY),
        "tuesday": DriveSpec(legs=[("main", 380.0, 445.0)], cruise=10.0, seed=2, light=noon,
                             start_time=DAY + dt.timedelta(days=1)),
    }  # fmt: skip
    root = folder / "archive"
    assert run_cli("dashcam", "init", root).returncode == 0
    for name, spec in specs.items():
        video, gps, _ = render_drive(spec, folder / f"{name}.mp4", width=W, height=H, fps=FPS)
        r = run_cli("dashcam", "ingest", root, video, "--gps", gps, "--codec", "vp9")  # joint: VP9 against monday
        assert r.returncode == 0, r.stderr
    r = run_cli("dashcam", "extract", root, "tuesday", "-o", folder / "tuesday.mkv")
    assert r.returncode == 0, r.stderr
    return root


@pytest.fixture(scope="session")
def serve_archive(tmp_path_factory) -> Path:
    """The pristine test archive, built once per test run (shared by pytest-xdist workers through
    a file lock); tests change copies of it (:func:`copy_archive`)."""
    base = tmp_path_factory.getbasetemp()
    shared = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "serve-archive"
    shared.mkdir(exist_ok=True)
    with open(shared / ".lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        if not (shared / "done").exists():
            _build(shared)
            (shared / "done").write_text("ok")
    return shared / "archive"


def copy_archive(pristine: Path, dest: Path) -> Path:
    """A copy of the test archive to change."""
    out = dest / "archive"
    shutil.copytree(pristine, out)
    return out


def _client(archive: Path, **kw):
    from starlette.testclient import TestClient

    from egovid.serve.app import ServeConfig, create_app

    cfg = ServeConfig(archive=archive, port=8642, token="t" * 24, **kw)
    return TestClient(create_app(cfg), base_url="http://127.0.0.1:8642")


def _decode(chunk: bytes) -> list[np.ndarray]:
    with av.open(io.BytesIO(chunk)) as c:
        return [f.to_ndarray(format="yuv420p") for f in c.decode(video=0)]


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(float) - b.astype(float)) ** 2)
    return 99.0 if mse == 0 else 10 * np.log10(255**2 / mse)


# -- units ---------------------------------------------------------------------------------------------


def test_chunk_cache_keeps_the_most_recent_within_its_bound():
    c = ChunkCache(100)
    for k in range(5):
        c.put(k, bytes(30))
    assert c.bytes <= 100 and len(c) == 3 and c.get(0) is None and c.get(4) is not None
    c.get(2)  # used: kept over 3
    c.put(5, bytes(30))
    assert c.get(2) is not None and c.get(3) is None


def _fake_source(drive_id: int = 1, chunks: int = 40, fail_at: int | None = None):
    """A 64x48 drive of ``chunks`` chunks of 4 frames; frame i is flat grey level i % 200 (raises
    at frame ``fail_at``)."""
    from egovid.serve.streams import StreamSource

    n = 4 * chunks

    def frames(first: int):
        for i in range(first, n):
            if i == fail_at:
                raise RuntimeError("bitstream damaged here")
            yield np.full((72, 64), 16 + i % 200, np.uint8)

    return StreamSource(drive_id, 64, 48, 10.0, n, 4, frames)


def _slow_source(drive_id: int):
    """:func:`_fake_source` at 2 frames per second."""
    src = _fake_source(drive_id)

    def frames(first: int):
        for f in src.frames(first):
            time.sleep(0.5)
            yield f

    return dataclasses.replace(src, frames=frames)


def test_a_seek_withdraws_the_viewers_demand_from_the_old_producer():
    from egovid.serve.streams import StreamError, StreamService

    svc = StreamService(lambda d: _fake_source(d), ahead=2, idle_s=30)
    try:
        svc.chunk(1, 0, viewer="a")
        old = next(p for p in svc._producers if p.source.drive_id == 1)
        assert old.want == 2
        svc.chunk(1, 20, viewer="a")  # a seek: another producer
        assert old.want == -1
        time.sleep(0.5)
        assert old.next <= 3  # it produces nothing more (it idles, then ends)
        new = next(p for p in svc._producers if p is not old)
        k = new.next
        svc.chunk(1, k, viewer="b")  # a second viewer there
        svc.chunk(1, 5, viewer="a")  # a leaves; b's demand keeps the producer going
        assert new.wants == {"b": k + 2} and not new.done
        # An earlier request of a viewer still waiting when it asks again was abandoned: it ends.
        slow = StreamService(lambda d: _slow_source(d), ahead=2, idle_s=30)
        try:
            with concurrent.futures.ThreadPoolExecutor(2) as pool:
                first = pool.submit(slow.chunk, 1, 0, 30.0, "c")
                time.sleep(0.3)
                second = pool.submit(slow.chunk, 1, 30, 30.0, "c")
                with pytest.raises(StreamError) as exc:
                    first.result(timeout=30)
                assert exc.value.status == 409 and len(second.result(timeout=30)) > 0
        finally:
            slow.close()
    finally:
        svc.close()


def _producers_settle(svc, bound: int, timeout: float = 10.0) -> None:
    """At most ``bound`` producers at work, and those told to stop (one whose viewers went
    elsewhere, the oldest when a new one needs its place) end within ``timeout`` seconds."""
    assert svc.stats()["producers"] <= bound, svc.stats()
    deadline = time.monotonic() + timeout
    while svc.stats()["stopping"]:
        assert time.monotonic() < deadline, f"stopped producers still running after {timeout:.0f} s: {svc.stats()}"
        time.sleep(0.05)


def test_a_failing_producer_answers_its_error_and_the_rest_goes_on():
    from egovid.serve.streams import StreamError, StreamService

    svc = StreamService(lambda d: _fake_source(d, fail_at=10 if d == 1 else None), max_producers=2)
    try:
        assert len(svc.chunk(1, 0)) > 0
        with pytest.raises(StreamError, match="bitstream damaged here") as exc:
            svc.chunk(1, 2)  # frames 8-11
        assert exc.value.status == 500
        assert len(svc.chunk(2, 5)) > 0 and len(svc.chunk(2, 30)) > 0 and len(svc.chunk(2, 15)) > 0
        _producers_settle(svc, 2)
        with pytest.raises(StreamError) as exc:
            svc.chunk(2, 40)
        assert exc.value.status == 404
    finally:
        svc.close()


def test_decoding_a_long_segment_keeps_no_frame_per_run():
    """Streaming an hour-long drive decodes one segment of thousands of random-access runs: the
    decoder used to keep each run's last anchor (one padded frame per run, 6 GB for an hour of
    720p). Memory after 30 runs is what it was after 5."""
    import tracemalloc

    from egovid.dashcam.codec import segment as codec
    from egovid.dashcam.codec import vpx

    w, h, runs = 64, 48, 30
    base = np.random.default_rng(0).integers(0, 255, (h * 3 // 2, w + 200), dtype=np.uint8)
    frames = (np.ascontiguousarray(base[:, k % 200 : k % 200 + w]) for k in range(24 * runs))
    blob = codec.encode_segment(frames, w, h, vpx.EncoderSettings(q=40, speed=8, gop=8, refresh=24)).blob
    tracemalloc.start()
    try:
        marks = {}
        for i, _ in enumerate(codec.decode_segment(blob)):
            if i in (5 * 24, 24 * runs - 2):
                marks[i] = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    grown = marks[24 * runs - 2] - marks[5 * 24]
    frame = w * h * 3 // 2  # the leak was one (padded) frame per run: 25 frames here
    assert grown < (runs - 5) * frame / 2, f"{grown} bytes more after {runs - 5} more runs"


def test_encoded_chunk_plays_back_its_frames():
    rng = np.random.default_rng(0)
    ramp = np.tile(np.linspace(16, 235, W, dtype=np.uint8), (H * 3 // 2, 1))
    frames = [np.clip(ramp.astype(int) + k * 3 + rng.integers(-2, 3, ramp.shape), 0, 255).astype(np.uint8)
              for k in range(12)]  # fmt: skip
    data = encode_chunk(frames, W, H, FPS)
    assert mime_codec(data).startswith('video/mp4; codecs="avc1.42')  # constrained baseline: every browser
    with av.open(io.BytesIO(data)) as c:
        pts = [f.pts for f in c.decode(video=0)]
    assert pts == sorted(pts) and len(pts) == 12
    back = _decode(data)
    assert all(_psnr(a, b) > 35 for a, b in zip(frames, back, strict=True))
    assert output_size(1280, 720, 360) == (640, 360) and output_size(320, 180, 360) == (320, 180)


def test_access_policy():
    local = AccessPolicy("127.0.0.1", 8000, "secret-token-123456")
    assert not local.token_for_reads and local.host_allowed("127.0.0.1:8000") and local.host_allowed("localhost:8000")
    assert not local.host_allowed("evil.example:8000") and not local.host_allowed("127.0.0.1:9000")
    lan = AccessPolicy("0.0.0.0", 8000, "secret-token-123456")
    assert lan.token_for_reads and lan.host_allowed("anything:8000")
    assert local.token_ok("secret-token-123456") and not local.token_ok("secret") and not local.token_ok(None)
    assert is_loopback("127.0.0.2") and is_loopback("::1") and not is_loopback("10.0.0.1")


# -- the app on the test archive -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def client(serve_archive, tmp_path_factory):
    with _client(copy_archive(serve_archive, tmp_path_factory.mktemp("api"))) as c:
        yield c


def _ids(client) -> dict[str, int]:
    return {d["name"]: d["id"] for d in client.get("/api/drives").json()["drives"]}


def test_drives_list_their_storage_and_coding(client):
    ov = client.get("/api/drives").json()
    by = {d["name"]: d for d in ov["drives"]}
    assert set(by) == {"monday", "tuesday"}
    assert by["monday"]["modes"] == ["intra"] and by["tuesday"]["modes"] == ["joint"]
    assert by["tuesday"]["references"] == ["monday"] and by["tuesday"]["day"] == "2026-05-05"
    assert ov["stored_bytes"] == sum(d["bytes"] for d in ov["drives"]) > 0
    assert all(len(d["track"]) >= 2 for d in ov["drives"])
    info = client.get("/api/info").json()
    assert info["read_only"] is False and info["token"] == "t" * 24
    track = client.get(f"/api/drives/{by['tuesday']['id']}/track").json()
    # 65 m at 10 m/s cruise: speeds up to ~36 km/h, video times within the drive
    assert min(track["t"]) >= 0 and max(track["t"]) <= by["tuesday"]["duration"] + 1
    assert 5 < max(track["speed"]) < 13


def test_joint_drive_streams_the_frames_extract_gives(client, serve_archive):
    """Every chunk of the joint drive, decoded as a browser would, against `dashcam extract`."""
    did = _ids(client)["tuesday"]
    m = client.get(f"/api/drives/{did}/stream").json()
    truth = [f.image for f in iter_frames(serve_archive.parent / "tuesday.mkv", i420=True)]
    assert m["frames"] == len(truth) and m["chunks"] == -(-len(truth) // m["chunk_frames"])
    got = []
    for k in range(m["chunks"]):
        r = client.get(f"/api/drives/{did}/chunks/{k}.mp4")
        assert r.status_code == 200 and r.headers["content-type"] == "video/mp4"
        assert r.headers["x-egovid-codec"].startswith("video/mp4; codecs=")
        frames = _decode(r.content)
        assert len(frames) == min(m["chunk_frames"], m["frames"] - k * m["chunk_frames"])
        got += frames
    psnr = [_psnr(a, b) for a, b in zip(truth, got, strict=True)]
    assert min(psnr) > 30, psnr
    # Each frame lands in its place: frame k is closer to truth k than to its neighbours.
    for k in range(1, len(truth) - 1):
        assert psnr[k] > _psnr(got[k], truth[k - 1]) and psnr[k] > _psnr(got[k], truth[k + 1])


def test_bad_ids_and_paths(client, serve_archive):
    did = _ids(client)["tuesday"]
    for path in ("/api/drives/999/track", "/api/drives/999/stream", "/api/drives/999/chunks/0.mp4",
                 f"/api/drives/{did}/chunks/99.mp4", "/api/drives/abc/track", f"/api/drives/{did}/chunks/-1.mp4",
                 "/api/clips/0123456789abcdef0123456789abcdef/clip.mp4", "/api/clips/../../etc/passwd/clip.mp4",
                 "/api/nothing"):  # fmt: skip
        r = client.get(path)
        assert r.status_code == 404, path
        assert "error" in r.json(), path
    # Path traversal, raw and percent-encoded, out of the static folders and the report folders.
    for raw in ("/static/../../../../etc/passwd", "/static/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
                "/static/..%2f..%2f..%2fetc%2fpasswd", "/static/leaflet/..%2f..%2f..%2f..%2fetc/passwd",
                "/static/%2fetc%2fpasswd", "/static//etc/passwd"):  # fmt: skip
        r = client.get(raw)
        assert r.status_code in (400, 404), raw
        assert b"root:" not in r.content
    assert client.get("/static/app.js").status_code == 200
    assert client.get("/static/leaflet/leaflet.js").status_code == 200
    r = client.get("/api/find", params={"near": "48.1,nope"})
    assert r.status_code == 400 and "near" in r.json()["error"]
    r = client.post("/api/clips", json={"drive": did, "t": -5}, headers={"x-egovid-token": "t" * 24})
    assert r.status_code == 400
    r = client.post("/api/forget", content=b"not json", headers={"x-egovid-token": "t" * 24})
    assert r.status_code == 400


def test_reports_are_served_and_fenced(serve_archive, tmp_path):
    rep = tmp_path / "vo-run"
    rep.mkdir()
    (rep / "report.html").write_text("<html><body>voeval report</body></html>")
    (tmp_path / "secret.txt").write_text("secret")
    (rep / "escape").symlink_to(tmp_path / "secret.txt")
    with _client(serve_archive, reports=[("voeval", rep)]) as c:
        info = c.get("/api/info").json()
        assert info["reports"] == [{"kind": "voeval", "name": "vo-run", "base": "/reports/voeval/0/",
                                    "pages": ["report.html"]}]  # fmt: skip
        assert "voeval report" in c.get("/reports/voeval/0/report.html").text
        for raw in ("/reports/voeval/0/../../secret.txt", "/reports/voeval/0/%2e%2e/secret.txt",
                    "/reports/voeval/0/escape"):  # fmt: skip
            r = c.get(raw)
            assert r.status_code == 404 and b"secret" not in r.content, raw


def test_token_host_and_post_only_changes(serve_archive):
    from starlette.testclient import TestClient

    from egovid.serve.app import ServeConfig, create_app

    token = "s" * 24
    # Beyond loopback's own address: every request needs the token.
    app = create_app(ServeConfig(archive=serve_archive, host="127.0.0.2", port=9000, token=token))
    with TestClient(app, base_url="http://127.0.0.2:9000") as c:
        assert c.get("/api/drives").status_code == 401
        assert c.get("/").status_code == 401
        assert c.get("/api/drives", headers={"x-egovid-token": "wrong" * 5}).status_code == 401
        assert c.get("/api/drives", headers={"x-egovid-token": token}).status_code == 200
        assert c.get("/?token=" + "x" * 24, follow_redirects=False).status_code == 401
        r = c.get(f"/?token={token}", follow_redirects=False)
        assert r.status_code == 303 and r.headers["location"] == "/" and "HttpOnly" in r.headers["set-cookie"]
        assert c.get("/api/drives").status_code == 200  # the cookie from now on
        assert c.get("/").status_code == 200
        # A change with the cookie but without the header is refused (no cross-site request can set it).
        did = _ids(c)["tuesday"]
        assert c.post(f"/api/drives/{did}/lock", json={}).status_code == 403
        assert c.get(f"/api/drives/{did}/lock").status_code == 405  # never by a link
        evil = {"x-egovid-token": token, "origin": "http://evil.example"}
        assert c.post(f"/api/drives/{did}/lock", json={}, headers=evil).status_code == 403
    # On loopback: reads without a token, but only under the server's own host name.
    with _client(serve_archive) as c:
        assert c.get("/api/drives").status_code == 200
        assert c.get("/api/drives", headers={"host": "evil.example:8642"}).status_code == 421
        assert c.post("/api/forget/preview", json={"drives": [1]}).status_code == 403
        r = c.get("/")
        assert "default-src 'self'" in r.headers["content-security-policy"]
        assert r.headers["x-frame-options"] == "DENY" and r.headers["x-content-type-options"] == "nosniff"
    # Read-only: the change routes are not there.
    with _client(serve_archive, read_only=True) as c:
        assert c.get("/api/info").json()["read_only"] is True
        hdr = {"x-egovid-token": "t" * 24}
        for path in ("/api/forget", "/api/forget/preview", "/api/drives/1/lock", "/api/drives/1/unlock"):
            assert c.post(path, json={"drives": [1]}, headers=hdr).status_code == 404, path


def test_concurrent_streams_give_the_same_chunks(serve_archive):
    """Four viewers at once on both drives (cold cache, at most three producers), against one alone."""
    with _client(serve_archive) as c:
        ids = list(_ids(c).values())
        plan = [(d, k) for d in ids for k in range(c.get(f"/api/drives/{d}/stream").json()["chunks"])]
        alone = {key: c.get(f"/api/drives/{key[0]}/chunks/{key[1]}.mp4").content for key in plan}
    with _client(serve_archive, producers=3) as c:

        def viewer(seed: int) -> dict:
            order = list(plan)
            np.random.default_rng(seed).shuffle(order)
            return {key: c.get(f"/api/drives/{key[0]}/chunks/{key[1]}.mp4") for key in order}

        with concurrent.futures.ThreadPoolExecutor(4) as pool:
            results = list(pool.map(viewer, range(4)))
        for got in results:
            assert all(r.status_code == 200 for r in got.values())
            assert {k: r.content for k, r in got.items()} == alone
        _producers_settle(c.app.state.streams, 3)


def test_a_damaged_stream_fails_alone(serve_archive, tmp_path):
    """A bitstream damaged in its second random-access run: that chunk is a 500 naming the damage,
    the chunk before it and the server go on."""
    root = copy_archive(serve_archive, tmp_path)
    with _client(root) as c:
        did = _ids(c)["monday"]
        seg = c.app.state.ops._open()[0].segments(did)[0]
        offsets = seg.params["run_offsets"]
        blob = next(p for p in (root / "blobs").rglob("*") if p.is_file() and p.name == seg.blob)
        data = bytearray(blob.read_bytes())
        mid = (offsets[1] + offsets[2]) // 2
        data[mid : mid + 64] = bytes(64)
        blob.write_bytes(bytes(data))
        assert c.get(f"/api/drives/{did}/chunks/0.mp4").status_code == 200
        r = c.get(f"/api/drives/{did}/chunks/1.mp4")
        assert r.status_code == 500 and f"drive {did} cannot be streamed" in r.json()["error"]
        assert c.get("/api/drives").status_code == 200
        assert c.get(f"/api/drives/{did}/chunks/0.mp4").status_code == 200


def test_find_clip_lock_forget(serve_archive, tmp_path):
    root = copy_archive(serve_archive, tmp_path)
    hdr = {"x-egovid-token": "t" * 24}
    with _client(root) as c:
        ids = _ids(c)
        track = c.get(f"/api/drives/{ids['tuesday']}/track").json()
        mid = len(track["lat"]) // 2
        near = f"{track['lat'][mid]},{track['lon'][mid]}"
        found = c.get("/api/find", params={"near": near, "radius": 30}).json()
        assert {s["drive"] for s in found} == {"monday", "tuesday"}
        assert all(0 <= s["t0"] < s["t1"] and s["distance_m"] < 30 for s in found)
        found = c.get("/api/find", params={"near": near, "radius": 30, "from": "2026-05-05T00:00:00Z"}).json()
        assert [s["drive"] for s in found] == ["tuesday"]
        lat, lon = np.array(track["lat"]), np.array(track["lon"])
        bbox = f"{lon.min() - 1e-3},{lat.min() - 1e-3},{lon.max() + 1e-3},{lat.max() + 1e-3}"
        assert len(c.get("/api/find", params={"bbox": bbox}).json()) == 2
        # A clip of tuesday around its 3rd second: H.264 + GPX, the frames of that stretch.
        r = c.post("/api/clips", json={"drive": ids["tuesday"], "t": 3.0, "before": 1, "after": 1}, headers=hdr)
        assert r.status_code == 200, r.text
        clip = r.json()
        video = c.get(clip["video"])
        assert video.status_code == 200 and "attachment" in video.headers["content-disposition"]
        assert len(_decode(video.content)) == clip["frames"] == clip["frame_end"] - clip["frame_start"]
        assert "<trkpt" in c.get(clip["gpx"]).text
        # Lock: forget then refuses; unlock: the preview says what else changes.
        assert c.post(f"/api/drives/{ids['monday']}/lock", json={"note": "claim"}, headers=hdr).json()["locked"]
        r = c.post("/api/forget/preview", json={"drives": [ids["monday"]]}, headers=hdr)
        assert r.status_code == 400 and "locked" in r.json()["error"]
        assert not c.post(f"/api/drives/{ids['monday']}/unlock", json={}, headers=hdr).json()["locked"]
        preview = c.post("/api/forget/preview", json={"drives": [ids["monday"]]}, headers=hdr).json()
        assert preview["dry_run"] and preview["kept_as_reference"] == {"monday": ["tuesday"]}
        assert preview["bytes_freed"] >= 0
        assert set(_ids(c)) == {"monday", "tuesday"}  # a preview changes nothing
        before = c.get(f"/api/drives/{ids['tuesday']}/chunks/1.mp4").content
        done = c.post("/api/forget", json={"drives": [ids["monday"]]}, headers=hdr).json()
        assert done["forgotten"] == ["monday"] and done["verified"] == ["tuesday"]
        assert set(_ids(c)) == {"tuesday"}
        assert c.get(f"/api/drives/{ids['monday']}/stream").status_code == 404
        after = c.get(f"/api/drives/{ids['tuesday']}/chunks/1.mp4")
        assert after.status_code == 200 and after.content == before  # decodes as before, through the reference


def test_serve_cli_refuses_bad_input(serve_archive, tmp_path, capsys):
    # Each is refused before serving, so in this process (see invoke_cli).
    from conftest import assert_one_error, invoke_cli

    cli = lambda *args: invoke_cli(list(args), capsys)  # noqa: E731
    assert_one_error(cli("serve", tmp_path / "nothing"), "not found")
    assert_one_error(cli("serve", tmp_path), "not an egovid archive")
    assert_one_error(cli("serve", serve_archive, "--token", "short"), "16 characters")
    assert_one_error(cli("serve", serve_archive, "--fpv", tmp_path / "none"), "report folder")
    # (absurd ports, foreign addresses, bad --tiles: tests/test_fuzz_cli.py, in process)
    with socket.socket() as taken:  # a port another program listens on
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert_one_error(cli("serve", serve_archive, "--port", port), f"cannot listen on 127.0.0.1:{port}")


def test_an_archive_on_postgresql_serves_the_same(serve_archive, pg_url, tmp_path):
    """The catalogue in PostgreSQL (each server thread its own connection): drives, track, a chunk."""
    root = tmp_path / "pg-archive"
    assert run_cli("dashcam", "init", root, "--db", pg_url).returncode == 0
    video = serve_archive.parent / "monday.mp4"
    r = run_cli("dashcam", "ingest", root, video, "--gps", video.with_suffix(".gpx"))
    assert r.returncode == 0, r.stderr
    with _client(root) as c:
        (d,) = c.get("/api/drives").json()["drives"]
        assert d["name"] == "monday" and d["modes"] == ["intra"]
        with concurrent.futures.ThreadPoolExecutor(3) as pool:  # several threads, several connections
            got = list(pool.map(lambda k: c.get(f"/api/drives/{d['id']}/chunks/{k}.mp4"), range(3)))
        assert all(g.status_code == 200 and len(_decode(g.content)) > 0 for g in got)
        assert len(c.get(f"/api/drives/{d['id']}/track").json()["t"]) > 2


def test_an_archive_with_blobs_on_s3_plays(serve_archive, s3_server, tmp_path, monkeypatch):
    """Blobs in an S3 bucket (seaweedfs), none on disk: the joint drive's chunk decodes, through
    its reference drive's bitstream fetched from the bucket too, to the frames `dashcam extract`
    gives for that stretch."""
    import s3fs

    backup = tmp_path / "catalogue.backup"
    assert run_cli("dashcam", "backup", serve_archive, backup).returncode == 0
    root = tmp_path / "s3-archive"
    r = run_cli("dashcam", "init", root, "--blobs", "s3://egovid/serve", env=s3_server)
    assert r.returncode == 0, r.stderr
    assert run_cli("dashcam", "restore", backup, root, env=s3_server).returncode == 0
    fs = s3fs.S3FileSystem(
        key=s3_server["AWS_ACCESS_KEY_ID"],
        secret=s3_server["AWS_SECRET_ACCESS_KEY"],
        client_kwargs={"endpoint_url": s3_server["AWS_ENDPOINT_URL"]},
        skip_instance_cache=True,
    )
    local = serve_archive / "blobs"
    for p in (p for p in local.rglob("*") if p.is_file()):
        fs.put_file(str(p), f"egovid/serve/{p.relative_to(local)}")
    assert not any(p.is_file() for p in (root / "blobs").rglob("*"))  # nothing on disk to fall back on
    for k, v in s3_server.items():
        monkeypatch.setenv(k, v)
    truth = [f.image for f in iter_frames(serve_archive.parent / "tuesday.mkv", i420=True)]
    with _client(root) as c:
        did = _ids(c)["tuesday"]
        m = c.get(f"/api/drives/{did}/stream").json()
        k = 1
        r = c.get(f"/api/drives/{did}/chunks/{k}.mp4")
        assert r.status_code == 200, r.text
        frames = _decode(r.content)
        want = truth[k * m["chunk_frames"] : (k + 1) * m["chunk_frames"]]
        assert len(frames) == len(want) == min(m["chunk_frames"], m["frames"] - k * m["chunk_frames"]) > 0
        assert min(_psnr(a, b) for a, b in zip(want, frames, strict=True)) > 30
