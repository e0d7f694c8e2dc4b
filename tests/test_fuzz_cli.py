"""A table of bad inputs across every command: each gets exit status 2, exactly one ``error:``
line naming the problem, no traceback, and leaves every file as it was (the folder is snapshot
before and after, hidden temporary files included).

Most cases fail in validation, so they run in this process through :func:`egovid.cli.run` (the
same code path as the ``egovid`` command, minus process start-up); a sample runs as real
subprocesses. Fault tests (read-only folders, a full disk, signals) are in test_failures.py.
"""

from __future__ import annotations

import gc
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from egovid.cli import run
from egovid.synth.fpv import render_fpv

from conftest import assert_one_error, invoke_cli, run_cli

GPX_HEAD = '<?xml version="1.0"?>\n<gpx version="1.0" creator="t"><trk><trkseg>\n'
GPX_TAIL = "</trkseg></trk></gpx>\n"


def _gpx(points: list[tuple[str, str, str]]) -> str:
    body = "".join(f'<trkpt lat="{la}" lon="{lo}"><time>{t}</time></trkpt>\n' for la, lo, t in points)
    return GPX_HEAD + body + GPX_TAIL


@pytest.fixture(scope="module")
def ws(tmp_path_factory) -> Path:
    """A folder of good and bad inputs (small: 160x120 clips)."""
    d = tmp_path_factory.mktemp("fuzz")
    clip = d / "clip.mp4"
    n = 30
    render_fpv(clip, np.c_[np.linspace(0, 6, n), np.zeros(n), np.zeros(n)], width=160, height=120, noise_std=2.0)
    # an MP4 with its index at the front, cut in half (as a copy interrupted half way)
    subprocess.run(
        ["ffmpeg", "-v", "error", "-y", "-i", clip, "-c", "copy", "-movflags", "+faststart", d / "fs.mp4"],
        check=True,
    )
    data = (d / "fs.mp4").read_bytes()
    (d / "half.mp4").write_bytes(data[: len(data) // 2])
    (d / "noindex.mp4").write_bytes(clip.read_bytes()[: clip.stat().st_size // 2])  # index at the end: lost
    (d / "text.mp4").write_text("hello\n" * 50)
    (d / "empty.mp4").write_bytes(b"")
    (d / "folder").mkdir()
    os.link(clip, d / "hardlink.mp4")
    (d / "link.mp4").symlink_to(clip)
    (d / "motion.csv").write_text(
        "frame,time,yaw,pitch,roll\n" + "".join(f"{i},{i / 30:.4f},0,0,0\n" for i in range(n))
    )
    (d / "short.csv").write_text("frame,time,yaw,pitch,roll\n0,0,0,0,0\n1,0.033,0,0,0\n")
    (d / "nan.csv").write_text("frame,time,yaw,pitch,roll\n0,0,nan,0,0\n1,0.033,0,0,0\n")
    (d / "words.csv").write_text("just,some,words\n1,2,3\n")
    (d / "binary.bin").write_bytes(bytes(range(256)) * 4)
    t = [f"2026-05-04T08:00:{s:02d}Z" for s in range(5)]
    (d / "nan.gpx").write_text(_gpx([("nan", "nan", x) for x in t]))
    (d / "one.gpx").write_text(_gpx([("48.1", "11.5", t[0])]))
    (d / "far.gpx").write_text(_gpx([("95", "11.5", x) for x in t]))
    (d / "good.gpx").write_text(_gpx([("48.1", f"11.5{i}", x) for i, x in enumerate(t)]))
    (d / "notime.gpx").write_text(_gpx([("48.1", "11.5", "")]).replace("<time></time>", ""))
    (d / "junk.nmea").write_text("$GPRMC,garbage*00\n" * 5)
    (d / "bad.gps.csv").write_text("time,lat,lon\n2026-05-04T08:00:00Z,abc,11\n")
    assert run(["dashcam", "init", str(d / "arc")]) == 0  # as a user makes it (fleet tables included)
    gc.collect()
    (d / "vids").mkdir()  # a folder of dashcam files whose sidecar GPS log is unusable
    shutil.copy(clip, d / "vids" / "v1.mp4")
    (d / "vids" / "v1.csv").write_text("time,lat,lon\n")
    (d / "notarc").mkdir()
    (d / "notarc" / "x.txt").write_text("x")
    run_dir = d / "run"
    run_dir.mkdir()
    return d


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under ``folder`` (hidden ones too): kind, size, modification time, content hash."""
    out: dict[str, tuple] = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs:
            out[os.path.relpath(os.path.join(root, name), folder)] = ("dir",)
        for name in files:
            p = Path(root) / name
            if p.is_symlink():
                out[str(p.relative_to(folder))] = ("link", os.readlink(p))
                continue
            st = p.stat()
            out[str(p.relative_to(folder))] = (
                "file",
                st.st_size,
                st.st_mtime_ns,
                hashlib.sha1(p.read_bytes()).hexdigest(),
            )
    return out


# (id, arguments relative to the workspace, text the error line must contain)
CASES: list[tuple[str, str, str]] = [
    # fpv motion
    ("motion-missing-video", "fpv motion nosuch.mp4 -o m.csv", "not found"),
    ("motion-video-is-folder", "fpv motion folder -o m.csv", "is a folder"),
    ("motion-empty-video", "fpv motion empty.mp4 -o m.csv", "empty"),
    ("motion-text-as-video", "fpv motion text.mp4 -o m.csv", "not a readable video"),
    ("motion-truncated-index-first", "fpv motion half.mp4 -o m.csv", "truncated"),
    ("motion-truncated-no-index", "fpv motion noindex.mp4 -o m.csv", "without its index"),
    ("motion-out-is-input", "fpv motion clip.mp4 -o clip.mp4", "overwrite the input"),
    ("motion-out-hardlink-of-input", "fpv motion clip.mp4 -o hardlink.mp4", "overwrite the input"),
    ("motion-out-symlink-to-input", "fpv motion clip.mp4 -o link.mp4", "overwrite the input"),
    ("motion-out-no-folder", "fpv motion clip.mp4 -o nodir/m.csv", "does not exist"),
    ("motion-out-is-folder", "fpv motion clip.mp4 -o folder", "is a folder"),
    ("motion-tum-no-folder", "fpv motion clip.mp4 -o m.csv --tum nodir/x.tum", "does not exist"),
    ("motion-plot-no-folder", "fpv motion clip.mp4 -o m.csv --plot nodir/x.png", "does not exist"),
    ("motion-plot-extension", "fpv motion clip.mp4 -o m.csv --plot m.txt", "extension"),
    ("motion-out-extension", "fpv motion clip.mp4 -o m.mp4", "extension"),
    ("motion-tum-equals-out", "fpv motion clip.mp4 -o m.csv --tum m.csv", "also given"),
    ("motion-focal-nan", "fpv motion clip.mp4 -o m.csv --focal nan", "finite"),
    ("motion-focal-absurd", "fpv motion clip.mp4 -o m.csv --focal 1", "absurd"),
    ("motion-hfov-200", "fpv motion clip.mp4 -o m.csv --hfov 200", "out of range"),
    ("motion-focal-and-hfov", "fpv motion clip.mp4 -o m.csv --focal 300 --hfov 60", "only one"),
    ("motion-lags-words", "fpv motion clip.mp4 -o m.csv --lags a,b", "integers"),
    ("motion-features-unknown", "fpv motion clip.mp4 -o m.csv --features surf", "surf"),
    ("motion-work-width-tiny", "fpv motion clip.mp4 -o m.csv --work-width 10", "--work-width"),
    ("motion-no-out", "fpv motion clip.mp4", "--out"),
    ("motion-unknown-option", "fpv motion clip.mp4 -o m.csv --bogus", "--bogus"),
    ("motion-source-unknown", "fpv motion clip.mp4 -o m.csv --source magic", "magic"),
    ("motion-source-gyro-without-gyro", "fpv motion clip.mp4 -o m.csv --source gyro", "needs a gyro"),
    # fpv score
    ("score-nothing", "fpv score", "either"),
    ("score-video-and-motion", "fpv score clip.mp4 --motion motion.csv", "either"),
    ("score-json-is-input", "fpv score clip.mp4 --json clip.mp4", "overwrite the input"),
    ("score-json-is-motion-input", "fpv score --motion motion.csv --json motion.csv", "overwrite the input"),
    ("score-motion-missing", "fpv score --motion nosuch.csv", "not found"),
    ("score-motion-nan", "fpv score --motion nan.csv", "NaN"),
    ("score-motion-not-motion", "fpv score --motion words.csv", "lacks"),
    ("score-motion-binary", "fpv score --motion binary.bin", "not a text CSV"),
    ("score-method-unknown", "fpv score clip.mp4 --method best", "best"),
    ("score-fps-zero", "fpv score --motion motion.csv --fps 0", "--fps"),
    ("score-fps-inf", "fpv score --motion motion.csv --fps inf", "finite"),
    ("score-d-over-f-negative", "fpv score --motion motion.csv --d-over-f -1", "--d-over-f"),
    ("score-mar-zero", "fpv score --motion motion.csv --mar 0", "--mar"),
    ("score-bias-nan", "fpv score --motion motion.csv --bias nan", "finite"),
    ("score-size-words", "fpv score --motion motion.csv --size big", "WIDTHxHEIGHT"),
    ("score-plot-no-folder", "fpv score --motion motion.csv --plot nodir/p.png", "does not exist"),
    ("score-sve-variant", "fpv score --motion motion.csv --sve-variant other", "other"),
    ("score-truncated", "fpv score half.mp4", "truncated"),
    # fpv stabilize
    ("stabilize-out-txt", "fpv stabilize clip.mp4 -o out.txt", "extension"),
    ("stabilize-out-is-input", "fpv stabilize clip.mp4 -o clip.mp4", "overwrite the input"),
    ("stabilize-strength-2", "fpv stabilize clip.mp4 -o o.mp4 --strength 2", "strength"),
    ("stabilize-strength-nan", "fpv stabilize clip.mp4 -o o.mp4 --strength nan", "finite"),
    ("stabilize-borders-unknown", "fpv stabilize clip.mp4 -o o.mp4 --borders wavy", "wavy"),
    ("stabilize-method-unknown", "fpv stabilize clip.mp4 -o o.mp4 --method best", "best"),
    ("stabilize-save-motion-no-folder", "fpv stabilize clip.mp4 -o o.mp4 --save-motion nodir/pre", "does not exist"),
    ("stabilize-report-no-folder", "fpv stabilize clip.mp4 -o o.mp4 --report nodir/r.html", "does not exist"),
    ("stabilize-json-extension", "fpv stabilize clip.mp4 -o o.mp4 --json r.txt", "extension"),
    ("stabilize-motion-wrong-length", "fpv stabilize clip.mp4 -o o.mp4 --motion short.csv", "frames"),
    ("stabilize-crf-99", "fpv stabilize clip.mp4 -o o.mp4 --crf 99", "--crf"),
    ("stabilize-anchor-zero", "fpv stabilize clip.mp4 -o o.mp4 --anchor-threshold 0", "--anchor-threshold"),
    ("stabilize-truncated", "fpv stabilize half.mp4 -o o.mp4", "truncated"),
    ("stabilize-report-is-json", "fpv stabilize clip.mp4 -o o.mp4 --report r.html --json r.html", "also given"),
    ("score-source-unknown", "fpv score clip.mp4 --source magic", "magic"),
    ("stabilize-source-unknown", "fpv stabilize clip.mp4 -o o.mp4 --source magic", "magic"),
    ("stabilize-source-gyro-without-gyro", "fpv stabilize clip.mp4 -o o.mp4 --source gyro", "needs a gyro"),
    # synth fpv
    ("synth-fpv-yaw-nan", "synth fpv o.mp4 --yaw-amp nan", "finite"),
    ("synth-fpv-yaw-huge", "synth fpv o.mp4 --yaw-amp 1e9", "out of range"),
    ("synth-fpv-period-inf", "synth fpv o.mp4 --period inf", "finite"),
    ("synth-fpv-frames-1", "synth fpv o.mp4 --frames 1", "--frames"),
    ("synth-fpv-size-odd", "synth fpv o.mp4 --size 101x51", "not usable"),
    ("synth-fpv-size-words", "synth fpv o.mp4 --size huge", "WIDTHxHEIGHT"),
    ("synth-fpv-fps-zero", "synth fpv o.mp4 --fps 0", "--fps"),
    ("synth-fpv-noise-negative", "synth fpv o.mp4 --noise -1", "--noise"),
    ("synth-fpv-motion-unknown", "synth fpv o.mp4 --motion dance", "dance"),
    ("synth-fpv-scene-unknown", "synth fpv o.mp4 --scene mars", "mars"),
    ("synth-fpv-out-txt", "synth fpv o.txt", "extension"),
    ("synth-fpv-out-no-folder", "synth fpv nodir/o.mp4", "does not exist"),
    ("synth-fpv-out-is-folder", "synth fpv folder", "is a folder"),
    ("synth-fpv-hfov-zero", "synth fpv o.mp4 --hfov 0", "out of range"),
    # synth drive
    ("synth-drive-gps-format", "synth drive o.mp4 --gps foo", "foo"),
    ("synth-drive-light", "synth drive o.mp4 --light purple", "purple"),
    ("synth-drive-route", "synth drive o.mp4 --route moon", "moon"),
    ("synth-drive-stop-nan", "synth drive o.mp4 --stop nan:3", "finite"),
    ("synth-drive-stop-words", "synth drive o.mp4 --stop here", "DISTANCE:SECONDS"),
    ("synth-drive-lane-change", "synth drive o.mp4 --lane-change 5", "A:B"),
    ("synth-drive-start", "synth drive o.mp4 --start yesterday", "ISO 8601"),
    ("synth-drive-cruise", "synth drive o.mp4 --cruise 100", "--cruise"),
    ("synth-drive-fps-nan", "synth drive o.mp4 --fps nan", "--fps"),
    ("synth-drive-from-negative", "synth drive o.mp4 --from -5", "--from"),
    ("synth-drive-lane-offset", "synth drive o.mp4 --lane-offset 1e20", "--lane-offset"),
    ("synth-drive-out-txt", "synth drive o.txt", "extension"),
    # dashcam
    ("dashcam-ingest-not-archive", "dashcam ingest notarc clip.mp4 --gps good.gpx", "not an egovid archive"),
    ("dashcam-ingest-gps-offset-nan", "dashcam ingest arc clip.mp4 --gps good.gpx --gps-offset nan", "finite"),
    ("dashcam-ingest-q-range", "dashcam ingest arc clip.mp4 --gps good.gpx --q 99", "--q"),
    ("dashcam-ingest-start-words", "dashcam ingest arc clip.mp4 --gps good.gpx --start noon", "ISO 8601"),
    ("dashcam-ingest-gps-nan", "dashcam ingest arc clip.mp4 --gps nan.gpx", "0 valid GPS fix"),
    ("dashcam-ingest-gps-one-fix", "dashcam ingest arc clip.mp4 --gps one.gpx", "at least 2"),
    ("dashcam-ingest-gps-out-of-range", "dashcam ingest arc clip.mp4 --gps far.gpx", "out of range"),
    ("dashcam-ingest-gps-no-times", "dashcam ingest arc clip.mp4 --gps notime.gpx", "valid GPS fix"),
    ("dashcam-ingest-gps-nmea-junk", "dashcam ingest arc clip.mp4 --gps junk.nmea", "NMEA"),
    ("dashcam-ingest-gps-csv-words", "dashcam ingest arc clip.mp4 --gps bad.gps.csv", "not a GPS fix"),
    ("dashcam-ingest-gps-folder", "dashcam ingest arc clip.mp4 --gps folder", "folder"),
    ("dashcam-ingest-gps-binary", "dashcam ingest arc clip.mp4 --gps binary.bin", "binary"),
    ("dashcam-ingest-gps-missing", "dashcam ingest arc clip.mp4 --gps nosuch.gpx", "not found"),
    ("dashcam-ingest-gps-offset-huge", "dashcam ingest arc clip.mp4 --gps good.gpx --gps-offset 1e20", "--gps-offset"),
    ("dashcam-ingest-video-truncated", "dashcam ingest arc half.mp4 --gps good.gpx", "truncated"),
    ("dashcam-ingest-video-text", "dashcam ingest arc text.mp4 --gps good.gpx", "not a readable video"),
    ("dashcam-ingest-video-missing", "dashcam ingest arc nosuch.mp4 --gps good.gpx", "not found"),
    ("dashcam-extract-start-inf", "dashcam extract arc d1 -o x.mkv --start inf", "finite"),
    ("dashcam-extract-unknown-drive", "dashcam extract arc nosuch -o x.mkv", "nosuch"),
    ("dashcam-extract-channel-not-a-name", "dashcam extract arc d1 -o x.mkv --channel rear/../x", "not a camera name"),
    ("dashcam-extract-channel-empty", "dashcam extract arc d1 -o x.mkv --channel=", "not a camera name"),
    ("dashcam-extract-channel-unknown-drive", "dashcam extract arc nosuch -o x.mkv --channel all", "nosuch"),
    ("dashcam-show-unknown-drive", "dashcam show arc nosuch", "nosuch"),
    ("dashcam-list-not-archive", "dashcam list notarc", "not an egovid archive"),
    ("dashcam-list-missing", "dashcam list nosuch", "not an egovid archive"),
    ("dashcam-gc-not-archive", "dashcam gc notarc", "not an egovid archive"),
    ("dashcam-init-not-empty", "dashcam init notarc", "not empty"),
    ("dashcam-init-existing-archive", "dashcam init arc", "already"),
    ("dashcam-unknown-command", "dashcam frobnicate arc", "frobnicate"),
    # dashcam ingest of several files, folders and sidecar GPS logs
    ("dashcam-ingest-folder-without-videos", "dashcam ingest arc folder", "holds no videos"),
    ("dashcam-ingest-sidecar-gps-empty", "dashcam ingest arc vids/v1.mp4", "0 valid GPS fix"),
    ("dashcam-ingest-folder-all-skipped", "dashcam ingest arc vids", "none of the 1 videos"),
    ("dashcam-ingest-no-gps-anywhere", "dashcam ingest arc clip.mp4", "no GPS for clip.mp4"),
    (
        "dashcam-ingest-start-with-several",
        "dashcam ingest arc clip.mp4 vids/v1.mp4 --start 2026-05-04T08:00:00Z",
        "several",
    ),
    ("dashcam-ingest-tz-offset", "dashcam ingest arc clip.mp4 --tz-offset 20", "--tz-offset"),
    ("dashcam-ingest-max-gap", "dashcam ingest arc clip.mp4 --max-gap -1", "--max-gap"),
    ("dashcam-ingest-preset", "dashcam ingest arc clip.mp4 --preset turbo", "turbo"),
    ("dashcam-ingest-workers-zero", "dashcam ingest arc clip.mp4 --workers 0", "--workers"),
    ("dashcam-ingest-json-is-input", "dashcam ingest arc clip.mp4 --gps good.gpx --json clip.mp4", "overwrite"),
    ("dashcam-ingest-aligner", "dashcam ingest arc clip.mp4 --gps good.gpx --aligner magic", "magic"),
    ("dashcam-ingest-gps-not-a-track", "dashcam ingest arc clip.mp4 --gps motion.csv", "not a GPS track"),
    # dashcam find / clip
    ("dashcam-find-nothing", "dashcam find arc", "nothing to find"),
    ("dashcam-find-near-one-number", "dashcam find arc --near 48.1", "2 comma-separated"),
    ("dashcam-find-near-off-earth", "dashcam find arc --near 95,11", "not a position"),
    ("dashcam-find-bbox-three", "dashcam find arc --bbox 1,2,3", "4 comma-separated"),
    ("dashcam-find-bbox-inverted", "dashcam find arc --bbox 11.6,48.1,11.5,48.2", "not a box"),
    ("dashcam-find-from-words", "dashcam find arc --from yesterday", "ISO 8601"),
    ("dashcam-find-window-backwards", "dashcam find arc --from 2026-05-05 --to 2026-05-04", "not after"),
    ("dashcam-find-radius-nan", "dashcam find arc --near 48.1,11.5 --radius nan", "finite"),
    ("dashcam-find-radius-negative", "dashcam find arc --near 48.1,11.5 --radius -5", "--radius"),
    ("dashcam-find-json-no-folder", "dashcam find arc --near 48.1,11.5 --json nodir/f.json", "does not exist"),
    ("dashcam-find-json-extension", "dashcam find arc --near 48.1,11.5 --json f.txt", "extension"),
    ("dashcam-find-not-archive", "dashcam find notarc --near 48.1,11.5", "not an egovid archive"),
    ("dashcam-clip-no-moment", "dashcam clip arc -o c.mp4", "--at"),
    ("dashcam-clip-at-and-near", "dashcam clip arc -o c.mp4 --at 2026-05-04T08:00:00Z --near 48.1,11.5", "one of"),
    ("dashcam-clip-extension", "dashcam clip arc -o c.txt --at 2026-05-04T08:00:00Z", "extension"),
    ("dashcam-clip-no-folder", "dashcam clip arc -o nodir/c.mp4 --at 2026-05-04T08:00:00Z", "does not exist"),
    ("dashcam-clip-at-words", "dashcam clip arc -o c.mp4 --at yesterday", "ISO 8601"),
    ("dashcam-clip-before-negative", "dashcam clip arc -o c.mp4 --at 2026-05-04T08:00:00Z --before -1", "--before"),
    ("dashcam-clip-after-inf", "dashcam clip arc -o c.mp4 --at 2026-05-04T08:00:00Z --after inf", "finite"),
    ("dashcam-clip-crf", "dashcam clip arc -o c.mp4 --at 2026-05-04T08:00:00Z --crf 99", "--crf"),
    ("dashcam-clip-radius-zero", "dashcam clip arc -o c.mp4 --near 48.1,11.5 --radius 0", "--radius"),
    ("dashcam-clip-unknown-drive", "dashcam clip arc -o c.mp4 --at 2026-05-04T08:00:00Z --drive nosuch", "nosuch"),
    ("dashcam-clip-nothing-then", "dashcam clip arc -o c.mp4 --at 2026-05-04T08:00:00Z", "not recorded"),
    (
        "dashcam-clip-channel-not-a-name",
        "dashcam clip arc -o c.mp4 --at 2026-05-04T08:00:00Z --channel Rück",
        "camera name",
    ),
    (
        "dashcam-clip-channel-nothing-then",
        "dashcam clip arc -o c.mp4 --at 2026-05-04T08:00:00Z --channel rear",
        "not recorded",
    ),
    # dashcam forget / lock / unlock / check / report --html
    ("dashcam-forget-nothing", "dashcam forget arc", "nothing to forget"),
    ("dashcam-forget-unknown-drive", "dashcam forget arc nosuch", "nosuch"),
    ("dashcam-forget-older-than-words", "dashcam forget arc --older-than soon", "not a duration"),
    ("dashcam-forget-older-than-negative", "dashcam forget arc --older-than -5d", "not a duration"),
    ("dashcam-forget-keep-bytes-words", "dashcam forget arc --keep-bytes lots", "not a size"),
    ("dashcam-forget-json-no-folder", "dashcam forget arc nosuch --json nodir/x.json", "does not exist"),
    ("dashcam-lock-unknown-drive", "dashcam lock arc nosuch", "nosuch"),
    ("dashcam-lock-no-drive", "dashcam lock arc", "missing argument"),
    ("dashcam-lock-not-archive", "dashcam lock notarc d1", "not an egovid archive"),
    ("dashcam-unlock-unknown-drive", "dashcam unlock arc nosuch", "nosuch"),
    ("dashcam-check-not-archive", "dashcam check notarc", "not an egovid archive"),
    ("dashcam-check-missing", "dashcam check nosuch", "not found"),
    ("dashcam-check-file", "dashcam check clip.mp4", "not a folder"),
    ("dashcam-check-unknown-option", "dashcam check arc --fix", "--fix"),
    ("dashcam-report-html-extension", "dashcam report arc --html r.txt", "extension"),
    ("dashcam-report-html-no-folder", "dashcam report arc --html nodir/r.html", "does not exist"),
    ("dashcam-report-html-is-json", "dashcam report arc --json r.json --html r.json", "also given"),
    ("dashcam-report-colour", "dashcam report arc --colour pink", "pink"),
    ("dashcam-report-html-not-archive", "dashcam report notarc --html r.html", "not an egovid archive"),
    # dashcam backup / restore
    ("dashcam-backup-not-archive", "dashcam backup notarc b.sqlite", "not an egovid archive"),
    ("dashcam-backup-over-a-file", "dashcam backup arc clip.mp4", "exists"),
    ("dashcam-backup-no-folder", "dashcam backup arc nodir/b.sqlite", "does not exist"),
    ("dashcam-backup-no-file", "dashcam backup arc", "missing argument"),
    ("dashcam-restore-missing", "dashcam restore nosuch.sqlite arc", "does not exist"),
    ("dashcam-restore-video", "dashcam restore clip.mp4 arc", "not a catalogue backup"),
    ("dashcam-restore-text", "dashcam restore words.csv arc", "not a catalogue backup"),
    ("dashcam-restore-folder", "dashcam restore folder arc", "is a folder"),
    ("dashcam-restore-not-archive", "dashcam restore clip.mp4 notarc", "not an egovid archive"),
    # voeval
    ("voeval-run-size", "voeval run --out r1 --size big", "WIDTHxHEIGHT"),
    ("voeval-run-levels", "voeval run --out r1 --levels lossless,crf99", "crf99"),
    ("voeval-run-frames", "voeval run --out r1 --frames 5", "--frames"),
    ("voeval-run-out-is-file", "voeval run --out clip.mp4", "is a file"),
    ("voeval-run-out-no-parent-writable", "voeval run --out motion.csv/sub", "not a folder"),
    ("voeval-run-workers", "voeval run --out r1 --workers 0", "--workers"),
    ("voeval-run-sequence-format", "voeval run --out r1 --sequence bogus:folder", "known format"),
    ("voeval-run-sequence-no-format", "voeval run --out r1 --sequence folder", "FORMAT:PATH"),
    ("voeval-run-sequence-missing-folder", "voeval run --out r1 --sequence tum:nosuch", "does not exist"),
    ("voeval-run-sequence-file-not-folder", "voeval run --out r1 --sequence tum:clip.mp4", "not a folder"),
    ("voeval-run-sequence-tum-empty", "voeval run --out r1 --sequence tum:folder", "rgb.txt"),
    ("voeval-run-sequence-kitti-empty", "voeval run --out r1 --sequence kitti:folder", "image_0"),
    ("voeval-run-sequence-gyro-missing", "voeval run --out r1 --sequence gyro:nosuch.mp4", "does not exist"),
    ("voeval-run-sequence-gyro-none", "voeval run --out r1 --sequence gyro:clip.mp4", "no embedded gyro"),
    ("voeval-run-vo-unknown", "voeval run --out r1 --vo bogus", "bogus"),
    ("voeval-run-scenes-unknown", "voeval run --out r1 --scenes bogus", "bogus"),
    ("voeval-run-seeds-words", "voeval run --out r1 --seeds a", "integers"),
    ("voeval-run-anchor", "voeval run --out r1 --anchor bogus", "bogus"),
    ("voeval-report-norm", "voeval report folder --norm bogus", "bogus"),
    ("voeval-report-missing", "voeval report nosuch", "no results"),
    ("voeval-report-file", "voeval report clip.mp4", "no results"),
    # demo and the top level
    ("demo-out-is-file", "demo --out clip.mp4", "is a file"),
    # serve (refused before it listens)
    ("serve-not-archive", "serve notarc", "not an egovid archive"),
    ("serve-port", "serve arc --port 70000", "not a port"),
    ("serve-token-short", "serve arc --token abc", "16 characters"),
    ("serve-report-missing", "serve arc --voeval nothere", "report folder"),
    ("serve-missing-archive", "serve nosuch", "not found"),
    ("serve-archive-is-file", "serve clip.mp4", "not a folder"),
    ("serve-port-negative", "serve arc --port -1", "not a port"),
    ("serve-port-words", "serve arc --port eighty", "--port"),
    ("serve-host-elsewhere", "serve arc --host 192.0.2.1 --port 0", "not an address of this machine"),
    ("serve-tiles-bogus", "serve arc --tiles bogus", "tile url"),
    ("serve-tiles-ftp", "serve arc --tiles ftp://tiles.example/{z}/{x}/{y}.png", "tile url"),
    ("serve-port-absurd", "serve arc --port 99999", "not a port"),
    ("serve-cache-tiny", "serve arc --cache-mb 1", "cache-mb"),
    ("top-unknown-command", "stabilise clip.mp4", "stabilise"),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_input_gets_one_error_and_changes_nothing(ws, case, capsys, monkeypatch):
    _, args, needle = case
    monkeypatch.chdir(ws)
    before = snapshot(ws)
    r = invoke_cli(args.split(), capsys)
    code, out, err = r.returncode, r.stdout, r.stderr
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert code == 2, f"exit {code}\nstdout: {out}\nstderr: {err}"
    assert "Traceback" not in err + out
    assert len(lines) == 1, err
    assert needle.lower() in lines[0].lower(), lines[0]
    assert snapshot(ws) == before, "files changed"


def _commands() -> set[str]:
    """Every command of the CLI, as "group command" (or "command" at the top level)."""
    import typer.main

    from egovid.cli import app

    out: set[str] = set()

    def walk(cmd, prefix: str) -> None:
        if hasattr(cmd, "commands"):  # a group
            for name, sub in cmd.commands.items():
                walk(sub, f"{prefix} {name}".strip())
        else:
            out.add(prefix)

    walk(typer.main.get_command(app), "")
    return out


def test_the_table_is_big_enough_and_covers_every_command(record_property):
    covered = {" ".join(c[1].split()[:2]) for c in CASES} | {c[1].split()[0] for c in CASES}
    missing = sorted(_commands() - covered)
    # printed in the run's summary by conftest.pytest_terminal_summary (also under pytest-xdist)
    n_cmd = len(_commands())
    record_property("summary", f"[fuzz] {len(CASES)} bad inputs over {n_cmd - len(missing)} of {n_cmd} commands")
    assert len(CASES) >= 60
    assert not missing, f"commands with no bad-input case: {missing}"


SUBPROCESS_SAMPLE = [
    "motion-out-is-input",
    "motion-truncated-index-first",
    "synth-fpv-yaw-nan",
    "synth-drive-gps-format",
    "dashcam-extract-start-inf",
    "stabilize-crf-99",
]


@pytest.mark.parametrize("name", SUBPROCESS_SAMPLE)
def test_bad_input_in_a_real_process(ws, name, tmp_path):
    """The same cases through the installed entry point (python -m egovid), in a copy of the
    workspace so the shared one is not touched."""
    _, args, needle = next(c for c in CASES if c[0] == name)
    work = tmp_path / "ws"
    shutil.copytree(ws, work, symlinks=True)
    before = snapshot(work)
    r = run_cli(*args.split(), cwd=work)
    assert_one_error(r, "")
    assert needle.lower() in r.stderr.lower()
    assert snapshot(work) == before
