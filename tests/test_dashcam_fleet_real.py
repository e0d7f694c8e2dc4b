"""The fleet archive on a real camera file: the GoPro HERO5 Karma clip, ingested with no --gps."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import shutil
import subprocess

import av
import pytest

from egovid.core.video import iter_frames
from egovid.dashcam.archive.store import open_archive
from egovid.dashcam.extract import drive_frames

from conftest import assert_one_error, run_cli

# The first frame was recorded between 19:27:57 and 19:27:58 UTC: the container's creation_time
# (whole seconds) and the Karma's own clock in its GPMF track (SYST: 19:27:58.000 UTC inside the
# first payload, video seconds 0-1.001) say so; see test_dashcam_fleet_clock.py.
FIRST_FRAME = (dt.datetime(2017, 4, 17, 19, 27, 57, tzinfo=dt.UTC), dt.datetime(2017, 4, 17, 19, 27, 58, tzinfo=dt.UTC))


def _sha(img) -> str:
    return hashlib.sha256(img.tobytes()).hexdigest()


def test_karma_clip_ingests_on_its_own_gps_and_comes_back_as_the_camera_wrote_it(karma_clip, tmp_path):
    root = tmp_path / "archive"
    assert run_cli("dashcam", "init", root).returncode == 0
    r = run_cli("dashcam", "ingest", root, karma_clip, "--json", tmp_path / "in.json")
    assert r.returncode == 0, r.stderr
    rep = json.loads((tmp_path / "in.json").read_text())
    start = dt.datetime.fromisoformat(rep["clock"]["start"])
    assert FIRST_FRAME[0] <= start <= FIRST_FRAME[1] and rep["clock"]["source"].startswith("GPS time (ExifTool")
    assert rep["streams"]["audio"]["codec"] == "opus" and rep["streams"]["telemetry"][0]["handler"] == "GoPro MET"
    # Extract: tagged full range like the camera's file, the archived frames bit for bit, the audio
    # (Opus) and the GPMF telemetry track back in the MP4.
    out = tmp_path / "karma.mp4"
    r = run_cli("dashcam", "extract", root, rep["name"], "-o", out)
    assert r.returncode == 0, r.stderr
    with av.open(str(out)) as c:
        v = c.streams.video[0].codec_context
        assert (v.color_range, v.color_primaries, v.colorspace) == (2, 1, 1)  # pc, bt709, bt709
        assert c.streams.audio[0].codec_context.name == "opus" and len(c.streams.data) == 1
    ar = open_archive(root)
    d = ar.drive_or_fail(rep["name"])
    archived = [_sha(f) for f in drive_frames(ar, d, 0, d.frames)]
    assert [_sha(f.image) for f in iter_frames(out, i420=True)] == archived and len(archived) == 362
    exiftool = shutil.which("exiftool")
    if exiftool:
        text = subprocess.run([exiftool, "-ee", "-n", "-GPSLatitude", str(out)], capture_output=True, text=True).stdout
        assert text.count("GPS Latitude") == 47
    # A stretch into Matroska (FFV1): full range, the archived frames, the Opus audio; the GPMF
    # track, which Matroska cannot hold, left out (not a failed header).
    mkv = tmp_path / "karma.mkv"
    r = run_cli("dashcam", "extract", root, rep["name"], "-o", mkv, "--start", "2", "--duration", "3")
    assert r.returncode == 0, r.stderr
    with av.open(str(mkv)) as c:
        assert c.streams.video[0].codec_context.color_range == 2 and len(c.streams.data) == 0
        assert c.streams.audio[0].codec_context.name == "opus"
    assert [_sha(f.image) for f in iter_frames(mkv, i420=True)] == archived[60:150]
    # An incident clip at a GPS time: H.264 + AAC + GPMF, and its GPX.
    moment = (start + dt.timedelta(seconds=6)).isoformat()
    clip = tmp_path / "incident.mp4"
    r = run_cli("dashcam", "clip", root, "--at", moment, "--before", "2", "--after", "2", "-o", clip)
    assert r.returncode == 0, r.stderr
    with av.open(str(clip)) as c:
        assert c.streams.video[0].frames == pytest.approx(121, abs=1)
        assert c.streams.audio[0].codec_context.name == "aac" and len(c.streams.data) == 1
        assert c.streams.video[0].codec_context.color_range == 2
    assert clip.with_suffix(".gpx").read_text().count("<trkpt") >= 15
    # check counts the audio/telemetry blob as the drive's (it said "no drive uses" and sent the
    # user to gc, which keeps it), and finds it damaged.
    r = run_cli("dashcam", "check", root)
    assert r.returncode == 0 and "no drive uses" not in r.stdout + r.stderr, r.stdout + r.stderr
    assert "1 drive(s), 1 segment(s), 2 bitstream(s)" in r.stdout
    streams = ar.catalogue.streams_blobs()
    assert list(streams.values()) == [[d.id]]
    (sha,) = streams
    blob = root / "blobs" / sha[:2] / sha
    data = bytearray(blob.read_bytes())
    data[len(data) // 2] ^= 0xFF
    blob.chmod(0o644)
    blob.write_bytes(bytes(data))
    r = run_cli("dashcam", "check", root)
    assert (
        r.returncode != 0
        and f"the audio and telemetry of drive {rep['name']} ({sha[:12]}) are corrupt" in r.stdout + r.stderr
    )


def test_a_video_without_gps_anywhere_is_one_error_naming_gps(handheld_clip, tmp_path):
    root = tmp_path / "archive"
    assert run_cli("dashcam", "init", root).returncode == 0
    assert_one_error(run_cli("dashcam", "ingest", root, handheld_clip), "--gps")
