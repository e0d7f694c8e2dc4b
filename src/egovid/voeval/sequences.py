"""Real sequences in the evaluation grid: ``--sequence FORMAT:PATH``.

A sequence is read by :mod:`egovid.voeval.datasets` (or, for ``gyro:``, from a video and its
embedded gyro by :mod:`egovid.voeval.gyro_reference`), its frames are matched to the reference
orientations by timestamp (:func:`match_reference`: spherical interpolation between the two
reference samples around each frame), and the longest run of matched frames (at most ``--frames``)
is stored like a synthetic scene: a lossless video (undistorted where the dataset has a lens
distortion, so every odometer sees a pinhole camera), its reference trajectory (TUM) and a JSON
description (:class:`egovid.voeval.scenes.SceneTruth`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from egovid.core.camera.intrinsics import Intrinsics
from egovid.core.errors import EgovidError
from egovid.core.rotations import so3_exp, so3_log
from egovid.voeval.datasets import READERS, RawSequence, check_times
from egovid.voeval.scenes import SceneTruth, lossless_writer, relative_to_first

FORMATS = (*READERS, "gyro")
FORMAT_HELP = {
    "tum": "TUM RGB-D folder (rgb.txt, groundtruth.txt)",
    "euroc": "EuRoC MAV folder (mav0/cam0, state_groundtruth_estimate0)",
    "kitti": "KITTI odometry sequence folder (image_0, times.txt, calib.txt, poses)",
    "frames": "folder of images + TUM trajectory + camera.txt",
    "gyro": "video with an embedded gyro (GoPro, Sony, Insta360, DJI): the gyro is the reference",
}


@dataclass(frozen=True)
class SequenceSpec:
    """``FORMAT:PATH`` as given on the command line, and the scene name of its cells."""

    fmt: str
    path: Path
    name: str

    @property
    def text(self) -> str:
        return f"{self.fmt}:{self.path}"


def parse_specs(texts: list[str]) -> list[SequenceSpec]:
    """Parse and check ``--sequence`` values (the path must exist); names are made unique."""
    specs: list[SequenceSpec] = []
    used: set[str] = set()
    for text in texts:
        fmt, sep, rest = text.partition(":")
        fmt = fmt.strip().lower()
        if not sep or fmt not in FORMATS:
            raise EgovidError(
                f"--sequence {text!r} does not start with a known format",
                "write FORMAT:PATH with FORMAT one of " + ", ".join(FORMATS),
            )
        path = Path(rest).expanduser()
        if not path.exists():
            raise EgovidError(f"--sequence {text!r}: {path} does not exist", f"give the path of a {FORMAT_HELP[fmt]}")
        if fmt == "gyro" and not path.is_file():
            raise EgovidError(f"--sequence {text!r}: {path} is not a video file", "give gyro:VIDEO.mp4")
        if fmt != "gyro" and not path.is_dir():
            raise EgovidError(f"--sequence {text!r}: {path} is not a folder", f"give the {FORMAT_HELP[fmt]}")
        base = re.sub(r"[^A-Za-z0-9_.-]+", "-", (path.stem if path.is_file() else path.resolve().name)) or fmt
        name, k = base, 2
        while name in used:
            name, k = f"{base}-{k}", k + 1
        used.add(name)
        specs.append(SequenceSpec(fmt, path, name))
    return specs


def match_reference(
    frame_times: np.ndarray, ref_times: np.ndarray, ref_R: np.ndarray, *, max_gap: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Reference orientation at each frame time.

    Interpolates spherically (slerp) between the reference samples just before and just after
    each frame. A frame is matched only inside the reference's time span and when those two
    samples are at most ``max_gap`` seconds apart (default: 3 x the median reference period, at
    least 50 ms). Returns (R (N, 3, 3), matched (N,) bool); unmatched frames get the identity.
    """
    t = np.asarray(frame_times, dtype=float)
    rt = np.asarray(ref_times, dtype=float)
    if max_gap is None:
        max_gap = max(3.0 * float(np.median(np.diff(rt))), 0.05) if len(rt) > 1 else 0.0
    j = np.clip(np.searchsorted(rt, t, side="right") - 1, 0, max(len(rt) - 2, 0))
    inside = (t >= rt[0]) & (t <= rt[-1])
    R = np.repeat(np.eye(3)[None], len(t), 0)
    if len(rt) < 2:
        exact = inside & (np.abs(t - rt[0]) < 1e-9)
        R[exact] = ref_R[0]
        return R, exact
    gap = rt[j + 1] - rt[j]
    on_sample = (np.abs(t - rt[j]) <= 1e-9) | (np.abs(t - rt[j + 1]) <= 1e-9)
    ok = inside & ((gap <= max_gap + 1e-12) | on_sample)
    a = np.clip((t - rt[j]) / np.where(gap > 0, gap, 1.0), 0.0, 1.0)
    R0, R1 = ref_R[j], ref_R[j + 1]
    step = so3_log(np.swapaxes(R0, -1, -2) @ R1)
    R_i = R0 @ so3_exp(step * a[:, None])
    R[ok] = R_i[ok]
    return R, ok


def longest_run(mask: np.ndarray) -> tuple[int, int]:
    """(start, stop) of the longest run of True in ``mask`` (stop exclusive; (0, 0) if none)."""
    best, start = (0, 0), None
    for k, v in enumerate([*np.asarray(mask, bool).tolist(), False]):
        if v and start is None:
            start = k
        elif not v and start is not None:
            if k - start > best[1] - best[0]:
                best = (start, k)
            start = None
    return best


def open_sequence(spec: SequenceSpec) -> RawSequence:
    """Read the dataset of a ``tum:``, ``euroc:``, ``kitti:`` or ``frames:`` spec."""
    seq = READERS[spec.fmt](spec.path)
    seq.name = spec.name
    check_times(seq)
    return seq


def _read_image(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise EgovidError(f"cannot read image {path}", "the file is missing or corrupt")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


def import_sequence(seq: RawSequence, video: Path, max_frames: int | None = None) -> SceneTruth:
    """Store the longest run of frames matched to the reference (at most ``max_frames``) as a
    lossless video at ``video`` (undistorted, cropped to an even size) and return its truth."""
    R_all, ok = match_reference(seq.image_times, seq.ref_times, seq.ref_rot)
    a, b = longest_run(ok)
    if b - a < 2:
        raise EgovidError(
            f"{seq.source}: fewer than two frames fall inside the reference trajectory's time span "
            f"(frames {seq.image_times[0]:.3f}-{seq.image_times[-1]:.3f} s, reference "
            f"{seq.ref_times[0]:.3f}-{seq.ref_times[-1]:.3f} s)",
            "check that images and reference use the same clock",
        )
    if max_frames is not None:
        b = min(b, a + max_frames)
    first = _read_image(seq.images[a])
    h0, w0 = first.shape[:2]
    w, h = w0 - w0 % 2, h0 - h0 % 2
    cam = seq.camera
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
    maps = None
    if cam.distortion and any(cam.distortion):
        maps = cv2.initUndistortRectifyMap(K, np.array(cam.distortion), None, K, (w0, h0), cv2.CV_16SC2)
    times = seq.image_times[a:b] - seq.image_times[a]
    fps = 1.0 / float(np.median(np.diff(times)))
    with lossless_writer(video, w, h, fps) as wr:
        for k in range(a, b):
            img = first if k == a else _read_image(seq.images[k])
            if img.shape[:2] != (h0, w0):
                raise EgovidError(f"{seq.images[k]} is {img.shape[1]}x{img.shape[0]}, not {w0}x{h0}", "one size")
            if maps is not None:
                img = cv2.remap(img, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            wr.write(img[:h, :w], float(times[k - a]))
    R, t = relative_to_first(R_all[a:b], _positions(seq, times + seq.image_times[a]))
    meta = {
        "kind": "real",
        "format": seq.fmt,
        "source": str(seq.source),
        "motion": "general",
        "frames_in_sequence": len(seq.images),
        "frames_matched": int(ok.sum()),
        "first_frame": a,
        "reference_rate_hz": round(1.0 / float(np.median(np.diff(seq.ref_times))), 3),
        "undistorted": maps is not None,
        "translation_unit": "m",
    }
    intr = Intrinsics(w, h, float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy))
    return SceneTruth(seq.name, R, intr, fps, times=times, meta=meta, t=t)


def _positions(seq: RawSequence, frame_times: np.ndarray) -> np.ndarray | None:
    """The reference's camera centre at each frame time (linear between samples; None where the
    dataset gives no positions or they never change)."""
    p = seq.ref_pos
    if p is None or not np.any(np.abs(p - p[0]) > 0):
        return None
    return np.stack([np.interp(frame_times, seq.ref_times, p[:, k]) for k in range(3)], axis=1)
