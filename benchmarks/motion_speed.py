"""Speed of `egovid fpv motion` at 1280x720 against decoding the same clip (target: >= 30 fps).

Prints frames per second of the whole rotation estimation (decode, features, pairs at lag 1 and
5, pose graph) and of decoding alone (the peer: no estimator can beat its own decoder), their
ratio, and the accuracy against the synthetic ground truth.
"""

from __future__ import annotations

import os

import numpy as np

from egovid.core.motion.source import camera_motion
from egovid.core.trajectory import Trajectory, read_motion_csv
from egovid.core.video import iter_frames

from _common import cache_dir, report, running_clip, timed


def main() -> None:
    clip = running_clip(cache_dir("motion") / "running720.mp4")
    n = sum(1 for _ in iter_frames(clip, gray=True))  # warm the file cache
    _, t_dec = timed(lambda: sum(1 for _ in iter_frames(clip, gray=True)))
    _, t_bgr = timed(lambda: sum(1 for _ in iter_frames(clip)))
    cm, t_est = timed(camera_motion, clip)  # what `fpv motion` runs (the clip has no gyro: vision)
    est = cm.vision
    gt = read_motion_csv(clip.with_name(clip.stem + ".gt.csv")).relative_to_first()
    err = np.sqrt(np.mean((est.trajectory.euler() - gt.euler()) ** 2, axis=0))
    err_chain = np.sqrt(np.mean((Trajectory(gt.times, est.chained).euler() - gt.euler()) ** 2, axis=0))
    report(
        "motion_speed",
        {
            "clip": f"{clip.name} 1280x720, {n} frames",
            "cores": os.cpu_count(),
            "egovid_motion_fps": n / t_est,
            "decode_only_fps_grey": n / t_dec,
            "decode_only_fps_bgr": n / t_bgr,
            "ratio_to_grey_decode": (n / t_est) / (n / t_dec),
            "target_fps": 30.0,
            "meets_target": n / t_est >= 30.0,
            "rms_error_deg_yaw_pitch_roll_graph": err.round(4).tolist(),
            "rms_error_deg_yaw_pitch_roll_chain": err_chain.round(4).tolist(),
            "pose_graph_seconds": est.seconds["graph"],
        },
    )


if __name__ == "__main__":
    main()
