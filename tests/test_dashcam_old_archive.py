"""Archives written by an earlier egovid keep working: tests/data/archive-vp9-v1 was made by the VP9
joint codec of commit 7452754 (blob format 4, realtime preset; see its expected.json). Its drives
must extract bit for bit as that version extracted them, `check --deep` must pass, and a new drive
must still be able to use one of its VP9 drives as the older drive it is coded against."""

import hashlib
import json
import shutil
from pathlib import Path

import pytest

from egovid.core.video import iter_frames
from egovid.dashcam.archive.store import Archive
from egovid.dashcam.check import check_archive

from conftest import run_cli

FIXTURE = Path(__file__).parent / "data" / "archive-vp9-v1"
EXPECTED = json.loads((FIXTURE / "expected.json").read_text())


@pytest.fixture()
def old_archive(tmp_path) -> Path:
    root = tmp_path / "archive"
    shutil.copytree(FIXTURE, root, ignore=shutil.ignore_patterns("expected.json"))
    return root


def _sha(video: Path) -> tuple[int, str]:
    h, n = hashlib.sha256(), 0
    for f in iter_frames(video, i420=True):
        h.update(f.image.tobytes())
        n += 1
    return n, h.hexdigest()


def test_old_vp9_archive_extracts_bit_exact(old_archive, tmp_path):
    for name in ("a", "b"):  # b is joint against a
        out = tmp_path / f"{name}.mkv"
        r = run_cli("dashcam", "extract", old_archive, name, "-o", out)
        assert r.returncode == 0, r.stderr
        assert _sha(out) == (EXPECTED[name]["frames"], EXPECTED[name]["sha256_i420"])


def test_old_vp9_archive_passes_deep_check(old_archive):
    rep = check_archive(old_archive, deep=True)
    assert not rep.errors, rep.findings
    assert rep.decoded_frames == EXPECTED["a"]["frames"] + EXPECTED["b"]["frames"]
    ar = Archive(old_archive)
    try:
        codecs = {s.params.get("codec", "vp9") for d in ar.catalogue.drives() for s in ar.catalogue.segments(d.id)}
    finally:
        ar.close()
    assert codecs == {"vp9"}  # segments without a recorded codec are VP9 (the only one then)


def test_a_new_drive_is_coded_against_an_old_vp9_drive(old_archive, tmp_path):
    """The older drive a joint piece refers to may be a VP9 drive of an old archive: the baseline
    is built from its decoded pictures whatever its codec. All in VP9 (``--codec vp9
    --joint-codec vp9``, as before AV1) the piece is joint VP9; with the defaults (AV1 standalone,
    the joint candidate in libaom) the smaller of joint and standalone is kept and the reason
    recorded."""
    from egovid.synth.drive import DriveSpec, Light, render_drive

    spec = DriveSpec(legs=[("main", 390.0, 430.0)], cruise=10.0, seed=3, light=Light.preset("noon"))
    video, gps, _ = render_drive(spec, tmp_path / "c.mp4", width=192, height=108)
    for name, extra in (("c-vp9", ["--codec", "vp9", "--joint-codec", "vp9"]), ("c", [])):
        r = run_cli("dashcam", "ingest", old_archive, video, "--gps", gps, "--name", name, *extra)
        assert r.returncode == 0, r.stderr
    ar = Archive(old_archive)
    try:
        drives = {d.name: d for d in ar.catalogue.drives()}
        (joint,) = ar.catalogue.segments(drives["c-vp9"].id)
        assert joint.mode == "joint" and joint.ref_drive_id in (drives["a"].id, drives["b"].id)
        assert joint.params["codec"] == "vp9" and "joint" in joint.params["choice"]
        for seg in ar.catalogue.segments(drives["c"].id):
            assert seg.params["joint_codec"] == "aom" and "standalone" in seg.params["choice"]
            assert seg.params["codec"] in ("av1", "aom")
            assert (seg.mode == "joint") == (seg.params["codec"] == "aom")
    finally:
        ar.close()
    rep = check_archive(old_archive, deep=True)
    assert not rep.errors, rep.findings


def test_a_new_drive_is_coded_in_av1_against_an_old_vp9_drive(old_archive, tmp_path):
    """With the archive preset (joint candidate in libaom's good-quality mode) the older drive (a
    VP9 drive of the old archive, decoded) is injected into libaom as a reference; whatever is
    stored extracts bit for bit as the encoder saw it, and both formats pass check --deep side by
    side."""
    from egovid.dashcam.codec import segment as codec
    from egovid.synth.drive import DriveSpec, Light, render_drive

    spec = DriveSpec(legs=[("main", 390.0, 430.0)], cruise=10.0, seed=3, light=Light.preset("noon"))
    video, gps, _ = render_drive(spec, tmp_path / "c.mp4", width=192, height=108)
    r = run_cli("dashcam", "ingest", old_archive, video, "--gps", gps, "--name", "c", "--preset", "archive")
    assert r.returncode == 0, r.stderr
    ar = Archive(old_archive)
    try:
        drives = {d.name: d for d in ar.catalogue.drives()}
        segs = ar.catalogue.segments(drives["c"].id)
    finally:
        ar.close()
    for seg in segs:
        assert seg.params["joint_codec"] == "aom" and "is smaller" in seg.params["choice"]
        assert seg.params["codec"] == ("aom" if seg.mode == "joint" else "av1")
    # the same road at the same light: libaom against the old VP9 drive beats standalone SVT-AV1
    # (48 frames: 11.5 kB against 13.8 kB at equal PSNR-Y; the realtime preset's libaom at
    # cpu-used 10 loses here, 19.7 kB, since the choice compares at equal quality the right way)
    assert any(s.mode == "joint" and s.ref_drive_id in (drives["a"].id, drives["b"].id) for s in segs), [
        (s.mode, s.params["choice"]) for s in segs
    ]
    out = tmp_path / "c.mkv"
    r = run_cli("dashcam", "extract", old_archive, "c", "-o", out)
    assert r.returncode == 0, r.stderr
    frames = [f.image for f in iter_frames(out, i420=True)]
    for seg in segs:
        h = hashlib.sha256()
        for f in frames[seg.frame_start : seg.frame_end]:
            codec.digest_update(h, f)
        assert h.hexdigest() == seg.params["recon_digest"]
    rep = check_archive(old_archive, deep=True)
    assert not rep.errors, rep.findings
    assert rep.decoded_frames == EXPECTED["a"]["frames"] + EXPECTED["b"]["frames"] + len(frames)
