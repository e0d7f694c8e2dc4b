"""The ingest pipeline's stages on their own: streamed alignment against the whole-sequence
aligners, the matcher against OpenCV's, one decode pass with bounded memory."""

import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest

from egovid.dashcam.align import ALIGNERS
from egovid.dashcam.align.orb import (
    OrbScorer,
    ScaleRefiner,
    align_orb,
    cross_check_matches,
    smooth_monotone,
)
from egovid.dashcam.align.seqslam import align_seqslam, descriptor
from egovid.dashcam.ingest.frames import RefFrames
from egovid.dashcam.ingest.options import IngestOptions

#: Standalone pieces in VP9, as before AV1: the joint encode is then the smaller, so these tests
#: get the joint pieces they check (with AV1 standalone pieces they would be stored standalone).
VP9 = IngestOptions(codec="vp9")


def test_cross_check_matches_are_opencvs():
    rng = np.random.default_rng(5)
    a = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    b = np.concatenate([a[::2] ^ rng.integers(0, 2, (150, 32), dtype=np.uint8), a[:40]])  # near and exact copies
    want = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(a, b)
    qi, ti = cross_check_matches(a, b)
    assert [(m.queryIdx, m.trainIdx) for m in want] == list(zip(qi.tolist(), ti.tolist(), strict=True))
    assert len(qi) > 100


def _view(img, z):
    """A 320x180 view of ``img`` magnified by ``z`` about (160, 70): a camera moving forward."""
    m = np.array([[z, 0.0, (1 - z) * 160.0], [0.0, z, (1 - z) * 70.0]])
    return cv2.warpAffine(img, m, (320, 180), flags=cv2.INTER_LINEAR)


class MemoryRef(RefFrames):
    """The baseline's sequence as grey frames in memory."""

    def __init__(self, grays):
        self.m, self._grays = len(grays), grays
        self.scorer, self.refiner = OrbScorer(), ScaleRefiner()
        self._image, self._gray, self._feats, self._fine, self._desc = {}, {}, {}, {}, {}
        self._released = 0
        self.low = 0

    def gray(self, j):
        assert j >= self.low, f"frame {j} asked for after the alignment said it needs none below {self.low}"
        return self._grays[j]


@pytest.fixture(scope="module")
def sequences():
    img = cv2.resize(_photo(), (320, 180))
    ref = [_view(img, 1.0 + 0.012 * j) for j in range(70)]
    zs = [1.0 + 0.012 * (4 + 0.8 * k) for k in range(50)]
    zs[18:26] = [zs[18]] * 8  # a stop
    new = [_view(img, z) for z in zs]
    stopped = np.zeros(50, bool)
    stopped[19:26] = True
    rng = np.random.default_rng(2)
    prior = np.array([4 + 0.8 * min(k, 18) + 0.8 * max(0, k - 25) for k in range(50)]) + rng.normal(0, 3, 50)
    return ref, new, stopped, prior


def _photo():
    from skimage import data

    return cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY)


@pytest.mark.parametrize("kind", ["orb", "orb-plain", "seqslam", "gps"])
def test_streamed_alignment_gives_the_whole_sequence_aligners_matches(sequences, kind):
    """Frame by frame, with each match final at most 24 frames after its frame, the streamed
    alignment equals the aligners run on whole sequences (as the archive did before it streamed)."""
    ref, new, stopped, prior = sequences
    speed_new = np.where(stopped, 0.0, 8.0)
    speed_ref = np.full(len(ref), 10.0)
    if kind in ("orb", "orb-plain"):
        sc, rf = OrbScorer(), ScaleRefiner()
        raw = align_orb(
            [sc.features(g) for g in new], [sc.features(g) for g in ref], prior, speed_new, speed_ref, stopped, 30.0, sc
        ).refmap
        want = (
            raw
            if kind == "orb-plain"
            else rf.refine(smooth_monotone(raw), [rf.features(g) for g in new], [rf.features(g) for g in ref], stopped)
        )
    elif kind == "seqslam":
        want = align_seqslam(
            np.stack([descriptor(g) for g in new]), np.stack([descriptor(g) for g in ref]), prior
        ).refmap
        for k in range(1, len(new)):
            if stopped[k]:
                want[k] = want[k - 1]
    else:
        want = np.clip(np.round(prior), 0, len(ref) - 1)
    mem = MemoryRef(ref)
    stream = ALIGNERS[kind](mem, prior, speed_new, speed_ref, stopped, 30.0)
    got, lag = [], 0
    for k, g in enumerate(new):
        got += stream.push(g)
        lag = max(lag, k + 1 - len(got))
        mem.release_below(stream.lowest_needed())
        mem.low = stream.lowest_needed()
    assert got == [int(v) for v in want]
    assert lag <= (24 if kind == "orb" else 0)  # two smoothing windows (more where a stretch begins)


def test_aligning_every_second_frame_searches_half_the_frames_and_keeps_the_matches(sequences):
    """``every`` = 2: half the moving frames are searched, the others interpolated; the matches
    stay within a frame of those of every frame searched (a steady zoom: the line is exact)."""
    ref, new, stopped, prior = sequences
    speed_new = np.where(stopped, 0.0, 8.0)
    speed_ref = np.full(len(ref), 10.0)
    got, searched = {}, {}
    for every in (1, 2):
        mem = MemoryRef(ref)
        stream = ALIGNERS["orb"](mem, prior, speed_new, speed_ref, stopped, 30.0, every)
        step, calls = stream.search.step, []
        stream.search.step = lambda k, f, step=step, calls=calls: calls.append(k) or step(k, f)
        out = []
        for g in new:
            out += stream.push(g)
            mem.release_below(stream.lowest_needed())
            mem.low = stream.lowest_needed()
        got[every], searched[every] = np.array(out), calls
    assert len(got[2]) == len(new)
    assert np.abs(got[2] - got[1]).max() <= 1
    moving_searched = [k for k in searched[2] if not stopped[k]]
    assert len(moving_searched) <= (int((~stopped).sum()) + 1) // 2 + 2  # + the last and the one before the stop
    assert len(searched[1]) == len(new)


def test_a_coarse_wide_search_finds_the_full_searchs_match_scoring_a_third_of_the_candidates(sequences):
    """The first frame is searched 1.5 s either side of its GPS prior; with ``coarse`` = 3 every
    3rd reference frame is scored, then the neighbours of the best: the same match, a third of the
    work (the frames after it search the same short range either way)."""
    from egovid.dashcam.align.orb import OrbSearch

    ref, new, stopped, prior = sequences
    sc = OrbScorer()
    ref_feats = [sc.features(g) for g in ref]
    new_feats = [sc.features(g) for g in new[:6]]
    got = {}
    for coarse in (1, 3):
        asked: list[int] = []
        search = OrbSearch(
            lambda j, asked=asked: asked.append(j) or ref_feats[j],
            len(ref),
            prior,
            np.where(stopped, 0.0, 8.0),
            np.full(len(ref), 10.0),
            stopped,
            30.0,
            OrbScorer(),
            coarse,
        )
        first = search.step(0, new_feats[0])
        n_first = len(asked)
        got[coarse] = (first, [search.step(k, new_feats[k]) for k in range(1, 6)], n_first, len(asked) - n_first)
    assert got[3][0] == got[1][0] and got[3][0][1] >= 12  # the same match, found by its inliers
    assert got[3][1] == got[1][1]
    assert got[1][2] >= 40 and got[3][2] <= got[1][2] // 3 + 5
    assert got[3][3] == got[1][3]


def test_the_default_options_are_the_default_preset_and_options_override_presets():
    from egovid.core.errors import EgovidError
    from egovid.dashcam.ingest.options import DEFAULT_PRESET, PRESETS, IngestOptions

    assert IngestOptions() == IngestOptions.from_preset(None) == IngestOptions.from_preset(DEFAULT_PRESET)
    for name, settings in PRESETS.items():
        opts = IngestOptions.from_preset(name, q=40, speed=None).check()
        assert opts.q == 40 and opts.preset == name and all(getattr(opts, k) == v for k, v in settings.items())
    with pytest.raises(EgovidError, match="unknown preset"):
        IngestOptions.from_preset("fastest")


class _CountingContainer:
    """An av container that counts the frames it decodes."""

    def __init__(self, container, counts, key):
        self._c, self._counts, self._key = container, counts, key

    def decode(self, *args, **kwargs):
        for frame in self._c.decode(*args, **kwargs):
            self._counts[self._key] = self._counts.get(self._key, 0) + 1
            yield frame

    def __getattr__(self, name):
        return getattr(self._c, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return self._c.__exit__(*exc)


def test_an_ingest_decodes_its_video_once_and_holds_few_frames(tmp_path, monkeypatch):
    """A joint drive of 10 s: FFmpeg decodes each of its frames once (plus the first, which probe
    looks at), and at most a few dozen frames of the two drives are in memory at any time."""
    import av

    from egovid.dashcam.archive.store import Archive
    from egovid.dashcam.ingest import ingest_videos
    from egovid.synth.drive import DriveSpec, Light, render_drive

    noon = Light.preset("noon")
    leg = [("main", 100.0, 200.0)]
    for name, spec in {
        "old": DriveSpec(legs=leg, cruise=10.0, seed=5, light=noon),
        "new": DriveSpec(legs=leg, cruise=9.0, stops=[(50.0, 1.0)], seed=6, light=noon),
    }.items():
        render_drive(spec, tmp_path / f"{name}.mp4", width=160, height=96)
    ar = Archive.create(tmp_path / "archive")
    ingest_videos(ar, [tmp_path / "old.mp4"], options=VP9)
    counts: dict = {}
    real_open = av.open
    monkeypatch.setattr(
        av, "open", lambda path, *a, **k: _CountingContainer(real_open(path, *a, **k), counts, str(path))
    )
    (rep,) = ingest_videos(ar, [tmp_path / "new.mp4"], options=VP9).reports
    assert [p.mode for p in rep.pieces] == ["joint"] and rep.frames > 300
    assert counts == {str(tmp_path / "new.mp4"): rep.frames + 1}
    assert 0 < max(p.peak_frames_held for p in rep.pieces) < 80


def test_read_ahead_keeps_order_hands_errors_on_and_stops_when_closed():
    import threading

    from egovid.dashcam.extract import read_ahead

    assert list(read_ahead(iter(range(50)), 3)) == list(range(50))

    def failing():
        yield 1
        raise ValueError("boom")

    it = read_ahead(failing(), 2)
    assert next(it) == 1
    with pytest.raises(ValueError, match="boom"):
        next(it)

    closed = threading.Event()

    def endless():
        try:
            yield from itertools.count()
        finally:
            closed.set()

    it = read_ahead(endless(), 2)
    assert next(it) == 0
    it.close()
    assert closed.is_set()  # the thread stopped and closed the source before close() returned


def _old_and_new_drive(folder) -> None:
    """old.mp4 and new.mp4 in ``folder``: the same 50 m of road at noon, 160x96, the new drive
    slower (a joint piece against the old one)."""
    from egovid.synth.drive import DriveSpec, Light, render_drive

    noon = Light.preset("noon")
    leg = [("main", 100.0, 150.0)]
    for name, spec in {
        "old": DriveSpec(legs=leg, cruise=10.0, seed=5, light=noon),
        "new": DriveSpec(legs=leg, cruise=9.0, seed=6, light=noon),
    }.items():
        render_drive(spec, folder / f"{name}.mp4", width=160, height=96)


def test_the_older_drive_read_while_the_baseline_is_chosen_changes_nothing_or_is_dropped(tmp_path, monkeypatch):
    """The older drive the first frame's light points to is decoded (and its features computed)
    while the piece's first 24 frames choose the baseline. Taken: the joint segment is bit for bit
    the one coded without it. The choice disagreeing: it is dropped, its threads stop, and the piece
    is coded as the choice says."""
    import shutil
    import threading

    from egovid.dashcam.archive.store import Archive, open_archive
    from egovid.dashcam.ingest import ingest_videos
    from egovid.dashcam.ingest import piece as piece_mod

    _old_and_new_drive(tmp_path)
    base = tmp_path / "base"
    ingest_videos(Archive.create(base), [tmp_path / "old.mp4"], options=VP9)

    def run(name: str):
        shutil.copytree(base, tmp_path / name)
        ar = open_archive(tmp_path / name)
        (rep,) = ingest_videos(ar, [tmp_path / "new.mp4"], options=VP9).reports
        return rep, [(s.mode, s.blob, s.params["recon_digest"], s.refmap.tolist()) for s in ar.segments(rep.drive_id)]

    taken = []
    real_take = piece_mod._Prefetch.take
    monkeypatch.setattr(piece_mod._Prefetch, "take", lambda self: taken.append(1) or real_take(self))
    rep, with_prefetch = run("with")
    assert taken == [1] and [p.mode for p in rep.pieces] == ["joint"]

    monkeypatch.setattr(piece_mod._PieceRun, "_start_prefetch", lambda self: None)
    _, without = run("without")
    assert with_prefetch == without

    monkeypatch.undo()
    calls = []
    real_choose = piece_mod.choose_baseline

    def changing_mind(illum, candidates):
        calls.append(1)
        return real_choose(illum, candidates) if len(calls) == 1 else None  # the light of frame 0 only

    started = []
    real_init = piece_mod._Prefetch.__init__
    monkeypatch.setattr(piece_mod, "choose_baseline", changing_mind)
    monkeypatch.setattr(piece_mod._Prefetch, "__init__", lambda self, *a: started.append(1) or real_init(self, *a))
    before = set(threading.enumerate())
    rep, dropped = run("dropped")
    assert started == [1] and [s[0] for s in dropped] == ["intra"]
    left = [t.name for t in set(threading.enumerate()) - before if t.name.startswith("egovid-")]
    assert left == []  # the older drive's decoder stopped with the read-ahead


def test_an_interrupt_while_the_encoders_open_leaves_no_thread_reading_the_older_drive(tmp_path, monkeypatch):
    """SIGTERM (the CLI raises it as a BaseException) can land after the baseline was chosen and
    before the producer takes the older drive read ahead for it. The prefetch thread was then left
    decoding: the ingest's clean-up closed that decoder under it ("generator already executing",
    an internal error instead of "interrupted") and the interpreter ended the thread inside
    OpenCV/FFmpeg at exit (abort, exit status -6; seen in a full test run). Now the interrupt
    comes out as itself and no egovid thread is left."""
    import threading

    from egovid.dashcam.archive.store import Archive
    from egovid.dashcam.ingest import ingest_videos
    from egovid.dashcam.ingest import piece as piece_mod

    class Stop(BaseException):
        pass

    _old_and_new_drive(tmp_path)
    ar = Archive.create(tmp_path / "archive")
    ingest_videos(ar, [tmp_path / "old.mp4"], options=VP9)

    prefetching = []

    def interrupted(self, run, *a, **k):
        prefetching.append(run.prefetch is not None and run.prefetch.thread.is_alive())
        raise Stop

    monkeypatch.setattr(piece_mod._Encoders, "__init__", interrupted)
    before = set(threading.enumerate())
    with pytest.raises(Stop):
        ingest_videos(ar, [tmp_path / "new.mp4"], options=VP9)
    assert prefetching == [True]  # the premise: the older drive was being read when the interrupt came
    left = [t.name for t in set(threading.enumerate()) - before if t.name.startswith("egovid-") and t.is_alive()]
    assert left == []


def test_the_older_drives_frames_passed_on_the_way_are_kept_not_decoded_again(tmp_path, monkeypatch):
    """A wide search scores every 3rd frame of the older drive and then asks for the ones between:
    each frame is decoded once (they were decoded again from their random-access run), and is the
    frame extract gives."""
    from egovid.dashcam import extract
    from egovid.dashcam.archive.store import Archive
    from egovid.dashcam.ingest import ingest_videos
    from egovid.synth.drive import DriveSpec, Light, render_drive

    render_drive(
        DriveSpec(legs=[("main", 100.0, 130.0)], cruise=10.0, seed=5, light=Light.preset("noon")),
        tmp_path / "old.mp4",
        width=160,
        height=96,
    )
    ar = Archive.create(tmp_path / "archive")
    (rep,) = ingest_videos(ar, [tmp_path / "old.mp4"], options=VP9).reports
    (seg,) = ar.segments(rep.drive_id)
    truth = list(extract.segment_frames(ar, seg))
    decoded = []
    real = extract.segment_frames

    def counting(source, s, start=0, stop=None):
        for i, frame in enumerate(real(source, s, start, stop)):
            decoded.append(start + i)
            yield frame

    monkeypatch.setattr(extract, "segment_frames", counting)
    refs = RefFrames(ar, rep.drive_id, seg.frame_start, 60, (160, 96), {})
    try:
        for j in [*range(0, 45, 3), *range(45), *range(40, 60)]:
            assert np.array_equal(refs.image(j), truth[j])
    finally:
        refs.close()
    assert len(decoded) == len(set(decoded)) and set(range(60)) <= set(decoded)


def test_the_aligner_registry_is_what_the_cli_offers_and_checks():
    """``--aligner`` names every registered aligner (its help is written out, so that ``--help``
    does not load OpenCV), the default first, and the options refuse a name not registered."""
    import inspect

    from egovid.cli import dashcam as cli
    from egovid.core.errors import EgovidError
    from egovid.dashcam.align import DEFAULT_ALIGNER
    from egovid.dashcam.ingest.options import IngestOptions

    option = inspect.signature(cli.ingest).parameters["aligner"].default
    offered = [part.split()[0] for part in option.help.rstrip(".").split(" | ")]
    assert offered == list(ALIGNERS) and option.default == DEFAULT_ALIGNER == IngestOptions().aligner
    for name, cls in ALIGNERS.items():
        assert cls.name == name and IngestOptions(aligner=name).check().aligner == name
    with pytest.raises(EgovidError, match="choose one of orb, orb-plain, seqslam, gps"):
        IngestOptions(aligner="magic").check()


def test_a_trip_is_probed_and_demuxed_once_per_file(tmp_path, monkeypatch):
    """Two loop files of one drive through ingest_videos (the CLI's route): each file is probed
    once and demuxed for its frame times once (the examination's probe travels with the drive;
    the stages demuxed every file again, a batch a third time), then decoded once."""
    import collections
    import datetime as dt
    import importlib

    import av

    from egovid.core import video as core_video
    from egovid.dashcam.archive.store import Archive
    from egovid.dashcam.ingest import ingest_videos, sources, stages
    from egovid.synth.drive import DriveSpec, Light, render_drive

    day = dt.datetime(2026, 5, 4, 8, 0, 0, tzinfo=dt.UTC)
    video, gps, _ = render_drive(
        DriveSpec(legs=[("main", 100.0, 140.0)], cruise=10.0, seed=7, light=Light.preset("noon"), start_time=day),
        tmp_path / "whole.mp4",
        width=160,
        height=96,
        gps_format="nmea",
    )
    frames = [f.image for f in core_video.iter_frames(video, i420=True)]
    (tmp_path / "card").mkdir()
    for k, (a, b) in enumerate(itertools.pairwise([0, len(frames) // 2, len(frames)])):
        t = day + dt.timedelta(seconds=a / 30.0)
        with av.open(str(tmp_path / "card" / f"{t:%Y_%m%d_%H%M%S}_{k + 1:04d}F.MP4"), "w") as c:
            c.metadata["creation_time"] = t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
            s = c.add_stream("libx264", rate=30)
            s.width, s.height, s.pix_fmt, s.options = 160, 96, "yuv420p", {"qp": "0", "preset": "ultrafast"}
            for i, img in enumerate(frames[a:b]):
                vf = av.VideoFrame.from_ndarray(img, format="yuv420p")
                vf.pts = i
                c.mux(s.encode(vf))
            c.mux(s.encode())
    calls: dict = collections.defaultdict(collections.Counter)

    def counted(kind, real):
        return lambda path, *a, **k: calls[kind].update([Path(path).name]) or real(path, *a, **k)

    probing = importlib.import_module("egovid.core.video.probe")  # the module; `probe` is also its function
    real_times = probing.frame_times
    for mod in (core_video, probing, sources, stages):
        monkeypatch.setattr(mod, "frame_times", counted("frame times", real_times))
    monkeypatch.setattr(probing, "_probe", counted("probe", probing._probe))
    probing._PROBED.clear()
    ar = Archive.create(tmp_path / "archive")
    result = ingest_videos(ar, [tmp_path / "card"], gps=gps)
    (rep,) = result.reports
    names = sorted(p.name for p in (tmp_path / "card").iterdir())
    assert rep.frames == len(frames)
    assert result.to_dict()["files"] == [str((tmp_path / "card" / n).resolve()) for n in names]
    assert calls == {"frame times": collections.Counter(names), "probe": collections.Counter(names)}
