"""The fleet commands on a small synthetic fleet, as a user runs them, and the map screenshot of
docs/dashcam.md (headless Chromium).

Four drives through the synthetic town on four days (the main road; a turn onto the side street;
the main road again, recorded as three loop files sharing one GPS log; an event file), ingested
with the CLI, then `find`, `clip`, `report --html` and a screenshot of the page. Prints what each
command printed and the figures the docs quote.

    python experiments/dashcam_fleet_map.py [OUT_FOLDER]   (default: a temporary folder)
"""

from __future__ import annotations

import datetime as dt
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import av

from egovid.synth.drive import DriveSpec, Light, render_drive

W, H, FPS = 640, 360, 15.0
DAY = dt.datetime(2026, 5, 4, 8, 0, 0, tzinfo=dt.UTC)
ROOT = Path(__file__).resolve().parents[1]


def cli(*args) -> str:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "egovid", *map(str, args)], capture_output=True, text=True)
    print(f"$ egovid {' '.join(map(str, args))}   ({time.perf_counter() - t:.1f} s)\n{r.stdout}{r.stderr}")
    if r.returncode:
        raise SystemExit(r.returncode)
    return r.stdout


def split(video: Path, folder: Path, parts: int, start: dt.datetime) -> None:
    """Cut a drive into loop files (lossless), named and timed like a Viofo's."""
    with av.open(str(video)) as c:
        frames = [f.to_ndarray(format="yuv420p") for f in c.decode(video=0)]
    edges = [round(k * len(frames) / parts) for k in range(parts + 1)]
    for k in range(parts):
        t = start + dt.timedelta(seconds=edges[k] / FPS)
        with av.open(str(folder / f"{t:%Y_%m%d_%H%M%S}_{k + 1:04d}F.MP4"), "w") as out:
            out.metadata["creation_time"] = t.strftime("%Y-%m-%dT%H:%M:%SZ")
            s = out.add_stream("libx264", rate=int(FPS))
            s.width, s.height, s.pix_fmt, s.options = W, H, "yuv420p", {"qp": "0", "preset": "ultrafast"}
            for i, img in enumerate(frames[edges[k] : edges[k + 1]]):
                vf = av.VideoFrame.from_ndarray(img, format="yuv420p")
                vf.pts = i
                for p in s.encode(vf):
                    out.mux(p)
            for p in s.encode():
                out.mux(p)


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    src = out / "videos"
    src.mkdir(exist_ok=True)
    light = Light.preset("noon")
    specs = {
        "monday": DriveSpec(legs=[("main", 250.0, 560.0)], cruise=11.0, seed=1, light=light, start_time=DAY),
        "tuesday": DriveSpec(legs=[("main", 250.0, 445.0), ("side", 5.0, 120.0)], cruise=10.0, seed=2, light=light,
                             start_time=DAY + dt.timedelta(days=1)),
        "wednesday": DriveSpec(legs=[("main", 300.0, 560.0)], cruise=9.0, seed=3, light=light,
                               start_time=DAY + dt.timedelta(days=2)),
        "thursday": DriveSpec(legs=[("main", 380.0, 470.0)], cruise=12.0, seed=4, light=light,
                              start_time=DAY + dt.timedelta(days=3)),
    }  # fmt: skip
    for name, spec in specs.items():
        render_drive(spec, src / f"{name}.mp4", width=W, height=H, fps=FPS, gps_format="gpx")
    loops = src / "wednesday-loops"
    loops.mkdir(exist_ok=True)
    split(src / "wednesday.mp4", loops, 3, specs["wednesday"].start_time)
    event = src / "RO"
    event.mkdir(exist_ok=True)
    shutil.copy(src / "thursday.mp4", event / "2026_0507_080000_0001F.MP4")
    archive = out / "archive"
    if archive.exists():
        shutil.rmtree(archive)
    cli("dashcam", "init", archive)
    cli("dashcam", "ingest", archive, src / "monday.mp4", "--gps", src / "monday.gpx", "--measure-savings")
    cli("dashcam", "ingest", archive, src / "tuesday.mp4", "--gps", src / "tuesday.gpx", "--measure-savings")
    cli("dashcam", "ingest", archive, loops, "--gps", src / "wednesday.gpx", "--measure-savings")
    cli("dashcam", "ingest", archive, event, "--gps", src / "thursday.gpx", "--measure-savings")
    cli("dashcam", "list", archive)
    from egovid.dashcam.route.tracks import read_track

    track = read_track(src / "monday.gpx")
    k = len(track) * 2 // 3
    cli("dashcam", "find", archive, "--near", f"{track.lat[k]:.6f},{track.lon[k]:.6f}", "--radius", "30")
    cli("dashcam", "clip", archive, "--at", "2026-05-05T08:00:12Z", "--before", "3", "--after", "3",
        "-o", out / "incident.mp4")  # fmt: skip
    page = out / "report.html"
    cli("dashcam", "report", archive, "--html", page, "--colour", "saving", "--tiles", "none")
    shot = out / "dashcam_map.png"
    chromium = shutil.which("chromium") or "chromium"
    subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={out / 'profile'}",
                    "--virtual-time-budget=5000", "--window-size=1100,700", f"--screenshot={shot}", page.as_uri()],
                   check=True, capture_output=True)  # fmt: skip
    print(f"screenshot {shot} ({shot.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="egovid-fleet-")))
