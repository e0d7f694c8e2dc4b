"""Encoders that stop responding (SVT-AV1 4.1.0 was seen to, under load): the ingest notices,
codes the piece again in fresh encoders from a fresh decode, and stores exactly what an
undisturbed ingest stores; an encoder that stalls every time ends the drive with one clear error
and nothing stored. The stall is injected through the ingest's ``watch`` argument (the codec's
hang itself cannot be reproduced on demand)."""

from __future__ import annotations

import threading
import time

import pytest

from egovid.dashcam.archive.store import Archive
from egovid.dashcam.codec import registry
from egovid.dashcam.codec.segment import EncoderFaultError
from egovid.dashcam.ingest import DriveInput, IngestOptions, ingest_drive
from egovid.dashcam.ingest.watchdog import EncoderStallError, EncoderWatch, Heartbeat
from egovid.synth.drive import DriveSpec, Light, render_drive

from conftest import run_cli

W, H = 192, 108
STALL_S = 3.0


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    d = tmp_path_factory.mktemp("watch")
    noon = Light.preset("noon")
    out = {}
    for name, seed, cruise in (("a", 1, 11.0), ("b", 2, 10.0)):
        spec = DriveSpec(legs=[("main", 380.0, 410.0)], cruise=cruise, seed=seed, light=noon)
        out[name] = render_drive(spec, d / f"{name}.mp4", width=W, height=H)[:2]
    return out


class Stalls:
    """An encode function whose codec keeps control of its first frame (it waits, as SVT-AV1's
    threads did on their semaphore) on the calls listed in ``on``; the others are the registry's."""

    def __init__(self, on: set[int]) -> None:
        self.on, self.calls = on, 0
        self.release = threading.Event()
        self.lock = threading.Lock()

    def __call__(self, frames, *args, **kwargs):
        with self.lock:
            call, self.calls = self.calls, self.calls + 1
        if call in self.on:
            next(iter(frames))  # the codec has a frame ...
            self.release.wait(60)  # ... and keeps it (released at the test's end: no thread outlives it)
            raise RuntimeError("released")
        return registry.encode_segment(frames, *args, **kwargs)


def _archive(tmp_path, name):
    root = tmp_path / name
    assert run_cli("dashcam", "init", root).returncode == 0
    return Archive(root)


def _ingest(ar, drives, name, watch=None):
    video, gps = drives[name]
    return ingest_drive(ar, DriveInput(video, gps, name=name), IngestOptions(), watch=watch)


def _blobs(ar, name):
    cat = ar.catalogue
    return [s.blob for s in cat.segments(cat.drive(name).id)]


def test_a_stalled_encoder_is_given_up_and_the_piece_coded_again_to_the_same_bytes(drives, tmp_path):
    plain = _archive(tmp_path, "plain")
    _ingest(plain, drives, "a")
    _ingest(plain, drives, "b")
    stalled = _archive(tmp_path, "stalled")
    _ingest(stalled, drives, "a")
    stalls = Stalls({0})  # drive b's first encoder (joint and standalone run side by side)
    try:
        rep = _ingest(stalled, drives, "b", EncoderWatch(stall_s=STALL_S, encode=stalls))
    finally:
        stalls.release.set()
    assert len(rep.encoder_restarts) == 1 and "kept control" in rep.encoder_restarts[0]
    # fresh encoders from a fresh decode: the very blobs an undisturbed ingest stores
    assert _blobs(stalled, "b") == _blobs(plain, "b")
    assert [p.mode for p in rep.pieces] == ["joint"]


def test_an_encoder_that_stalls_every_time_ends_the_drive_and_stores_nothing(drives, tmp_path):
    ar = _archive(tmp_path, "ar")
    stalls = Stalls(set(range(100)))
    try:
        with pytest.raises(EncoderStallError, match=r"kept control .* 2 tries\); nothing of 'a' was stored") as e:
            _ingest(ar, drives, "a", EncoderWatch(stall_s=STALL_S, encode=stalls))
    finally:
        stalls.release.set()
    assert isinstance(e.value, EncoderFaultError) and "--codec vp9" in e.value.one_line()
    assert ar.catalogue.drive("a") is None
    rep = _ingest(ar, drives, "a")  # the archive takes the drive afterwards
    assert rep.encoder_restarts == [] and ar.catalogue.drive("a") is not None


def test_heartbeat_is_overdue_only_while_the_codec_holds_control_past_its_allowance():
    beat = Heartbeat()
    assert beat.overdue(1e12) < 0  # idle
    beat.busy(5.0)
    now = time.monotonic()
    assert beat.overdue(now + 4.0) < 0 < beat.overdue(now + 6.0)
    beat.idle()
    assert beat.overdue(now + 100.0) < 0
    with pytest.raises(ValueError):
        EncoderWatch(stall_s=0)
