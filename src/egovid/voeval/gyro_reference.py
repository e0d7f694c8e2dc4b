"""``gyro:VIDEO`` — a real video whose own embedded gyro is the reference orientation."""

from __future__ import annotations

from pathlib import Path

from egovid.errors import EgovidError


def check_gyro_video(path: Path) -> None:
    """Raise :class:`EgovidError` unless ``path`` is a video with an embedded gyro."""
    from egovid.io.telemetry import read_camera_telemetry
    from egovid.io.video import probe

    probe(path)
    if not read_camera_telemetry(path).has_gyro:
        raise EgovidError(
            f"{path} has no embedded gyro that telemetry-parser can read",
            "give a GoPro, Sony, Insta360 or DJI video with gyro telemetry, or use another --sequence format",
        )


def import_gyro_sequence(spec, video: Path, max_frames: int | None = None):
    raise EgovidError("gyro: sequences are not available yet", "use tum:, euroc:, kitti: or frames:")
