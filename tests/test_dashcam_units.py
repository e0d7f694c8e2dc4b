"""Dashcam archive parts on hand-made or exactly known inputs: GPS readers, path matching and
splitting, catalogue transactions, illumination features, stops, the VP9 reference injection,
SeqSLAM."""

import datetime as dt
import hashlib

import numpy as np
import pytest

from egovid.core.errors import EgovidError
from egovid.dashcam.align.illumination import best_match, frame_features, rank_scores
from egovid.dashcam.align.seqslam import align_seqslam, descriptor
from egovid.dashcam.align.stops import stopped_frames
from egovid.dashcam.archive.catalogue import PostgresCatalogue, SqliteCatalogue
from egovid.dashcam.codec import segment as codec
from egovid.dashcam.codec import vpx
from egovid.dashcam.codec.settings import EncoderSettings
from egovid.dashcam.ingest.piece import DB_PER_HALVING, keep_joint
from egovid.dashcam.route.paths import match_path, resample, split_drive, split_points
from egovid.dashcam.route.tracks import project, read_track


def _nmea(body):
    cs = 0
    for ch in body:
        cs ^= ord(ch)
    return f"${body}*{cs:02X}"


def test_nmea_checksums_void_and_dead_reckoning_fixes_are_dropped(tmp_path):
    lines = [
        _nmea("GPRMC,080000.00,A,4025.4220,N,08655.2720,W,20.0,90.0,040526,,,A"),
        _nmea("GPRMC,080001.00,A,4025.4220,N,08655.2600,W,20.0,90.0,040526,,,A"),
        _nmea("GPRMC,080002.00,V,4025.4220,N,08655.2500,W,20.0,90.0,040526,,,N"),  # void
        _nmea("GPRMC,080003.00,A,4025.4220,N,08655.2400,W,20.0,90.0,040526,,,E"),  # dead reckoning
        _nmea("GPRMC,080004.00,A,4025.4220,N,08655.2300,W,20.0,90.0,040526,,,A")[:-2] + "00",  # bad checksum
        _nmea("GPRMC,080005.00,A,4025.4220,N,08655.2200,W,20.0,90.0,040526,,,A"),
        _nmea("GPGGA,080006.00,4025.4220,N,08655.2100,W,0,00,99.9,190.0,M,-33.0,M,,"),  # no fix
        _nmea("GPGGA,080007.00,4025.4220,N,08655.2000,W,1,09,0.9,190.0,M,-33.0,M,,"),
    ]
    p = tmp_path / "log.nmea"
    p.write_text("\r\n".join(lines) + "\r\n")
    g = read_track(p)
    t0 = dt.datetime(2026, 5, 4, 8, 0, 0, tzinfo=dt.UTC).timestamp()
    np.testing.assert_allclose(g.t - t0, [0, 1, 5, 7])
    assert g.dropped == {"checksum": 1, "void or estimated": 3, "unparsable": 0}
    assert g.lat[0] == pytest.approx(40 + 25.422 / 60)
    assert g.lon[0] == pytest.approx(-(86 + 55.272 / 60))
    assert g.speed[0] == pytest.approx(20 * 0.514444)  # knots
    assert g.gaps(3.0) == [(t0 + 1, t0 + 5)]


def test_a_log_file_and_a_text_track_merge_rmc_and_gga_alike(tmp_path):
    """The same sentences in a log file and as samples of a video's text track give the same fixes:
    one merge rule (an RMC and a GGA of one second make one fix, a GGA alone adds its position)."""
    from egovid.dashcam.route.embedded import fixes_from_nmea_samples

    lines = [
        _nmea("GPRMC,080000.00,A,4025.4220,N,08655.2720,W,20.0,90.0,040526,,,A"),
        _nmea("GPGGA,080000.00,4025.4221,N,08655.2721,W,1,09,0.9,190.0,M,-33.0,M,,"),  # RMC's second: RMC wins
        _nmea("GPGGA,080001.00,4025.4220,N,08655.2600,W,1,09,0.9,190.0,M,-33.0,M,,"),
        _nmea("GPGGA,080001.00,4025.4290,N,08655.2600,W,1,09,0.9,190.0,M,-33.0,M,,"),  # same second: first wins
        _nmea("GPRMC,080002.00,A,4025.4220,N,08655.2500,W,20.0,90.0,040526,,,A"),
        _nmea("GPRMC,080003.00,A,4025.4220,N,08655.2400,W,20.0,,040526,,,A"),  # no course
    ]
    p = tmp_path / "log.nmea"
    p.write_text("\n".join(lines) + "\n")
    log = read_track(p)
    inside = fixes_from_nmea_samples([(0.1 * k, ln) for k, ln in enumerate(lines)]).track
    t0 = dt.datetime(2026, 5, 4, 8, 0, 0, tzinfo=dt.UTC).timestamp()
    np.testing.assert_allclose(log.t - t0, [0, 1, 2, 3])
    for k in ("t", "lat", "lon", "speed", "bearing"):
        np.testing.assert_array_equal(getattr(log, k), getattr(inside, k), err_msg=k)
    assert log.lat[0] == pytest.approx(40 + 25.422 / 60) and log.lat[1] == pytest.approx(40 + 25.422 / 60)


def test_gpx_and_csv_and_derived_speed(tmp_path):
    t0 = 1777881600.0
    # 10 m/s due east for 20 s, no speed column: derived from positions.
    xs = np.arange(21) * 10.0
    lat, lon = 40.0 + 0 * xs, -86.0 + np.degrees(xs / (6371008.8 * np.cos(np.radians(40.0))))
    rows = "".join(f"{t0 + i},{la:.8f},{lo:.8f}\n" for i, (la, lo) in enumerate(zip(lat, lon, strict=True)))
    (tmp_path / "t.csv").write_text("time,lat,lon\n" + rows)
    g = read_track(tmp_path / "t.csv")
    assert np.median(g.speed) == pytest.approx(10.0, rel=0.02)
    assert np.median(g.bearing) == pytest.approx(90.0, abs=1.0)
    xy = g.xy((40.0, -86.0))
    assert xy[-1, 0] == pytest.approx(200.0, abs=0.05)
    import gpxpy.gpx

    gpx = gpxpy.gpx.GPX()
    trk, seg = gpxpy.gpx.GPXTrack(), gpxpy.gpx.GPXTrackSegment()
    gpx.tracks.append(trk)
    trk.segments.append(seg)
    for i, (la, lo) in enumerate(zip(lat, lon, strict=True)):
        seg.points.append(gpxpy.gpx.GPXTrackPoint(la, lo, time=dt.datetime.fromtimestamp(t0 + i, dt.UTC)))
    (tmp_path / "t.gpx").write_text(gpx.to_xml())
    g2 = read_track(tmp_path / "t.gpx")
    np.testing.assert_allclose(g2.t, g.t)
    np.testing.assert_allclose(g2.lat, g.lat, atol=1e-7)


@pytest.mark.parametrize(
    "content,needle",
    [
        (b"\x00\x01\x02garbage", "binary"),
        (b'{"type": "FeatureCollection"}', "not a GPS track"),
        (b"time,x,y\n1,2,3\n", "not a GPS track"),
        (b"time,lat,lon\n2026-05-04T08:00:00Z,40,-86\n", "at least 2"),
        (b"time,lat,lon\nnoon,40,-86\n", "neither ISO"),
        (b"", "empty"),
    ],
)
def test_wrong_gps_files_give_clear_errors(tmp_path, content, needle):
    p = tmp_path / "g.txt"
    p.write_bytes(content)
    with pytest.raises(EgovidError, match=needle):
        read_track(p)


def _line(n, y=0.0, start=0.0):
    return np.stack([start + np.arange(n) * 5.0, np.full(n, y)], axis=1)


def test_drive_along_a_path_and_one_that_leaves_it():
    path = _line(41)  # 200 m eastwards
    # Drive 1: the whole path, eastwards at ~10 m/s with 3 m of noise.
    rng = np.random.default_rng(0)
    xy = np.stack([np.arange(21) * 10.0, np.zeros(21)], 1) + rng.normal(0, 3, (21, 2))
    bearing, speed = np.full(21, 90.0), np.full(21, 10.0)
    m = match_path(7, path, xy, bearing, speed)
    assert m.indicator.all()
    assert np.all(np.diff(m.closest) >= 0)
    pieces = split_drive([m], 21)
    assert [(p.start, p.end, p.path_id) for p in pieces] == [(0, 21, 7)]
    # Drive 2: joins at 100 m, leaves northwards at 150 m.
    xy2 = np.concatenate(
        [
            np.stack([100 + np.arange(6) * 10.0, np.zeros(6)], 1),
            np.stack([np.full(10, 150.0), 10 + np.arange(10) * 10.0], 1),
        ]
    )
    b2 = np.concatenate([np.full(6, 90.0), np.zeros(10)])
    m2 = match_path(7, path, xy2, b2, np.full(16, 10.0))
    pieces = split_drive([m2], 16)
    assert pieces[0].path_id == 7 and pieces[-1].path_id is None
    on = pieces[0]
    assert split_points(on.first_point, on.last_point, len(path)) == [on.first_point, on.last_point + 1]
    assert on.first_point == 20 and 29 <= on.last_point <= 31
    # The other direction is a different path.
    m3 = match_path(7, path, xy[::-1], np.full(21, 270.0), speed)
    assert not m3.indicator.any()


def test_resample_keeps_ends_and_spacing():
    pts = np.array([[0.0, 0.0], [0.0, 12.0], [9.0, 12.0]])
    r = resample(pts, 5.0)
    np.testing.assert_allclose(r[0], pts[0])
    np.testing.assert_allclose(r[-1], pts[-1])
    assert len(r) == 6  # 21 m of polyline every <= 5 m
    chords = np.hypot(*np.diff(r, axis=0).T)
    assert np.all(chords <= 21.0 / 5 + 1e-9) and np.all(chords > 2.5)


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_catalogue_transaction_rolls_back_and_spatial_index_finds_paths(tmp_path, backend, request):
    if backend == "sqlite":
        cat = SqliteCatalogue(tmp_path / "c.sqlite", create=True)
    else:
        cat = PostgresCatalogue(request.getfixturevalue("pg_url"), "egovid_unit_test", create=True)
    with cat.transaction():
        d = cat.add_drive("a", "a.mp4", "a.gpx", 0.0, 30.0, 64, 48, 10)
        cat.add_path(_line(100), d)
    with pytest.raises(RuntimeError), cat.transaction():
        cat.add_drive("b", "b.mp4", "b.gpx", 0.0, 30.0, 64, 48, 10)
        cat.add_path(_line(5, y=1000.0), None)
        raise RuntimeError("crash in the middle of an ingest")
    assert [x.name for x in cat.drives()] == ["a"]
    assert len(cat.paths()) == 1
    assert cat.paths_near(240, -1, 260, 1) == [1]
    assert cat.paths_near(240, 900, 260, 1100) == []
    assert cat.paths_near(495, 0, 600, 10) == [1]  # touching the last point's box counts
    assert cat.paths_near(495.5, 0, 600, 10) == []
    pid = cat.paths()[0].id
    with cat.transaction():
        cat.update_path(pid, _line(10, y=1000.0))  # moved: the index follows
    assert cat.paths_near(240, -1, 260, 1) == [] and cat.paths_near(20, 990, 30, 1010) == [pid]
    np.testing.assert_array_equal(cat.path(pid).points, _line(10, y=1000.0))
    cat.close()
    assert project([40.0], [-86.0], (40.0, -86.0)).tolist() == [[0.0, 0.0]]


def test_postgresql_catalogue_that_loses_its_server_says_so(pg_url):
    import psycopg

    cat = PostgresCatalogue(pg_url, "egovid_lost_test", create=True)
    with psycopg.connect(pg_url, autocommit=True) as admin:
        pid = cat._db.info.backend_pid
        admin.execute("SELECT pg_terminate_backend(%s)", (pid,))
    with pytest.raises(EgovidError, match="lost the PostgreSQL catalogue"):
        cat.drives()
    with pytest.raises(EgovidError, match="is missing from"):
        PostgresCatalogue(pg_url, "egovid_no_such_schema")


def test_tamura_contrast_and_rank_scores_by_hand():
    # Two grey levels, half each: sigma = 50, kurtosis = 1, so C = 50 in every quadrant.
    img = np.zeros((8, 8), np.uint8)
    img[:, ::2] = 100
    f = frame_features(img)
    np.testing.assert_allclose(f, [50, 50] * 4)
    new = np.array([100.0, 40] * 4)
    cands = {
        1: np.array([100.0, 40] * 4),
        2: np.array([90.0, 40] * 4),
        3: np.array([100.0, 40, 100, 40, 100, 40, 10, 5]),
    }
    scores = rank_scores(new, cands)
    # Candidate 1 is best in every quadrant (3 points x 4); 3 ties with 1 in three quadrants.
    assert scores[1] == 12 and scores[2] < scores[3]
    assert best_match(new, cands) == 1
    assert best_match(new, {9: np.array([250.0, 5] * 4)}) is None  # no usable light: a root


def test_stops_need_low_speed_no_turning_and_duration():
    fps = 10.0
    speed = np.array([5.0] * 10 + [0.1] * 10 + [5.0] * 5 + [0.1] * 2 + [5.0] * 5)
    bearing = np.zeros(len(speed))
    s = stopped_frames(speed, bearing, fps)
    assert s[10:20].all() and not s[:10].any() and not s[25:27].any()
    turning = np.cumsum(np.where(speed < 1, 3.0, 0.0))  # 30°/s while slow: still aligned
    assert not stopped_frames(speed, turning, fps).any()


def _i420(rng, w, h, base=None, shift=0):
    if base is None:
        base = rng.integers(0, 256, (h * 3 // 2, w + 8), dtype=np.uint8)
    return np.ascontiguousarray(base[:, shift : shift + w]), base


@pytest.mark.parametrize(
    ("kind", "gop", "refresh", "realtime"),
    [
        ("none", 1, 0, False),
        ("gain", 1, 0, False),
        ("similarity", 1, 0, False),
        ("none", 4, 0, False),
        ("gain", 4, 0, False),
        ("none", 4, 5, False),
        ("none", 1, 4, False),
        ("none", 4, 5, True),  # realtime: runs start key, hold, ra (START_BASELINE_HELD)
    ],
)
def test_injected_reference_decodes_bit_exactly(kind, gop, refresh, realtime):
    rng = np.random.default_rng(1)
    w, h, n = 64, 48, 11  # with gop 4: key 0, p 1, anchors 5, 9 and a one-frame last chunk (10)
    _ref, base = _i420(rng, w, h)
    frames = [np.roll(_i420(rng, w, h, base, k % 4)[0], 1, axis=1) for k in range(n)]
    refs = [_i420(rng, w, h, base, k % 4)[0] for k in range(n)]
    params = {"none": None, "gain": [70, -300], "similarity": [4096, 10, 30, -10, 4096, -20]}[kind]
    asked = []

    def baseline(k):  # frame 5 has none (the car stood still): with refresh 5 its run starts with a keyframe
        asked.append(k)
        return None if k == 5 else codec.apply_alignment(vpx.pad_i420(refs[k], w, h), w, h, kind, params)

    recon = []
    settings = EncoderSettings(
        q=30, speed=9 if realtime else 6, realtime=realtime, gop=gop, refresh=refresh, start_speed=5 if realtime else 0
    )
    enc = codec.encode_segment(iter(frames), w, h, settings, baseline, keep_recon=recon, verify=True)
    sb = codec.parse(enc.blob)
    runs = codec.substreams(n, refresh)
    joint_start = codec.START_BASELINE_HELD if realtime else codec.START_BASELINE
    assert sb.starts == tuple(codec.START_KEY if k0 == 5 else joint_start for k0, _ in runs)
    assert enc.blob[4:6] == (b"\x04\x00" if realtime else b"\x03\x00")  # version 4 only with held starts
    lay, _ = codec.parse_header(enc.blob)  # one run per random-access period, however it starts
    assert len(lay.run_packets()) == len(runs) and len(codec.run_offsets(enc.blob)) == len(runs) + 1
    assert [lay.plan()[p0][1] for p0, _ in lay.run_packets()] == ["key" if s == 0 else "dummy" for s in sb.starts]
    if realtime:  # a held start in a version-3 header is damage (version-3 readers do not know it)
        with pytest.raises(EgovidError, match="inconsistent layout"):
            codec.parse(enc.blob[:4] + b"\x03\x00" + enc.blob[6:])
    decoded = list(codec.decode_segment(enc.blob, baseline))
    assert len(decoded) == n == len(enc.bytes_per_frame) == enc.frames
    assert all(np.array_equal(a, b) for a, b in zip(decoded, recon, strict=True))
    # One digest per random-access run (none for a single run), each over that run's pictures.
    want = []
    for k0, m in runs if refresh else []:
        hr = hashlib.sha256()
        for f in recon[k0 : k0 + m]:
            hr.update(f.tobytes())
        want.append(hr.hexdigest()[: codec.RUN_DIGEST_CHARS])
    assert enc.run_digests == want
    # Decoding from a later frame gives the same pictures (display order, whatever the coding order)
    # and, with random-access runs, never touches the frames of the runs before.
    asked.clear()
    later = list(codec.decode_segment(enc.blob, baseline, 6))
    assert len(later) == n - 6 and all(np.array_equal(a, b) for a, b in zip(later, recon[6:], strict=True))
    first = codec.run_start(enc.blob, 6)
    assert first == (5 if refresh == 5 else 4 if refresh == 4 else 0) and min(asked) >= first
    # Without the baseline the pictures are wrong: the reference really is used.
    blind = list(codec.decode_segment(enc.blob))
    assert not all(np.array_equal(a, b) for a, b in zip(blind, recon, strict=True))
    # The reconstruction is the source up to quantisation, frame by frame (no reordering mix-up).
    for src, rec in zip(frames, recon, strict=True):
        assert np.mean(np.abs(src[:h].astype(int) - rec[:h].astype(int))) < 12


@pytest.mark.parametrize("realtime", [False, True])
def test_a_run_started_from_the_baseline_is_cheaper_than_a_keyframe(realtime):
    """The first frame of a joint run is predicted from the older drive (the thesis' inter-view P
    picture) instead of coded intra: with a baseline close to it, it must cost far less. At the
    realtime deadline this needs the hold frame after the grey keyframe (libvpx's realtime mode
    decision skips GOLDEN right after a keyframe: without it the frame came out intra, 3077 vs
    3061 bytes here)."""
    rng = np.random.default_rng(7)
    w, h = 64, 48
    frames, refs = [], []
    for _ in range(3):
        ref, base = _i420(rng, w, h)
        refs.append(ref)
        frames.append(_i420(rng, w, h, base, 1)[0])
    settings = EncoderSettings(q=20, speed=9 if realtime else 6, realtime=realtime, refresh=2)

    def baseline(k):
        return vpx.pad_i420(refs[k], w, h)

    joint = codec.encode_segment(iter(frames), w, h, settings, baseline)
    plain = codec.encode_segment(iter(frames), w, h, settings)
    held = codec.START_BASELINE_HELD if realtime else codec.START_BASELINE
    assert codec.parse(joint.blob).starts == (held, held) and codec.parse(plain.blob).starts == (0, 0)
    for k in (0, 2):  # the run starts: grey keyframe + ra frame vs a keyframe
        assert joint.bytes_per_frame[k] < 0.5 * plain.bytes_per_frame[k]


def test_the_verifying_decoder_follows_the_chosen_runs_and_catches_a_wrong_picture_there(monkeypatch):
    """``verify_runs`` picks the random-access runs the decoder follows: it decodes exactly their
    packets (each run begins with a keyframe, so skipping the others is safe), a picture it gets
    wrong in a followed run stops the encode, one in a skipped run is never looked at; the
    per-run digests come from the encoder's pictures either way."""
    rng = np.random.default_rng(3)
    w, h, n, refresh = 64, 48, 20, 4  # 5 runs
    _ref, base = _i420(rng, w, h)
    frames = [_i420(rng, w, h, base, k % 6)[0] for k in range(n)]
    settings = EncoderSettings(q=30, speed=6, gop=2, refresh=refresh)
    plan = codec.coding_plan(n, 2, refresh, [codec.START_KEY] * 5)
    real = vpx.VP9Decoder.decode
    decoded: list[int] = []
    spoil: set[int] = set()

    def counting(self, packet, golden=None, last=None):
        decoded.append(len(packet))
        return real(self, packet, golden, last)

    vpx.self_test()  # its own decodes, once per process
    monkeypatch.setattr(vpx.VP9Decoder, "decode", counting)
    full = codec.encode_segment(iter(frames), w, h, settings, verify=True)
    assert len(decoded) == len(plan)
    decoded.clear()
    some = codec.encode_segment(iter(frames), w, h, settings, verify=True, verify_runs=lambda i: i in (0, 3))
    assert len(decoded) == 2 * refresh  # runs 0 and 3, four packets each
    assert some.blob == full.blob and some.run_digests == full.run_digests and len(full.run_digests) == 5

    packet_frame = {}

    def wrong(self, packet, golden=None, last=None):
        out = real(self, packet, golden, last)
        k = packet_frame[id(self)] = packet_frame.get(id(self), -1) + 1
        if k in spoil:
            out = out.copy()
            out[0, 0] ^= 1
        return out

    monkeypatch.setattr(vpx.VP9Decoder, "decode", wrong)
    # The decoder's k-th packet: with runs 0 and 3 followed, packets 0-3 are run 0, 4-7 run 3.
    spoil.add(5)
    with pytest.raises(EgovidError, match="does not reproduce"):
        codec.encode_segment(iter(frames), w, h, settings, verify=True, verify_runs=lambda i: i in (0, 3))
    packet_frame.clear()
    spoil.clear()
    spoil.add(9)  # would be run 2's second packet were it followed
    codec.encode_segment(iter(frames), w, h, settings, verify=True, verify_runs=lambda i: i in (0, 3))
    packet_frame.clear()
    with pytest.raises(EgovidError, match="does not reproduce"):
        codec.encode_segment(iter(frames), w, h, settings, verify=True)


def test_verified_runs_are_the_first_the_last_and_a_seeded_share_of_the_rest():
    from egovid.dashcam.ingest.options import IngestOptions

    n = 400
    picks = IngestOptions.from_preset("realtime").verified_runs(n, seed=7)
    chosen = [i for i in range(n) if picks(i)]
    again = IngestOptions.from_preset("realtime").verified_runs(n, seed=7)
    assert chosen == [i for i in range(n) if again(i)]
    assert chosen[0] == 0 and chosen[-1] == n - 1
    assert 0.18 < (len(chosen) - 2) / (n - 2) < 0.32  # the realtime preset's quarter
    other = IngestOptions.from_preset("realtime").verified_runs(n, seed=8)
    assert chosen != [i for i in range(n) if other(i)]
    for preset in ("balanced", "archive"):
        every = IngestOptions.from_preset(preset).verified_runs(n, seed=7)
        assert all(every(i) for i in range(n))
    with pytest.raises(EgovidError, match="outside"):
        IngestOptions(verify_share=0.0).check()


@pytest.mark.parametrize(("gop", "refresh"), [(1, 0), (2, 0), (3, 0), (8, 0), (1, 4), (3, 7), (8, 8), (8, 32)])
@pytest.mark.parametrize("n", [1, 2, 3, 9, 10, 17, 30, 70])
def test_coding_plan_codes_every_frame_once_after_its_references(n, gop, refresh):
    runs = codec.substreams(n, refresh)
    starts = [i % 3 for i in range(len(runs))]  # keyframe / baseline / held baseline starts in turn
    plan = codec.coding_plan(n, gop, refresh, starts)
    assert sorted(k for k, role, _ in plan if role != "dummy") == list(range(n))
    assert sum(role == "dummy" for _, role, _ in plan) == sum(starts)  # one or two undisplayed frames
    run_of = {k: i for i, (k0, m) in enumerate(runs) for k in range(k0, k0 + m)}
    done: set[int] = set()
    anchors = [k for k, role, _ in plan if role in ("key", "ra", "p", "anchor")]
    for pos, (k, role, last) in enumerate(plan):
        k0 = runs[run_of[k]][0]
        if role == "dummy":
            assert k == k0 and starts[run_of[k]] in (1, 2) and (k, "ra", None) in plan[pos + 1 : pos + 3]
            continue
        if role in ("key", "ra"):  # a run starts clean: nothing of it coded yet
            assert k == k0 and not done & set(range(k0, k0 + runs[run_of[k]][1]))
            assert (role == "ra") == (starts[run_of[k]] != 0)
        elif role == "p":
            assert k - 1 in done and run_of[k - 1] == run_of[k] and (gop == 1 or k == k0 + 1)
        elif role == "anchor":
            assert last in done and last < k and k - last <= gop and run_of[last] == run_of[k]
        else:  # between: LAST holds the previous frame, ALTREF the anchor ahead (same run)
            assert role == "between" and k - 1 in done and run_of[k - 1] == run_of[k]
            ahead = min(a for a in anchors if a > k)
            assert ahead in done and run_of[ahead] == run_of[k]
        done.add(k)
    for k0, m in runs:
        if gop > 1 and m > 2:
            assert max(k for k, role, _ in plan if role == "anchor" and run_of[k] == run_of[k0]) == k0 + m - 1


def test_version_1_and_2_low_delay_blobs_still_decode():
    rng = np.random.default_rng(4)
    frames = [_i420(rng, 32, 32)[0] for _ in range(4)]
    recon = []
    blob = codec.encode_segment(iter(frames), 32, 32, EncoderSettings(q=40, speed=8), keep_recon=recon).blob
    sb = codec.parse(blob)
    for version, gop in ((1, 0), (2, 1)):  # version 1 had no GOP, versions 1-2 no run layout
        head = codec._HEADER.pack(codec.MAGIC, version, 32, 32, 32, 32, len(sb.packets), sb.q, gop)
        old = head + b"".join(len(p).to_bytes(4, "little") + p for p in sb.packets)
        assert all(np.array_equal(a, b) for a, b in zip(codec.decode_segment(old), recon, strict=True))


def test_damaged_blob_is_refused():
    rng = np.random.default_rng(2)
    frames = [_i420(rng, 32, 32)[0] for _ in range(2)]
    blob = codec.encode_segment(iter(frames), 32, 32, EncoderSettings(q=40, speed=8)).blob
    with pytest.raises(EgovidError, match="truncated"):
        codec.parse(blob[:-5])
    with pytest.raises(EgovidError, match="format"):
        codec.parse(b"XXXX" + blob[4:])


def test_seqslam_recovers_a_shifted_sequence():
    rng = np.random.default_rng(3)
    ref = [np.clip(rng.normal(128, 40, (72, 128)), 0, 255).astype(np.uint8) for _ in range(80)]
    ref = [
        np.ascontiguousarray(np.roll(ref[0], 3 * k, axis=1) * 0.5 + r * 0.5).astype(np.uint8) for k, r in enumerate(ref)
    ]
    new = ref[10:60]
    prior = np.arange(10, 60) + rng.normal(0, 5, 50)
    res = align_seqslam(np.stack([descriptor(g) for g in new]), np.stack([descriptor(g) for g in ref]), prior)
    assert np.mean(res.refmap[10:] == np.arange(20, 60)) > 0.95


def test_baselines_fetch_the_older_drive_forward_in_coding_order():
    """Coding order asks for an anchor's baseline before the frames behind it; the older drive must
    still be read forward (a jump in its frame numbers — it stood still — would otherwise restart
    its decoding from the keyframe)."""
    from egovid.dashcam.extract import baseline_builder

    class Recorder:
        def __init__(self):
            self.asked = []

        def get(self, idx):
            self.asked.append(idx)
            return np.full((72, 64), idx % 256, np.uint8)

    refmap = np.array([0, 1, 2, 3, 300, 301, 302, 303, 304, 305, 306, 307, 308, 309, 310, 311, 312])
    rec = Recorder()
    build = baseline_builder(rec, refmap, 64, 48, {"kind": "none"})
    for k, role, _ in codec.coding_plan(len(refmap), 8):
        if role in ("anchor", "between"):
            assert int(build(k)[0, 0]) == refmap[k] % 256  # the right frame, whatever the order
    assert rec.asked == sorted(rec.asked)


def _zoomed(img, z, dx=0.0):
    """A 320x180 view of ``img`` magnified by ``z`` about (160, 70), shifted right by ``dx`` px:
    what a forward-moving camera sees (up to parallax), sideways offset included."""
    import cv2

    m = np.array([[z, 0.0, (1 - z) * 160.0 + dx], [0.0, z, (1 - z) * 70.0]])
    return cv2.warpAffine(cv2.resize(img, (320, 180)), m, (320, 180), flags=cv2.INTER_LINEAR)


def test_vertical_scale_measures_zoom_and_ignores_sideways_shift():
    from egovid.dashcam.align.orb import ScaleRefiner, vertical_log_scale
    from egovid.synth.photos import photo

    img = photo("astronaut")
    img = img if img.ndim == 2 else img.mean(axis=2).astype(np.uint8)
    rf = ScaleRefiner()
    a = rf.features(_zoomed(img, 1.0))
    for z, dx in ((1.05, 0.0), (0.97, 0.0), (1.04, -5.0)):
        assert abs(vertical_log_scale(a, rf.features(_zoomed(img, z, dx))) - np.log(z)) < 0.003
    assert abs(vertical_log_scale(a, rf.features(_zoomed(img, 1.0, 6.0)))) < 0.002


def test_scale_refiner_finds_the_frame_level_with_the_new_one():
    """Reference frames every unit of road (0-17), new frames every 1.12 units from -1.4 on, 4 px to
    the side, with a stop: it starts before the older drive and ends after it. Matches that start
    up to 2 frames off must end on the nearest reference frame, and never outside the older drive."""
    from egovid.dashcam.align.orb import ScaleRefiner
    from egovid.synth.photos import photo

    img = photo("astronaut")
    img = img if img.ndim == 2 else img.mean(axis=2).astype(np.uint8)
    zoom = lambda t: float(np.exp(0.02 * t))  # noqa: E731 - magnification after t units of road
    stopped = np.zeros(24, bool)
    stopped[12:16] = True  # a stop: the camera stays where it is
    t_new = -1.4 + np.concatenate([[0.0], np.cumsum(np.where(stopped[1:], 0.0, 1.12))])
    rf = ScaleRefiner()
    ref = [rf.features(_zoomed(img, zoom(j))) for j in range(18)]
    new = [rf.features(_zoomed(img, zoom(t), dx=4.0)) for t in t_new]
    truth = np.clip(np.round(t_new), 0, 17).astype(int)
    start = np.clip(truth + np.random.default_rng(0).integers(-2, 3, len(truth)), 0, 17)
    got = rf.refine(start, new, ref, stopped)
    assert got.min() >= 0 and got.max() <= 17
    assert np.mean(got == truth) >= 0.85 and np.max(np.abs(got - truth)) <= 1
    assert np.all(got[12:16] == got[11]) and np.all(np.diff(got) >= 0)


def test_a_track_covering_less_than_80_percent_of_the_video_is_refused():
    """The stages' coverage check is the clock's rule (hand-computed spans)."""
    from egovid.core.errors import EgovidError
    from egovid.dashcam.ingest.stages import check_coverage
    from egovid.dashcam.route.tracks import GpsTrack

    t = 1777881600.0 + np.arange(101.0)  # fixes over 100 s
    track = GpsTrack(t, np.full(101, 40.0), np.full(101, -86.0), np.ones(101), np.zeros(101), "log.gpx")
    check_coverage(track, t[10] + np.arange(0.0, 100.1, 0.5), "v.mp4", "log.gpx")  # 90 of 100 s
    with pytest.raises(EgovidError, match=r"covers 50% of video v\.mp4"):
        check_coverage(track, t[50] + np.arange(0.0, 100.1, 0.5), "v.mp4", "log.gpx")


def test_the_joint_or_standalone_choice_compares_at_equal_quality_by_hand():
    """keep_joint moves the joint bytes to the standalone's PSNR-Y along 2 dB per halving: a joint
    encode of the same size and higher quality always wins; one of lower quality costs more."""
    assert DB_PER_HALVING == 2.0
    assert keep_joint((1000, 36.0), (1000, 35.0))[0]  # same bytes, 1 dB better: joint
    assert not keep_joint((1000, 34.0), (1000, 35.0))[0]  # same bytes, 1 dB worse: standalone
    # 1200 B at 38 dB = 600 B at 36 dB (one halving per 2 dB) < 700 B: joint, though larger
    kept, why = keep_joint((1200, 38.0), (700, 36.0))
    assert kept and "= 600 B at 36.00 dB" in why
    # 500 B at 34 dB = 1000 B at 36 dB > 900 B: standalone, though smaller
    kept, why = keep_joint((500, 34.0), (900, 36.0))
    assert not kept and "= 1000 B at 36.00 dB" in why
