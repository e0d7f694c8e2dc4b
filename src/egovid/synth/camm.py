"""Synthetic CAMM (Camera Motion Metadata) tracks: the gyro and accelerometer of a known motion,
written into an MP4 the way Insta360 cameras and Street View apps write them.

:func:`camm_record` packs one record (the layouts are :data:`egovid.core.camera.camm.RECORD_FORMATS`,
the one copy of them); :func:`add_camm_track` appends a metadata track to a file PyAV wrote (its
samples at the end of ``mdat``, a ``trak`` in ``moov``: :mod:`egovid.synth.mp4box`), with the
handler ``camm`` (Insta360) or ``meta`` (the spec's), ``samples_per_chunk`` samples per chunk (so
``stsc`` matters) and, optionally, an edit list that starts the track later on the movie's
timeline. :func:`imu_for_motion` makes the IMU of a rendered clip: the gyro turns as the picture
does (each frame step's rotation held at a constant rate over the step, so integrating it gives
back the rendered orientations exactly), in camera axes, with a seeded bias and white noise, on
a clock ``offset_s`` ahead of the video's; the accelerometer reads gravity through the same
orientations plus seeded noise.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass

import numpy as np

from egovid.core.camera.camm import ACCEL, GYRO, RECORD_FORMATS
from egovid.core.rotations import so3_log
from egovid.core.video.isobmff import iter_boxes
from egovid.synth.mp4box import add_to_mdat, box

#: Standard gravity (m/s²).
G = 9.80665


def camm_record(kind: int, *values) -> bytes:
    """One CAMM record: reserved 0, ``kind``, the payload of :data:`RECORD_FORMATS` (little-endian)."""
    return struct.pack("<HH", 0, kind) + struct.pack(RECORD_FORMATS[kind], *values)


def _full(kind: str, version: int, payload: bytes) -> bytes:
    return box(kind, struct.pack(">I", version << 24) + payload)


def _movie_timescale(path: str | os.PathLike) -> int:
    """The ``mvhd`` time scale (ticks per second) of the MP4 ``path``."""
    with open(path, "rb") as fh:
        data = fh.read()
    for kind, at, payload, size in iter_boxes(data):
        if kind == "moov":
            for k, _, p, _ in iter_boxes(data, payload, at + size):
                if k == "mvhd":
                    return struct.unpack_from(">I", data, p + 4 + (16 if data[p] == 1 else 8))[0]
    raise ValueError(f"{path}: no mvhd")


def camm_trak(
    track_id: int,
    chunk_offsets: list[int],
    sizes: list[int],
    durations: list[int],
    *,
    timescale: int,
    samples_per_chunk: int,
    handler: str = "camm",
    start_s: float = 0.0,
    movie_timescale: int = 1000,
) -> bytes:
    """The ``trak`` box of a CAMM track whose samples (``sizes`` bytes, ``durations`` ticks of
    ``timescale``) lie in chunks of ``samples_per_chunk`` at ``chunk_offsets``; ``start_s`` > 0
    adds an edit list with an empty edit of that many seconds (the track starts later)."""
    n = len(sizes)
    total = int(sum(durations))
    tkhd = _full("tkhd", 0, struct.pack(">IIIII", 0, 0, track_id, 0, total * movie_timescale // timescale) + bytes(60))
    mdhd = _full("mdhd", 0, struct.pack(">IIIIHH", 0, 0, timescale, total, 0x55C4, 0))
    hdlr = _full(
        "hdlr", 0, struct.pack(">I4s", 0, handler.encode("latin-1")) + bytes(12) + b"CameraMetadataMotionHandler\0"
    )
    entry = box("camm", bytes(6) + struct.pack(">H", 1))  # SampleEntry: reserved, data_reference_index
    stsd = _full("stsd", 0, struct.pack(">I", 1) + entry)
    runs: list[list[int]] = []
    for d in durations:
        if runs and runs[-1][1] == d:
            runs[-1][0] += 1
        else:
            runs.append([1, int(d)])
    stts = _full("stts", 0, struct.pack(">I", len(runs)) + b"".join(struct.pack(">II", *r) for r in runs))
    last = n - samples_per_chunk * (len(chunk_offsets) - 1)
    stsc_rows = [(1, samples_per_chunk, 1)]
    if last != samples_per_chunk:
        stsc_rows.append((len(chunk_offsets), last, 1))
    stsc = _full("stsc", 0, struct.pack(">I", len(stsc_rows)) + b"".join(struct.pack(">III", *r) for r in stsc_rows))
    stsz = _full("stsz", 0, struct.pack(">II", 0, n) + struct.pack(f">{n}I", *sizes))
    stco = _full(
        "stco", 0, struct.pack(">I", len(chunk_offsets)) + struct.pack(f">{len(chunk_offsets)}I", *chunk_offsets)
    )
    dinf = box("dinf", _full("dref", 0, struct.pack(">I", 1) + box("url ", struct.pack(">I", 1))))  # self-contained
    minf = box("minf", _full("nmhd", 0, b"") + dinf + box("stbl", stsd + stts + stsc + stsz + stco))
    edts = b""
    if start_s > 0:
        empty = round(start_s * movie_timescale)
        rows = struct.pack(">Iii", empty, -1, 0x10000) + struct.pack(
            ">Iii", total * movie_timescale // timescale, 0, 0x10000
        )
        edts = box("edts", _full("elst", 0, struct.pack(">I", 2) + rows))
    return box("trak", tkhd + edts + box("mdia", mdhd + hdlr + minf))


def add_camm_track(
    path: str | os.PathLike,
    samples: list[bytes],
    durations: list[int],
    *,
    timescale: int = 10000,
    samples_per_chunk: int = 4,
    handler: str = "camm",
    start_s: float = 0.0,
    track_id: int = 99,
) -> None:
    """Append a CAMM track of ``samples`` (each ``durations`` ticks of ``timescale`` long) to the
    MP4 ``path`` (as PyAV writes it: ``moov`` last, after ``mdat``); see :func:`camm_trak`."""
    chunks = [b"".join(samples[i : i + samples_per_chunk]) for i in range(0, len(samples), samples_per_chunk)]
    sizes = [len(s) for s in samples]
    movie = _movie_timescale(path)
    add_to_mdat(
        path,
        chunks,
        lambda offsets: camm_trak(
            track_id,
            offsets,
            sizes,
            durations,
            timescale=timescale,
            samples_per_chunk=samples_per_chunk,
            handler=handler,
            start_s=start_s,
            movie_timescale=movie,
        ),
    )


@dataclass(frozen=True)
class CammImuTruth:
    """What :func:`imu_for_motion` wrote: ``times`` (N,) s on the CAMM clock (video time +
    ``offset_s``), ``gyro`` (N, 3) rad/s and ``accel`` (N, 3) m/s² as stored (camera axes, with
    bias and noise), ``bias`` (3,) rad/s, ``down_world`` (3,) the world's down direction in the
    frame of the rendered orientations' first frame."""

    times: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    offset_s: float
    bias: np.ndarray
    down_world: np.ndarray


def imu_for_motion(
    R: np.ndarray,
    fps: float,
    *,
    rate_hz: float = 200.0,
    offset_s: float = 0.04,
    bias_deg_s: tuple[float, float, float] = (0.4, -0.3, 0.2),
    noise_deg_s: float = 0.2,
    accel_noise: float = 0.05,
    gravity_world: tuple[float, float, float] = (0.0, 1.0, 0.0),
    seed: int = 0,
) -> CammImuTruth:
    """The gyro and accelerometer of a camera whose camera-to-world orientations at frames
    ``k / fps`` are ``R`` (K, 3, 3) (see the module docstring). ``gravity_world``: the world's
    down direction in ``R``'s world; the accelerometer reads ``-G · Rᵀ down``."""
    R = np.asarray(R, float)
    rates = so3_log(np.swapaxes(R[:-1], 1, 2) @ R[1:]) * fps  # (K-1, 3) camera axes
    rng = np.random.default_rng(seed)
    t_video = np.arange(0.0, (len(R) - 1) / fps, 1.0 / rate_hz)
    step = np.minimum((t_video * fps).astype(int), len(rates) - 1)
    bias = np.radians(np.asarray(bias_deg_s, float))
    gyro = rates[step] + bias + np.radians(noise_deg_s) * rng.normal(size=(len(t_video), 3))
    # The orientation at each sample: the frame's, turned on at the step's rate.
    from scipy.spatial.transform import Rotation

    frac = (t_video - step / fps)[:, None]
    R_t = R[step] @ Rotation.from_rotvec(rates[step] * frac).as_matrix()
    down = np.asarray(gravity_world, float)
    down = down / np.linalg.norm(down)
    accel = -G * np.einsum("nji,j->ni", R_t, down) + accel_noise * rng.normal(size=(len(t_video), 3))
    return CammImuTruth(t_video + offset_s, gyro, accel, offset_s, bias, R[0].T @ down)


def write_camm_imu(
    path: str | os.PathLike,
    truth: CammImuTruth,
    *,
    handler: str = "camm",
    timescale: int = 10000,
    samples_per_chunk: int = 4,
) -> int:
    """Append ``truth``'s IMU to the MP4 ``path`` as a CAMM track, two records per sample (a gyro
    and an accelerometer reading of the same instant, as Insta360 packs them), the first sample
    at ``truth.times[0]`` through an edit list; returns the number of samples."""
    samples = [
        camm_record(GYRO, *map(float, g)) + camm_record(ACCEL, *map(float, a))
        for g, a in zip(truth.gyro, truth.accel, strict=True)
    ]
    ticks = np.round(truth.times * timescale).astype(np.int64)
    durations = [*np.diff(ticks).tolist(), int(np.median(np.diff(ticks)))]
    add_camm_track(
        path, samples, durations, timescale=timescale, samples_per_chunk=samples_per_chunk, handler=handler,
        start_s=float(ticks[0]) / timescale,
    )  # fmt: skip
    return len(samples)
