"""Re-ingesting a card the archive holds already (a sync job run again), against its first ingest,
through the CLI exactly as a user runs it: ``egovid dashcam ingest ARCHIVE CARD --gps LOG``.

The card: one synthetic drive (egovid.synth.drive) cut into loop files named like a Viofo's
(``2026_0601_090000_0001F.MP4`` …), lossless H.264 (more bytes per second than a real dashcam's
H.264, so the digest's share is if anything overstated). Timed, in one run (shared machine: only
the ratios mean something): the first ingest (CLI); the same card again through the CLI (the
light step answers it: :func:`egovid.dashcam.archive.identity.all_known`, sampled digests, no
pipeline import), and with ``--verify-known`` (every byte hashed); in this process the light
step alone and the library call (:func:`egovid.dashcam.ingest.ingest_videos`), three times each
(median), with the bytes the light step read (``rchar`` of /proc/self/io: every read() of the
process); and the import of ``egovid.dashcam.ingest`` in a fresh interpreter (what the
command no longer pays for a known card). Reported: whole command ÷ first ingest, and an
extrapolation to a 64 GB card (not measured): first ingest at this run's input rate; re-ingest =
this run's whole command + per file the light step's time here + its sampled bytes read at an
SD card's 90 MB/s, for loop files of EGOVID_BENCH_LOOP_S seconds at the bench card's bitrate.
Target (issue 30): ≤ 2 %.

Env: EGOVID_BENCH_SIZE (default 640x360), EGOVID_BENCH_FPS (default 15), EGOVID_BENCH_SECONDS
(drive length, default 40), EGOVID_BENCH_FILES (loop files, default 4), EGOVID_BENCH_LOOP_S (a real
camera's loop-file length for the extrapolation, default 60: short files are the worst case). Appends to
bench-output/results.jsonl.
"""

from __future__ import annotations

import datetime as dt
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import av

from _common import report


def _card(folder: Path, size: tuple[int, int], fps: float, seconds: float, files: int) -> tuple[Path, Path]:
    """The loop files of one drive in ``folder/card`` and its GPS log."""
    from egovid.core.video import iter_frames
    from egovid.synth.drive import DriveSpec, Light, render_drive

    start = dt.datetime(2026, 6, 1, 9, 0, 0, tzinfo=dt.UTC)
    length = 10.0 * seconds  # metres at 10 m/s
    spec = DriveSpec(legs=[("main", 380.0, 380.0 + length)], cruise=10.0, seed=5, light=Light.preset("noon"),
                     start_time=start)  # fmt: skip
    video, gps, _ = render_drive(spec, folder / "whole.mp4", width=size[0], height=size[1], fps=fps)
    frames = [f.image for f in iter_frames(video, i420=True)]
    card = folder / "card"
    card.mkdir()
    per = -(-len(frames) // files)
    for k in range(files):
        chunk = frames[k * per : (k + 1) * per]
        t = start + dt.timedelta(seconds=k * per / fps)
        with av.open(str(card / f"{t:%Y_%m%d_%H%M%S}_{k + 1:04d}F.MP4"), "w") as c:
            c.metadata["creation_time"] = t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
            s = c.add_stream("libx264", rate=round(fps))
            s.width, s.height, s.pix_fmt = size[0], size[1], "yuv420p"
            s.options = {"qp": "0", "preset": "ultrafast"}
            for i, img in enumerate(chunk):
                vf = av.VideoFrame.from_ndarray(img, format="yuv420p")
                vf.pts = i
                for p in s.encode(vf):
                    c.mux(p)
            for p in s.encode():
                c.mux(p)
    return card, gps


SD_BYTES_PER_S = 90e6  # a good SD card's sequential read
CARD_BYTES = 64e9


def _rchar() -> int:
    """Bytes this process has read so far (every read() call; Linux)."""
    with open("/proc/self/io") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("rchar:"))


def _cli(*args) -> tuple[float, str]:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "egovid", *map(str, args)], capture_output=True, text=True,
                       stdin=subprocess.DEVNULL, timeout=3600)  # fmt: skip
    if r.returncode != 0:
        raise SystemExit(f"egovid {' '.join(map(str, args))} failed:\n{r.stdout}{r.stderr}")
    return time.perf_counter() - t, r.stdout


def main() -> None:
    w, h = (int(x) for x in os.environ.get("EGOVID_BENCH_SIZE", "640x360").split("x"))
    fps = float(os.environ.get("EGOVID_BENCH_FPS", "15"))
    seconds = float(os.environ.get("EGOVID_BENCH_SECONDS", "40"))
    files = int(os.environ.get("EGOVID_BENCH_FILES", "4"))
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        card, gps = _card(d, (w, h), fps, seconds, files)
        card_bytes = sum(f.stat().st_size for f in card.iterdir())
        root = d / "archive"
        _cli("dashcam", "init", root)
        first, _ = _cli("dashcam", "ingest", root, card, "--gps", gps)
        again, out = _cli("dashcam", "ingest", root, card, "--gps", gps)
        assert f"{files} file(s) already archived" in out, out
        verified, out = _cli("dashcam", "ingest", root, card, "--gps", gps, "--verify-known")
        assert f"{files} file(s) already archived" in out, out
        t = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import egovid.dashcam.ingest"], check=True, stdin=subprocess.DEVNULL)
        startup = time.perf_counter() - t
        from egovid.dashcam.archive.identity import SAMPLED_BYTES, all_known
        from egovid.dashcam.archive.store import open_archive

        light, read = [], []
        for _ in range(3):
            archive = open_archive(root)
            r0, t = _rchar(), time.perf_counter()
            hits = all_known(archive, [card])
            light.append(time.perf_counter() - t)
            read.append(_rchar() - r0)
            archive.close()
            assert hits is not None and len(hits) == files
        from egovid.dashcam.ingest import ingest_videos

        lib = []
        for _ in range(3):
            archive = open_archive(root)
            t = time.perf_counter()
            res = ingest_videos(archive, [card], gps=gps)
            lib.append(time.perf_counter() - t)
            archive.close()
            assert res.nothing_new and res.known == files
    lib_s, light_s, read_b = statistics.median(lib), statistics.median(light), statistics.median(read)
    # 64 GB, extrapolated: the first ingest at this run's input rate; the card of loop files of
    # loop_s seconds at this card's bitrate, each read SAMPLED_BYTES (or whole, if smaller).
    loop_s = float(os.environ.get("EGOVID_BENCH_LOOP_S", "60"))
    bitrate = card_bytes / seconds  # bytes per second of video
    n64 = CARD_BYTES / (bitrate * loop_s)
    read64 = n64 * min(bitrate * loop_s, SAMPLED_BYTES)
    first64 = first * CARD_BYTES / card_bytes
    again64 = again + n64 * light_s / files + read64 / SD_BYTES_PER_S
    report(
        "dashcam_reingest",
        {
            "card": f"{files} loop files, {w}x{h} at {fps:g} fps, {seconds:g} s, {card_bytes / 2**20:.1f} MiB",
            "first_ingest_s": first,
            "card_bytes": card_bytes,
            "reingest_cli_s": again,
            "reingest_cli_verify_known_s": verified,
            "ingest_import_s": startup,
            "light_step_s": light_s,
            "light_step_bytes_read": read_b,
            "light_step_read_over_card": read_b / card_bytes,
            "reingest_library_s": lib_s,
            "reingest_cli_over_first": again / first,
            "reingest_cli_verify_known_over_first": verified / first,
            "reingest_library_over_first": lib_s / first,
            "card64_loop_s": loop_s,
            "card64_files": n64,
            "card64_bytes_read": read64,
            "card64_first_ingest_s": first64,
            "card64_reingest_s": again64,
            "card64_reingest_over_first": again64 / first64,
            "card64_verify_known_over_first": (again + CARD_BYTES / SD_BYTES_PER_S) / first64,
            "target": 0.02,
            "load_avg_1min": os.getloadavg()[0],
            "note": "wall-clock on a shared 2-core machine; in-process figures the median of 3; 64 GB extrapolated",
        },
    )


if __name__ == "__main__":
    main()
