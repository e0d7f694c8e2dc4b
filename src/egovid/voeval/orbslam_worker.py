"""Run ORB-SLAM3 (pyorbslam3, monocular) on a video, in its own process.
Usage: python -m egovid.voeval.orbslam_worker VIDEO OUT.json VOCAB fx fy cx cy width height fps

Writes {"rotations": {frame: camera-to-world 3x3}, "frames": N} for the frames tracked, frame
keys as six-digit indices ("000123").

The worker decodes the video itself (once, streamed): no folder of PNG frames is written and read
back per cell. The grey frames are bit-identical to what ORB-SLAM3 was given before from PNG files
(``cv2.imread(png, IMREAD_GRAYSCALE)``, i.e. libpng's RGB-to-grey): ITU-R BT.601 weights in 15-bit
fixed point, truncated (:func:`grey`).
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

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
ORBextractor.scaleFactor: 1.2
ORBextractor.nLevels: 8
ORBextractor.iniThFAST: 12
ORBextractor.minThFAST: 5
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

#: libpng's png_set_rgb_to_gray(0.299, 0.587) weights (R, G, B) in 1/32768, as it rounds them.
_GREY_WEIGHTS = (9797, 19234, 3737)


def grey(bgr):
    """(H, W) uint8 luma of a (H, W, 3) BGR uint8 frame, exactly as libpng computes it."""
    import numpy as np

    wr, wg, wb = _GREY_WEIGHTS
    im = bgr.astype(np.uint32)
    return ((im[..., 2] * wr + im[..., 1] * wg + im[..., 0] * wb) >> 15).astype(np.uint8)


def main() -> None:
    import numpy as np
    import pyorbslam3

    from egovid.core.video import iter_frames

    video, out, vocab = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
    fx, fy, cx, cy, width, height, fps = sys.argv[4:11]
    n = 0
    with tempfile.TemporaryDirectory() as tmp:
        settings = Path(tmp) / "settings.yaml"
        # 1500 features up to EuRoC's 752x480 (ORB-SLAM3's own EuRoC/TUM settings use 1000, which
        # did not initialise on the 320x240 orbit), 2000 for KITTI-size frames as ORB-SLAM3 does.
        features = 1500 if int(width) * int(height) <= 752 * 480 else 2000
        settings.write_text(
            SETTINGS.format(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height, fps=fps, features=features)
        )
        slam = pyorbslam3.Slam(vocab, settings, pyorbslam3.Sensor.MONOCULAR)
        rotations = {}
        try:
            for f in iter_frames(video):
                r = slam.track_monocular(grey(f.image), f.index / float(fps))
                if r.pose_valid:
                    rotations[f"{f.index:06d}"] = np.asarray(r.pose_wc)[:3, :3].tolist()
                n = f.index + 1
        finally:
            slam.shutdown()
    out.write_text(json.dumps({"rotations": rotations, "frames": n}))


if __name__ == "__main__":
    main()
