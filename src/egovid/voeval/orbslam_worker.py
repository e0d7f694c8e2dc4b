"""Run ORB-SLAM3 (pyorbslam3, monocular) on a video, in its own process.
Usage: python -m egovid.voeval.orbslam_worker VIDEO OUT.json SETTINGS.json

``SETTINGS.json`` is what :func:`settings` makes (vocabulary, pinhole camera, frame rate, ORB
extractor). Writes ``{"rotations": {frame: camera-to-world 3x3}, "positions": {frame: camera
centre}, "frames": N, "notes": {"states": [[state, first frame, frames], ...], ...}}`` for the
frames tracked, frame keys as six-digit indices ("000123"). The tracking state of every frame
(ORB-SLAM3's own: NOT_INITIALIZED, OK, RECENTLY_LOST, LOST, ...) is kept run by run, so a cell
that gave no pose says whether ORB-SLAM3 never initialised or initialised and was reset
(:func:`reason`).

**ORB settings per dataset camera** (:data:`ORB_PROFILES`): for the datasets ORB-SLAM3 ships
monocular settings for (EuRoC, TUM RGB-D, KITTI), the worker uses those (features, FAST
thresholds; the camera is always the sequence's own, undistorted); for everything else (the
synthetic scenes, frame folders, gyro videos) egovid's: 1500 features (2000 above 752x480) and FAST
thresholds 12 / 5, because ORB-SLAM3's 1000 features and 20 / 7 did not initialise on the 320x240
synthetic orbit.

The worker decodes the video itself (once, streamed): no folder of PNG frames is written and read
back per cell. The grey frames are bit-identical to what ORB-SLAM3 was given before from PNG files
(``cv2.imread(png, IMREAD_GRAYSCALE)``, i.e. libpng's RGB-to-grey): ITU-R BT.601 weights in 15-bit
fixed point, truncated (:func:`grey`).
"""

from __future__ import annotations

import itertools
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.video import iter_frames

SETTINGS = """%YAML:1.0
Camera.type: "PinHole"
Camera.fx: {fx}
Camera.fy: {fy}
Camera.cx: {cx}
Camera.cy: {cy}
Camera.k1: 0.0
Camera.k2: 0.0
Camera.p1: 0.0
Camera.p2: 0.0
Camera.width: {width}
Camera.height: {height}
Camera.fps: {fps}
Camera.RGB: 0
ORBextractor.nFeatures: {features}
ORBextractor.scaleFactor: {scale_factor}
ORBextractor.nLevels: {levels}
ORBextractor.iniThFAST: {ini_fast}
ORBextractor.minThFAST: {min_fast}
Viewer.KeyFrameSize: 0.05
Viewer.KeyFrameLineWidth: 1.0
Viewer.GraphLineWidth: 0.9
Viewer.PointSize: 2.0
Viewer.CameraSize: 0.08
Viewer.CameraLineWidth: 3.0
Viewer.ViewpointX: 0.0
Viewer.ViewpointY: -0.7
Viewer.ViewpointZ: -1.8
Viewer.ViewpointF: 500.0
"""

#: ORB extractor settings of ORB-SLAM3's own monocular examples, by dataset (Examples/Monocular/
#: EuRoC.yaml, TUM1.yaml-TUM3.yaml, KITTI00-02.yaml: scale factor 1.2, 8 levels in all).
ORB_PROFILES = {
    "euroc": {"features": 1000, "ini_fast": 20, "min_fast": 7, "from": "ORB-SLAM3 EuRoC.yaml"},
    "tum": {"features": 1000, "ini_fast": 20, "min_fast": 7, "from": "ORB-SLAM3 TUM1-3.yaml"},
    "kitti": {"features": 2000, "ini_fast": 20, "min_fast": 7, "from": "ORB-SLAM3 KITTI00-02.yaml"},
}

#: libpng's png_set_rgb_to_gray(0.299, 0.587) weights (R, G, B) in 1/32768, as it rounds them.
_GREY_WEIGHTS = (9797, 19234, 3737)


def orb_profile(dataset: str, width: int, height: int) -> dict:
    """ORB extractor settings for footage of ``dataset`` at ``width`` x ``height`` pixels."""
    if dataset in ORB_PROFILES:
        return {**ORB_PROFILES[dataset], "scale_factor": 1.2, "levels": 8}
    features = 1500 if width * height <= 752 * 480 else 2000
    return {"features": features, "ini_fast": 12, "min_fast": 5, "scale_factor": 1.2, "levels": 8, "from": "egovid"}


def settings(vocabulary: str, intr: Intrinsics, fps: float, dataset: str) -> dict:
    """The worker's SETTINGS.json: vocabulary file, pinhole camera (pixels), frames per second and
    ORB settings (:func:`orb_profile`)."""
    camera = {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy, "width": intr.width, "height": intr.height}
    return {"vocabulary": vocabulary, **camera, "fps": fps, "orb": orb_profile(dataset, intr.width, intr.height)}


def grey(bgr: np.ndarray) -> np.ndarray:
    """(H, W) uint8 luma of a (H, W, 3) BGR uint8 frame, exactly as libpng computes it."""
    wr, wg, wb = _GREY_WEIGHTS
    im = bgr.astype(np.uint32)
    return ((im[..., 2] * wr + im[..., 1] * wg + im[..., 0] * wb) >> 15).astype(np.uint8)


def state_runs(states: list[str]) -> list[list]:
    """Run-length form ``[[state, first frame, frames], ...]`` of per-frame tracking states."""
    runs: list[list] = []
    for k, s in enumerate(states):
        if runs and runs[-1][0] == s:
            runs[-1][2] += 1
        else:
            runs.append([s, k, 1])
    return runs


def reason(notes: dict) -> str:
    """One line on how ORB-SLAM3 tracked, from the worker's notes ("" when it tracked throughout)."""
    runs = notes.get("states") or []
    n = sum(r[2] for r in runs)
    ok = [r for r in runs if r[0] in ("OK", "OK_KLT")]
    if not runs or (len(ok) == 1 and ok[0][1] == 0 and ok[0][2] == n):
        return ""
    if not ok:
        waiting = sum(r[2] for r in runs if r[0] in ("NOT_INITIALIZED", "NO_IMAGES_YET", "SYSTEM_NOT_READY"))
        return f"ORB-SLAM3 never initialised (not initialised on {waiting} of {n} frames)"
    resets = sum(1 for a, b in itertools.pairwise(runs) if b[0] == "NOT_INITIALIZED" and a[0] != b[0])
    lost = sum(r[2] for r in runs if r[0] in ("LOST", "RECENTLY_LOST"))
    parts = [f"ORB-SLAM3 initialised at frame {ok[0][1]}", f"tracked {sum(r[2] for r in ok)} of {n} frames"]
    if lost:
        parts.append(f"lost on {lost}")
    if resets:
        parts.append(f"map reset {resets} time{'s' * (resets > 1)} (tracking lost soon after initialising)")
    return ", ".join(parts)


def main() -> None:
    import pyorbslam3  # heavy optional dependency, only in this worker process

    video, out, cfg = Path(sys.argv[1]), Path(sys.argv[2]), json.loads(Path(sys.argv[3]).read_text())
    n = 0
    with tempfile.TemporaryDirectory() as tmp:
        yaml = Path(tmp) / "settings.yaml"
        yaml.write_text(SETTINGS.format(**{k: v for k, v in cfg.items() if k != "orb"}, **cfg["orb"]))
        slam = pyorbslam3.Slam(cfg["vocabulary"], yaml, pyorbslam3.Sensor.MONOCULAR)
        rotations, positions, states = {}, {}, []
        try:
            for f in iter_frames(video):
                r = slam.track_monocular(grey(f.image), f.index / float(cfg["fps"]))
                states.append(str(r.state).rsplit(".", 1)[-1])
                if r.pose_valid:
                    T = np.asarray(r.pose_wc)
                    rotations[f"{f.index:06d}"] = T[:3, :3].tolist()
                    positions[f"{f.index:06d}"] = T[:3, 3].tolist()
                n = f.index + 1
        finally:
            slam.shutdown()
    notes = {"states": state_runs(states), "orb": cfg["orb"]}
    out.write_text(json.dumps({"rotations": rotations, "positions": positions, "frames": n, "notes": notes}))


if __name__ == "__main__":
    main()
