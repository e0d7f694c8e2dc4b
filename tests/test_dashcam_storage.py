"""Dashcam storage on its own: blob stores, byte-range reads, locks, path splitting replayed at
commit, GPS that would poison the archive."""

import threading

import numpy as np
import pytest

from egovid.core.errors import EgovidError
from egovid.dashcam.archive.blobs import FsspecBlobs, LocalBlobs
from egovid.dashcam.archive.catalogue import Segment, SqliteCatalogue
from egovid.dashcam.archive.locks import FileLocks, PgLocks
from egovid.dashcam.codec import segment as codec
from egovid.dashcam.codec.settings import EncoderSettings
from egovid.dashcam.extract import segment_frames
from egovid.dashcam.ingest.stages import CataloguePaths, PlannedPaths, split_path
from egovid.dashcam.route.tracks import read_track


@pytest.fixture(params=["local", "memory"])
def store(request, tmp_path):
    if request.param == "local":
        return LocalBlobs(tmp_path / "blobs")
    import uuid

    return FsspecBlobs(f"memory://egovid-{uuid.uuid4().hex}/blobs")


def test_blob_store_is_content_addressed_and_checks_what_it_reads(store):
    a = store.put(b"hello archive")
    assert store.put(b"hello archive") == a  # the same bytes are stored once
    assert store.get(a) == b"hello archive"
    assert store.read_range(a, 6, 13) == b"archive"
    assert [(f.name, f.size) for f in store.files()] == [(a, 13)]
    b = store.put(b"x" * 100)
    assert {f.name for f in store.files()} == {a, b} and store.total_bytes() == 113
    with pytest.raises(EgovidError, match="missing"):
        store.get("0" * 64)
    with pytest.raises(EgovidError, match="shorter"):
        store.read_range(a, 0, 50)
    store._write(a, b"tampered")  # damage the blob behind the store's back
    with pytest.raises(EgovidError, match="corrupt"):
        store.get(a)
    store.delete(a)
    assert [f.name for f in store.files()] == [b]


class CountingStore(LocalBlobs):
    """A local store that counts the bytes read."""

    read = 0

    def _read(self, sha):
        data = super()._read(sha)
        self.read += len(data)
        return data

    def _read_range(self, sha, start, end):
        self.read += end - start
        return super()._read_range(sha, start, end)


class Source:
    def __init__(self, blobs, segs):
        self.blobs, self._segs = blobs, segs

    def segments(self, drive_id):
        return self._segs[drive_id]


def test_a_stretch_is_read_by_byte_ranges_and_decodes_as_the_whole(tmp_path):
    rng = np.random.default_rng(1)
    w, h, n = 64, 48, 40
    base = rng.integers(0, 256, (h * 3 // 2 + 8, w + 40), dtype=np.uint8)
    frames = [np.ascontiguousarray(base[k % 8 : k % 8 + h * 3 // 2, k : k + w]) for k in range(n)]
    st = EncoderSettings(q=30, speed=6, gop=4, refresh=8)
    enc = codec.encode_segment(iter(frames), w, h, st)
    store = CountingStore(tmp_path / "blobs")
    sha = store.put(enc.blob)
    with open(tmp_path / "spool", "w+b") as spool:  # packets streamed to a file: the same blob
        spooled = codec.encode_segment(iter(frames), w, h, st, spool=spool)
        assert store.put_chunks(spooled.chunks(size=1000)) == sha and spooled.nbytes == len(enc.blob)
        assert spooled.run_offsets == enc.run_offsets == codec.run_offsets(enc.blob)
    params = {"width": w, "height": h, "refresh": 8, "run_digests": enc.run_digests}
    whole = Segment(1, 1, 0, n, "intra", None, np.full(n, -1), {}, sha, len(enc.blob), params)
    ranged = Segment(
        1,
        1,
        0,
        n,
        "intra",
        None,
        np.full(n, -1),
        {},
        sha,
        len(enc.blob),
        {**params, "run_offsets": codec.run_offsets(enc.blob)},
    )
    everything = list(segment_frames(Source(store, {}), whole))
    assert len(everything) == n
    store.read = 0
    part = list(segment_frames(Source(store, {}), ranged, 17, 21))
    assert all(np.array_equal(a, b) for a, b in zip(part, everything[17:21], strict=True)) and len(part) == 4
    offsets = ranged.params["run_offsets"]
    assert store.read == offsets[0] + offsets[3] - offsets[2] < len(enc.blob) / 3  # header + run 2 only


def _straight(n, step=5.0):
    return np.stack([np.arange(n) * step, np.zeros(n)], axis=1)


def test_split_path_cuts_the_path_and_its_sequences_the_same_in_plan_and_commit(tmp_path):
    """A path cut in three: it keeps the first part, the others become new paths that continue it
    exactly (no overlap), and an older drive's sequence is cut where it passes the cuts, with
    positions along the part it lands on. The plan (in memory) and the commit (catalogue) agree."""
    cat = SqliteCatalogue(tmp_path / "c.sqlite", create=True)
    with cat.transaction():
        d = cat.add_drive("old", "v", "g", 0.0, 30.0, 64, 48, 100)
        pid = cat.add_path(_straight(41), d)
        seg = cat.add_segment(d, 0, 100, "intra", None, np.full(100, -1), {}, "0" * 64, 1, {})
        cat.add_sequence(d, pid, 0, 100, np.linspace(0, 200, 100, dtype=np.float32), np.zeros(8), seg)
    plan = PlannedPaths(cat, [pid])
    keys = split_path(plan, pid, [0, 10, 25, 40])
    with cat.transaction():
        ids = split_path(CataloguePaths(cat, d), pid, [0, 10, 25, 40])
    assert ids[0] == pid and len(set(ids)) == 3
    for key, i in zip(keys, ids, strict=True):
        np.testing.assert_array_equal(plan.points(key), cat.path(i).points)
        got = [(s.frame_start, s.frame_end) for s in plan.sequences(key)]
        assert got == [(s.frame_start, s.frame_end) for s in cat.sequences(path_id=i)]
    lengths = [cat.path(i).length_m for i in ids]
    assert lengths == pytest.approx([50.0, 75.0, 75.0])
    np.testing.assert_array_equal(cat.path(ids[1]).points[0], cat.path(ids[0]).points[-1])
    seqs = [cat.sequences(path_id=i)[0] for i in ids]
    assert [s.frame_start for s in seqs] == [0, seqs[0].frame_end, seqs[1].frame_end] and seqs[2].frame_end == 100
    for s, length in zip(seqs, lengths, strict=True):
        assert s.positions.min() >= 0 and s.positions.max() <= length + 1e-3
    assert seqs[1].positions[0] < 3.0  # measured from the start of its own part


def test_a_gps_log_of_nans_is_refused_and_nans_among_fixes_are_dropped(tmp_path):
    pts = "".join(
        f'<trkpt lat="{la}" lon="{lo}"><time>2026-05-04T08:00:{i:02d}Z</time></trkpt>'
        for i, (la, lo) in enumerate([("nan", "nan")] * 5)
    )
    gpx = f'<?xml version="1.0"?><gpx version="1.1" creator="t"><trk><trkseg>{pts}</trkseg></trk></gpx>'
    (tmp_path / "nan.gpx").write_text(gpx)
    with pytest.raises(EgovidError, match="0 valid GPS fix"):
        read_track(tmp_path / "nan.gpx")
    rows = ["time,lat,lon"] + [f"{1777881600 + i},{40 + i * 1e-4 if i != 3 else 'nan'},-86.0" for i in range(6)]
    (tmp_path / "some.csv").write_text("\n".join(rows) + "\n")
    g = read_track(tmp_path / "some.csv")
    assert len(g) == 5 and g.dropped["not finite"] == 1 and np.all(np.isfinite(g.lat))


def _locks(kind, tmp_path, request):
    if kind == "files":
        return FileLocks(tmp_path)
    url = request.getfixturevalue("pg_url")
    return PgLocks(url, "egovid_locktest")


@pytest.mark.parametrize("kind", ["files", "postgresql"])
def test_area_locks_serialise_the_same_road_and_gc_refuses_while_an_ingest_runs(kind, tmp_path, request):
    locks = _locks(kind, tmp_path, request)
    events = []
    first_holds, second_waits, gc_tried, second_done = (threading.Event() for _ in range(4))

    def first():
        # Holds its area until the second ingest waits for it and gc has been tried, so a loaded
        # machine cannot let both finish before the main thread tries gc (CI saw that race).
        with locks.ingest() as s:
            s.acquire({"c1_1", "c2_1"})
            events.append("first has c1_1")
            first_holds.set()
            second_waits.wait(30)
            gc_tried.wait(30)
            events.append("first commits")

    def on_wait(_k):
        events.append("second waits")
        second_waits.set()

    def second():
        first_holds.wait(30)
        with locks.ingest(on_wait=on_wait) as s:
            s.acquire({"c9_9"})  # another place: free at once
            s.acquire({"c2_1"})  # below what it holds: released and taken again in order
            events.append("second has c2_1")
        second_done.set()

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for t in threads:
        t.start()
    assert first_holds.wait(30)
    try:
        with pytest.raises(EgovidError, match="busy"), locks.maintenance("gc"):
            pass
    finally:
        gc_tried.set()
    for t in threads:
        t.join(60)
    assert second_done.is_set() and second_waits.is_set()
    assert events == ["first has c1_1", "second waits", "first commits", "second has c2_1"]
    with locks.maintenance("gc"):  # nobody ingests now
        pass
