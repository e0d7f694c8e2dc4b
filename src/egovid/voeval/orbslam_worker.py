"""Run ORB-SLAM3 (pyorbslam3, monocular) on a folder of PNG frames, in its own process.
Usage: python -m egovid.voeval.orbslam_worker IMAGES OUT.json VOCAB fx fy cx cy width height fps

Writes {"rotations": {frame: camera-to-world 3x3}} for the frames tracked.
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


def main() -> None:
    import cv2
    import numpy as np
    import pyorbslam3

    images, out, vocab = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
    fx, fy, cx, cy, width, height, fps = sys.argv[4:11]
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
            for k, f in enumerate(sorted(images.glob("*.png"))):
                img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
                r = slam.track_monocular(img, k / float(fps))
                if r.pose_valid:
                    rotations[f.stem] = np.asarray(r.pose_wc)[:3, :3].tolist()
        finally:
            slam.shutdown()
    out.write_text(json.dumps({"rotations": rotations}))


if __name__ == "__main__":
    main()
