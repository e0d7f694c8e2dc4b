"""The camera motion of a video from the source the user asks for: one function for every command.

Sources (``--source``):

* ``vision`` — the pictures (thesis ch. 6, :mod:`egovid.core.motion.estimate`). Works on any video;
  its noise floor is a few hundredths of a degree per frame, and it is blind where the picture
  is (black, featureless, motion-blurred frames are bridged and flagged).
* ``gyro`` — the camera's own gyroscope (GoPro GPMF, Sony, Insta360, DJI... through
  telemetry-parser): exact at high frequency, needs a sync (time offset and axis mapping, found
  against vision on the first ``SYNC_SECONDS`` seconds) and drifts slowly over long clips.
* ``camera-orientation`` — the orientation of the picture the camera recorded itself (GoPro
  CORI·IORI), the right description when it stabilised the picture electronically.
* ``fused`` — gyro between-factors and vision factors in one pose graph: the gyro's precision
  frame to frame, vision's lack of drift.
* ``auto`` — the gyro when the file has one, unless the camera stabilised the picture itself
  (GoPro HyperSmooth/EIS): then the body gyro does not describe the picture, and the camera's
  image orientation is used when recorded, vision otherwise. The reason is reported.

With a gyro and no ``--focal/--hfov``, the focal length is fitted from the gyro against the
matched points (:func:`egovid.core.motion.gyro.fit_focal`), and vision is re-fitted with it.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from egovid.core.camera.intrinsics import CameraModel, resolve_camera
from egovid.core.camera.telemetry import CameraTelemetry, read_camera_telemetry
from egovid.core.errors import EgovidError
from egovid.core.motion import gyro as gyro_mod
from egovid.core.motion.estimate import (
    CONF_MEASURED,
    MotionEstimate,
    MotionOptions,
    collect_pairs,
    refit,
    solve_motion,
)
from egovid.core.motion.posegraph import Edge
from egovid.core.trajectory import Trajectory
from egovid.core.video import frame_times, probe

#: What ``--source`` accepts.
SOURCES = ("auto", "vision", "gyro", "fused")
#: Seconds of video that vision measures to sync a gyro when the gyro alone is the source.
SYNC_SECONDS = 30.0
#: A focal-length fit moves the focal length only if it is this much (relative) off.
_REFIT_TOLERANCE = 0.005
#: Stated noise of one gyro step between frames (degrees); calibrated from the data in the graph.
_GYRO_STEP_SIGMA_DEG = 0.005

Progress = Callable[[str, int, int], None]


@dataclass
class CameraMotion:
    """The per-frame camera orientation of a video and how it was obtained.

    ``trajectory``: camera-to-world orientations (frame 0 = identity) at the frame times;
    ``confidence`` (N,): 1 = the step from the previous frame was measured, 0.5 = bridged (gyro,
    or only longer vision pairs), 0 = interpolated; ``source``: what was used (``vision``,
    ``gyro``, ``camera-orientation``, ``fused``); ``requested``: what was asked; ``reason``: why
    (in words); ``camera``: the intrinsics and their source; ``sync``: the gyro sync;
    ``focal_fit``: the gyro focal-length fit; ``comparison``: vision against the gyro where both
    ran; ``vision``: the vision estimate where it ran on the whole video.
    """

    trajectory: Trajectory
    confidence: np.ndarray
    source: str
    requested: str
    reason: str
    camera: CameraModel
    telemetry: CameraTelemetry = field(repr=False, default_factory=CameraTelemetry)
    sync: gyro_mod.GyroSync | None = None
    focal_fit: gyro_mod.FocalFit | None = None
    comparison: gyro_mod.RateComparison | None = None
    vision: MotionEstimate | None = field(default=None, repr=False)
    seconds: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready summary: source, reason, intrinsics, sync, fit, comparison, confidence."""
        tel = self.telemetry
        doc: dict = {
            "source": self.source,
            "requested": self.requested,
            "reason": self.reason,
            "frames": len(self.trajectory),
            "intrinsics": self.camera.to_dict(),
            "camera": {
                "make": tel.make,
                "model": tel.model,
                "lens_mode": tel.lens_name,
                "electronic_stabilization": tel.stabilization,
                "gyro_samples": len(tel.imu) if tel.imu is not None else 0,
                "gyro_rate_hz": round(tel.imu.rate_hz, 2) if tel.imu is not None else None,
            },
            "frames_bridged": int(np.sum(self.confidence < CONF_MEASURED)),
            "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
        }
        if self.sync is not None:
            doc["gyro_sync"] = self.sync.to_dict()
        if self.focal_fit is not None:
            doc["focal_fit"] = self.focal_fit.to_dict()
        if self.comparison is not None:
            doc["vision_vs_gyro"] = self.comparison.to_dict()
        if self.vision is not None:
            doc["vision"] = {
                "failed_pairs": self.vision.failed_pairs,
                "pairs": len(self.vision.pairs),
                "noise_scale": {k: round(v, 4) for k, v in self.vision.noise_scale.items()},
            }
        return doc


def choose_source(requested: str, telemetry: CameraTelemetry) -> tuple[str, str]:
    """The source to use for ``requested`` given what the file carries, and why (in words).

    Raises :class:`EgovidError` when ``gyro`` or ``fused`` is asked of a file without a gyro.
    """
    if requested not in SOURCES:
        raise EgovidError(f"unknown motion source {requested!r}", f"choose one of {', '.join(SOURCES)}")
    has_gyro = telemetry.has_gyro
    eis = telemetry.electronically_stabilized
    name = " ".join(x for x in (telemetry.make, telemetry.model) if x) or "the camera"
    if requested in ("gyro", "fused") and not has_gyro:
        raise EgovidError(
            f"--source {requested} needs a gyro, and this file records none", "use --source vision (or auto)"
        )
    if requested == "vision":
        return "vision", "asked for"
    if requested == "fused":
        why = "asked for"
        if eis:
            why += _eis_note(name, telemetry)
        return "fused", why
    if requested == "gyro":
        why = f"asked for ({name} gyro, {telemetry.imu.rate_hz:.0f} Hz)"
        if eis:
            why += _eis_note(name, telemetry)
        return "gyro", why
    # auto
    if not has_gyro:
        return "vision", "the file records no gyro"
    if eis:
        if telemetry.image_orientation is not None:
            return (
                "camera-orientation",
                f"{name} stabilised the picture itself ({telemetry.stabilization}): its recorded image orientation "
                "describes the picture, its body gyro does not",
            )
        return (
            "vision",
            f"{name} stabilised the picture itself ({telemetry.stabilization}) and records no image orientation: "
            "its body gyro does not describe the picture",
        )
    return "gyro", f"{name} records a gyro ({telemetry.imu.rate_hz:.0f} Hz) and did not stabilise the picture"


def _eis_note(name: str, telemetry: CameraTelemetry) -> str:
    return (
        f"; note: {name} stabilised the picture itself ({telemetry.stabilization}), "
        "so its body gyro does not describe the picture"
    )


def camera_motion(
    video: str | os.PathLike,
    source: str = "auto",
    *,
    focal: float | None = None,
    hfov: float | None = None,
    options: MotionOptions | None = None,
    progress: Progress | None = None,
) -> CameraMotion:
    """Per-frame camera orientation of ``video`` from ``source`` (see the module docstring).

    ``focal``/``hfov`` override the intrinsics (no gyro fit then); ``options`` tune vision;
    ``progress(stage, done, total)`` reports the stages (``motion``, ``sync``). Raises
    :class:`EgovidError` for unreadable videos and impossible requests (a gyro source on a file
    without one); everything else degrades with a reason.
    """
    t_start = time.perf_counter()
    opts = options or MotionOptions()
    info = probe(video)
    try:
        telemetry = read_camera_telemetry(video)
    except EgovidError:
        telemetry = CameraTelemetry()
    chosen, reason = choose_source(source, telemetry)
    camera = resolve_camera(video, focal, hfov, telemetry=telemetry)
    user_focal = camera.source == "flag"
    report = _stage(progress)
    # The body gyro helps vision too (focal-length fit, bridging gaps), unless the camera
    # stabilised the picture itself: then it does not describe the picture.
    uses_gyro = telemetry.has_gyro and (chosen in ("gyro", "fused") or not telemetry.electronically_stabilized)
    if chosen == "camera-orientation":
        track = gyro_mod.orientation_track(telemetry.image_orientation)
    elif uses_gyro:
        track = gyro_mod.integrate(telemetry.imu)
    else:
        track = None
    seconds: dict[str, float] = {}

    # Vision: on the whole video, except for a gyro-only source on a long clip (sync window).
    full_vision = chosen in ("vision", "fused") or info.duration <= SYNC_SECONDS * 1.5 or info.duration <= 0
    window = None if full_vision else max(2, int(SYNC_SECONDS * info.fps))
    # Matched points are kept for the focal-length fit, over at most 1.5 x the sync window (so a
    # short clip is re-fitted without decoding it again; a long one is decoded twice).
    keep = 0 if track is None or user_focal else int(SYNC_SECONDS * 1.5 * max(info.fps, 1.0)) + max(opts.lags)
    vopts = MotionOptions(**{**opts.__dict__, "keep_matches": keep, "max_frames": window})
    pairs = collect_pairs(video, camera.intrinsics, vopts, report("motion"))
    seconds["vision_pairs"] = pairs.seconds
    vision = solve_motion(pairs, camera.intrinsics, calibrate=vopts.calibrate, detail_hz=vopts.detail_hz)

    sync = fit = comparison = None
    gyro_track = track
    if track is not None:
        t0 = time.perf_counter()
        sync = _sync(track, vision, chosen == "camera-orientation")
        if not sync.trusted:
            if chosen in ("gyro", "camera-orientation", "fused"):
                reason += f"; but the gyro does not match the picture (r = {sync.r_vector:.2f}), so vision is used"
                chosen = "vision"
            track = sync = None
        elif chosen != "camera-orientation":
            track = gyro_mod.integrate(telemetry.imu, bias=sync.bias)
        seconds["sync"] = time.perf_counter() - t0
    if track is not None and not user_focal and pairs.matches:
        before = camera
        for attempt in range(2):  # vision angles are nearly, not exactly, proportional to 1/focal
            step = gyro_mod.fit_focal(
                [(i, j, p.Q) for i, j, p in pairs.pairs if p.ok],
                gyro_mod.frame_rotations(track, sync, vision.trajectory.times),
                camera.intrinsics.focal,
            )
            if attempt == 0:
                fit = step
            if not step.well_posed or abs(step.scale - 1.0) <= _REFIT_TOLERANCE:
                break
            previous = camera
            camera = before.with_focal(
                step.focal_px,
                "gyro-fit",
                f"fitted from the gyro on {step.pairs} frame pairs (the {before.source} gave "
                f"{before.intrinsics.focal:.1f} px: {before.detail})",
            )
            if len(pairs.times) <= keep:  # every pair's matches are kept: re-fit them (cheap)
                pairs = refit(pairs, previous.intrinsics, step.focal_px)
            elif chosen in ("vision", "fused") and attempt == 0:  # a long clip: measure it again
                pairs = collect_pairs(video, camera.intrinsics, vopts, report("motion (refit)"))
            else:
                pairs = None
                break
            vision = solve_motion(pairs, camera.intrinsics, calibrate=vopts.calibrate, detail_hz=vopts.detail_hz)
            sync = _sync(gyro_track, vision, chosen == "camera-orientation")
            if chosen != "camera-orientation":
                track = gyro_mod.integrate(telemetry.imu, bias=sync.bias)
        if fit is not None and fit.well_posed:
            fit = replace(fit, focal_px=camera.intrinsics.focal)
            if camera is before:
                camera = camera.with_focal(
                    camera.intrinsics.focal, camera.source, camera.detail + "; confirmed by the gyro"
                )
    if track is not None and pairs is not None:
        comparison = gyro_mod.compare_rotations(
            vision.trajectory.R, gyro_mod.frame_rotations(track, sync, vision.trajectory.times), vision.confidence[1:]
        )

    # The chosen source's trajectory.
    if chosen == "vision":
        bridge = None
        if track is not None and sync is not None and np.any(vision.confidence < CONF_MEASURED):
            bridge = gyro_mod.frame_rotations(track, sync, vision.trajectory.times)
            vision = solve_motion(
                pairs, camera.intrinsics, bridge=bridge, calibrate=vopts.calibrate, detail_hz=vopts.detail_hz
            )
        traj, conf = vision.trajectory, vision.confidence
    elif chosen == "fused":
        times = vision.trajectory.times
        Rg = gyro_mod.frame_rotations(track, sync, times)
        gyro_edges = [
            Edge(k, k + 1, Rg[k].T @ Rg[k + 1], _GYRO_STEP_SIGMA_DEG, group="gyro") for k in range(len(times) - 1)
        ]
        fused = solve_motion(pairs, camera.intrinsics, extra_edges=gyro_edges, calibrate=vopts.calibrate)
        traj = fused.trajectory
        conf = np.maximum(fused.confidence, _coverage(track, sync, times))
    else:  # gyro or camera-orientation
        times = vision.trajectory.times if full_vision else frame_times(video)
        Rg = gyro_mod.frame_rotations(track, sync, times)
        traj = Trajectory(times, Rg)
        conf = _coverage(track, sync, times)
    seconds["total"] = time.perf_counter() - t_start
    return CameraMotion(
        trajectory=traj,
        confidence=conf,
        source=chosen,
        requested=source,
        reason=reason,
        camera=camera,
        telemetry=telemetry,
        sync=sync,
        focal_fit=fit,
        comparison=comparison,
        vision=vision if full_vision else None,
        seconds=seconds,
    )


def _sync(track: gyro_mod.GyroTrack, vision: MotionEstimate, orientation: bool) -> gyro_mod.GyroSync:
    """Sync ``track`` to the vision estimate, on the frame steps vision measured."""
    times = vision.trajectory.times
    weights = (vision.confidence[1:] >= CONF_MEASURED).astype(float)
    rates = gyro_mod.frame_rates(times, vision.trajectory.R)
    return gyro_mod.sync_gyro(track, times, rates, weights, estimate_bias=not orientation)


def _coverage(track: gyro_mod.GyroTrack, sync: gyro_mod.GyroSync, times: np.ndarray) -> np.ndarray:
    """1 where the gyro recorded the frame's time, 0 where it is extrapolated."""
    t = np.asarray(times) + sync.offset_s
    return ((t >= track.times[0]) & (t <= track.times[-1])).astype(float)


def _stage(progress: Progress | None) -> Callable[[str], Callable[[int, int], None] | None]:
    def make(stage: str):
        if progress is None:
            return None
        return lambda done, total: progress(stage, done, total)

    return make
