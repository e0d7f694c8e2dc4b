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
  image orientation is used when recorded, vision otherwise. Where the file does not say so, it
  is measured once the gyro is synced: a picture that keeps under half of the gyro's 2-8 Hz shake
  was stabilised in the camera (:mod:`egovid.core.motion.eis`). The reason is reported.

Each source is a :class:`MotionSource` in the registry :data:`SOURCES` (what it needs, what vision
measures for it, how its trajectory is solved); :func:`choose_source` resolves a request.
With a gyro and no ``--focal/--hfov``, a GoPro file that names no lens gets the calibrated lens
the gyro confirms (:func:`_choose_lens`); otherwise the focal length is fitted from the gyro
against the matched points (:func:`egovid.core.motion.gyro.fit_focal`), and vision is re-fitted
with it.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from egovid.core.camera.lens_profiles import MAX_SPREAD
from egovid.core.camera.resolve import CameraModel, lens_candidates, resolve_camera
from egovid.core.camera.telemetry import CAMM_FORMAT_NAME, CameraTelemetry, read_camera_telemetry
from egovid.core.errors import EgovidError
from egovid.core.motion import eis
from egovid.core.motion import gyro as gyro_mod
from egovid.core.motion.estimate import (
    CONF_MEASURED,
    MotionEstimate,
    MotionOptions,
    PairSet,
    collect_pairs,
    refit,
    solve_motion,
)
from egovid.core.motion.posegraph import Edge
from egovid.core.motion.rolling_shutter import frame_rates, refit_pairs
from egovid.core.trajectory import Trajectory
from egovid.core.video import frame_times, probe

#: Intrinsics sources a gyro fit refines (the user's flags, the file's own facts and a calibrated
#: lens profile come before it; see :mod:`egovid.core.camera.resolve`).
FITTED_SOURCES = ("lens-mode", "default")
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
    ran; ``vision``: the vision estimate where it ran on the whole video; ``picture_share``: how
    much of the body gyro's shake the picture keeps (:mod:`egovid.core.motion.eis`) where a body
    gyro was synced; ``body_sync``: that gyro's sync where it was then set aside (the picture was
    judged stabilised in the camera).
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
    picture_share: eis.PictureShare | None = None
    body_sync: gyro_mod.GyroSync | None = None

    def source_dict(self) -> dict:
        """The motion source, deterministic (no timings): what was used, what was asked, why,
        the sensor's sync and the share of the body gyro's shake the picture keeps."""
        doc: dict = {"source": self.source, "requested": self.requested, "reason": self.reason}
        if self.sync is not None:
            doc["gyro_sync"] = self.sync.to_dict()
        if self.picture_share is not None:
            doc["picture_vs_body_gyro"] = self.picture_share.to_dict()
            if self.body_sync is not None:
                doc["picture_vs_body_gyro"]["gyro_sync"] = self.body_sync.to_dict()
        return doc

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
                "gyro_from": tel.imu_source,
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
        if "picture_vs_body_gyro" in (src := self.source_dict()):
            doc["picture_vs_body_gyro"] = src["picture_vs_body_gyro"]
        if self.vision is not None:
            doc["vision"] = {
                "failed_pairs": self.vision.failed_pairs,
                "pairs": len(self.vision.pairs),
                "noise_scale": {k: round(v, 4) for k, v in self.vision.noise_scale.items()},
            }
        return doc


@dataclass
class _Run:
    """What :func:`camera_motion` has measured so far, handed from one stage to the next."""

    video: str | os.PathLike
    source: MotionSource
    reason: str
    camera: CameraModel
    telemetry: CameraTelemetry
    vopts: MotionOptions
    full_vision: bool  # vision measures the whole video (else the sync window of a long clip)
    keep: int  # frames whose matched points are kept for the focal-length fit
    report: Callable[[str], Callable[[int, int], None] | None]
    track: gyro_mod.GyroTrack | None = None
    gyro_track: gyro_mod.GyroTrack | None = None  # the track before any bias was taken off
    pairs: PairSet | None = None
    vision: MotionEstimate | None = None
    sync: gyro_mod.GyroSync | None = None
    fit: gyro_mod.FocalFit | None = None
    comparison: gyro_mod.RateComparison | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    requested: str = "auto"
    picture: eis.PictureShare | None = None
    body_sync: gyro_mod.GyroSync | None = None


@dataclass(frozen=True)
class MotionSource:
    """One place camera motion can come from (see the module docstring).

    ``needs_gyro``: refused for a file without a gyro; ``whole_vision``: vision is measured on the
    whole video, as (part of) the answer (else only on the sync window of a long clip);
    ``orientation``: the sensor track is the camera's recorded image orientation, synced without a
    gyro bias; ``requestable``: ``--source`` may name it (``camera-orientation`` only comes from
    ``auto``); ``asked(telemetry)`` the reason when asked for by name; ``solve(run)`` the
    trajectory and per-frame confidence from the measurements.
    """

    name: str
    needs_gyro: bool
    whole_vision: bool
    orientation: bool
    requestable: bool
    asked: Callable[[CameraTelemetry], str]
    solve: Callable[[_Run], tuple[Trajectory, np.ndarray]]

    @property
    def sensor(self) -> bool:
        """Whether the camera's sensor (gyro or recorded orientation) is part of the answer."""
        return self.needs_gyro or self.orientation


def _camera_name(telemetry: CameraTelemetry) -> str:
    make = None if telemetry.make == CAMM_FORMAT_NAME else telemetry.make
    return " ".join(x for x in (make, telemetry.model) if x) or "the camera"


def _eis_note(telemetry: CameraTelemetry) -> str:
    """What to add to a reason when the camera stabilised the picture itself (else nothing)."""
    if not telemetry.electronically_stabilized:
        return ""
    return (
        f"; note: {_camera_name(telemetry)} stabilised the picture itself ({telemetry.stabilization}), "
        "so its body gyro does not describe the picture"
    )


def _solve_vision(run: _Run) -> tuple[Trajectory, np.ndarray]:
    """Vision, its unmeasured steps bridged by the synced gyro where there is one."""
    vision = run.vision
    if run.track is not None and run.sync is not None and np.any(vision.confidence < CONF_MEASURED):
        bridge = gyro_mod.frame_rotations(run.track, run.sync, vision.trajectory.times)
        run.vision = vision = solve_motion(
            run.pairs,
            run.camera.intrinsics,
            bridge=bridge,
            calibrate=run.vopts.calibrate,
            detail_hz=run.vopts.detail_hz,
        )
    return vision.trajectory, vision.confidence


def _solve_fused(run: _Run) -> tuple[Trajectory, np.ndarray]:
    """Gyro steps and vision pairs in one pose graph."""
    times = run.vision.trajectory.times
    Rg = gyro_mod.frame_rotations(run.track, run.sync, times)
    gyro_edges = [
        Edge(k, k + 1, Rg[k].T @ Rg[k + 1], _GYRO_STEP_SIGMA_DEG, group="gyro") for k in range(len(times) - 1)
    ]
    fused = solve_motion(run.pairs, run.camera.intrinsics, extra_edges=gyro_edges, calibrate=run.vopts.calibrate)
    return fused.trajectory, np.maximum(fused.confidence, _coverage(run.track, run.sync, times))


def _solve_sensor(run: _Run) -> tuple[Trajectory, np.ndarray]:
    """The synced sensor track at every frame's time."""
    times = run.vision.trajectory.times if run.full_vision else frame_times(run.video)
    Rg = gyro_mod.frame_rotations(run.track, run.sync, times)
    return Trajectory(times, Rg), _coverage(run.track, run.sync, times)


def _gyro_words(telemetry: CameraTelemetry) -> str:
    """``"400 Hz"``, or ``"200 Hz, in its CAMM track (camm handler)"`` where the gyro is not the
    one telemetry-parser reads."""
    src = telemetry.imu_source or ""
    return f"{telemetry.imu.rate_hz:.0f} Hz" + (f", in its {src}" if src.startswith("CAMM") else "")


def _asked_gyro(telemetry: CameraTelemetry) -> str:
    return f"asked for ({_camera_name(telemetry)} gyro, {_gyro_words(telemetry)})" + _eis_note(telemetry)


#: The motion sources by name, in the order ``--source`` lists them.
SOURCES: dict[str, MotionSource] = {
    s.name: s
    for s in (
        MotionSource("vision", False, True, False, True, lambda tel: "asked for", _solve_vision),
        MotionSource("gyro", True, False, False, True, _asked_gyro, _solve_sensor),
        MotionSource("fused", True, True, False, True, lambda tel: "asked for" + _eis_note(tel), _solve_fused),
        MotionSource("camera-orientation", False, False, True, False, lambda tel: "", _solve_sensor),
    )
}
#: What ``--source`` accepts: ``auto`` (see :func:`choose_source`) and the sources asked for by name.
REQUESTS = ("auto", *(name for name, s in SOURCES.items() if s.requestable))


def choose_source(requested: str, telemetry: CameraTelemetry) -> tuple[str, str]:
    """The source to use for ``requested`` given what the file carries, and why (in words).

    Raises :class:`EgovidError` when ``gyro`` or ``fused`` is asked of a file without a gyro.
    """
    if requested not in REQUESTS:
        raise EgovidError(f"unknown motion source {requested!r}", f"choose one of {', '.join(REQUESTS)}")
    if requested == "auto":
        return _auto_source(telemetry)
    source = SOURCES[requested]
    if source.needs_gyro and not telemetry.has_gyro:
        raise EgovidError(
            f"--source {requested} needs a gyro, and this file records none", "use --source vision (or auto)"
        )
    return requested, source.asked(telemetry)


def _auto_source(telemetry: CameraTelemetry) -> tuple[str, str]:
    """``auto``: the gyro, unless there is none or the camera stabilised the picture itself."""
    name = _camera_name(telemetry)
    if not telemetry.has_gyro:
        return "vision", "the file records no gyro"
    if telemetry.electronically_stabilized:
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
    said = (
        "did not stabilise the picture"
        if telemetry.electronically_stabilized is False
        else "does not say it stabilised the picture"
    )
    return "gyro", f"{name} records a gyro ({_gyro_words(telemetry)}) and {said}"


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
    run = _start(video, source, focal, hfov, options or MotionOptions(), progress)
    run.pairs = collect_pairs(video, run.camera.intrinsics, run.vopts, run.report("motion"))
    run.seconds["vision_pairs"] = run.pairs.seconds
    run.vision = solve_motion(
        run.pairs, run.camera.intrinsics, calibrate=run.vopts.calibrate, detail_hz=run.vopts.detail_hz
    )
    if run.track is not None:
        _sync_sensor(run)
    if run.track is not None and not run.source.orientation:
        _check_picture(run)
    if run.track is not None and not run.source.orientation and run.pairs.matches and len(run.pairs.times) <= run.keep:
        _choose_lens(run)
    if run.track is not None and run.camera.source in FITTED_SOURCES and run.pairs.matches:
        _fit_focal(run)
    if run.camera.readout_ms and run.pairs is not None and run.pairs.matches and len(run.pairs.times) <= run.keep:
        _correct_rolling_shutter(run)
    if run.track is not None and run.pairs is not None:
        run.comparison = gyro_mod.compare_rotations(
            run.vision.trajectory.R,
            gyro_mod.frame_rotations(run.track, run.sync, run.vision.trajectory.times),
            run.vision.confidence[1:],
        )
    traj, conf = run.source.solve(run)
    run.seconds["total"] = time.perf_counter() - t_start
    return CameraMotion(
        trajectory=traj,
        confidence=conf,
        source=run.source.name,
        requested=source,
        reason=run.reason,
        camera=run.camera,
        telemetry=run.telemetry,
        sync=run.sync,
        focal_fit=run.fit,
        comparison=run.comparison,
        vision=run.vision if run.full_vision else None,
        seconds=run.seconds,
        picture_share=run.picture,
        body_sync=run.body_sync,
    )


def _start(
    video: str | os.PathLike,
    requested: str,
    focal: float | None,
    hfov: float | None,
    opts: MotionOptions,
    progress: Progress | None,
) -> _Run:
    """Read what the file says (size, telemetry, intrinsics), choose the source, and plan the
    vision pass and the sensor track."""
    info = probe(video)
    try:
        telemetry = read_camera_telemetry(video)
    except EgovidError:
        telemetry = CameraTelemetry()
    chosen, reason = choose_source(requested, telemetry)
    source = SOURCES[chosen]
    camera = resolve_camera(video, focal, hfov, telemetry=telemetry)
    # The body gyro helps vision too (focal-length fit, bridging gaps), unless the camera
    # stabilised the picture itself: then it does not describe the picture.
    uses_gyro = telemetry.has_gyro and (source.needs_gyro or not telemetry.electronically_stabilized)
    if source.orientation:
        track = gyro_mod.orientation_track(telemetry.image_orientation)
    elif uses_gyro:
        track = gyro_mod.integrate(telemetry.imu)
    else:
        track = None
    # Vision: on the whole video, except for a sensor-only source on a long clip (sync window).
    full_vision = source.whole_vision or info.duration <= SYNC_SECONDS * 1.5 or info.duration <= 0
    window = None if full_vision else max(2, int(SYNC_SECONDS * info.fps))
    # Matched points are kept for the focal-length fit, over at most 1.5 x the sync window (so a
    # short clip is re-fitted without decoding it again; a long one is decoded twice).
    fixed = camera.source not in FITTED_SOURCES  # the user's, the file's or a calibration: not refitted
    wanted = (track is not None and not fixed) or bool(camera.readout_ms)  # focal fit, rolling shutter
    keep = int(SYNC_SECONDS * 1.5 * max(info.fps, 1.0)) + max(opts.lags) if wanted else 0
    vopts = MotionOptions(**{**opts.__dict__, "keep_matches": keep, "max_frames": window})
    return _Run(
        video, source, reason, camera, telemetry, vopts, full_vision, keep, _stage(progress), track, track,
        requested=requested,
    )  # fmt: skip


def _sync_sensor(run: _Run) -> None:
    """Sync the sensor track to vision; an untrusted sync drops the sensor (vision is used)."""
    t0 = time.perf_counter()
    run.sync = _sync(run.track, run.vision, run.source.orientation)
    if not run.sync.trusted:
        if run.source.sensor:
            run.reason += f"; but the gyro does not match the picture (r = {run.sync.r_vector:.2f}), so vision is used"
            run.source = SOURCES["vision"]
        run.track = run.sync = None
    elif not run.source.orientation:
        run.track = gyro_mod.integrate(run.telemetry.imu, bias=run.sync.bias)
    run.seconds["sync"] = time.perf_counter() - t0


def _check_picture(run: _Run) -> None:
    """Measure how much of the synced body gyro's shake the picture keeps (before the focal-length
    fit, which would absorb part of a missing shake into the focal length). For ``auto`` on a file
    that does not say the camera stabilised the picture, a picture judged stabilised in the camera
    sets the body gyro aside: the camera's recorded image orientation is used where there is one,
    else vision on the whole video; vision asked for by name no longer uses that gyro (bridges,
    focal-length fit). Otherwise the verdict is added to the reason."""
    times = run.vision.trajectory.times
    vision_rates = gyro_mod.frame_rates(times, run.vision.trajectory.R)
    gyro_rates = gyro_mod.frame_rates(times, gyro_mod.frame_rotations(run.track, run.sync, times))
    fps = 1.0 / float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    run.picture = pic = eis.picture_share(vision_rates, gyro_rates, fps, run.vision.confidence[1:] >= CONF_MEASURED)
    if not pic.stabilised:
        if run.source.needs_gyro:
            run.reason += f"; {pic.describe()}: " + (
                "not stabilised in the camera"
                if pic.verdict == eis.KEPT
                else "cannot tell whether the camera stabilised it"
            )
        return
    if not run.source.needs_gyro:  # vision asked for: the body gyro neither bridges nor fits its focal length
        run.body_sync, run.track, run.gyro_track, run.sync = run.sync, None, None, None
        run.reason += f"; {pic.describe()}: the camera stabilised the picture itself, so its body gyro is not used"
        return
    if run.requested != "auto":
        run.reason += (
            f"; note: {pic.describe()}: the camera seems to have stabilised it (--source auto would not use the gyro)"
        )
        return
    note = f"; but {pic.describe()}: the camera stabilised the picture itself, so its body gyro does not describe it"
    run.body_sync = run.sync
    tel = run.telemetry
    if tel.image_orientation is not None:
        track = gyro_mod.orientation_track(tel.image_orientation)
        sync = _sync(track, run.vision, True)
        if sync.trusted:
            run.source, run.track, run.gyro_track, run.sync = SOURCES["camera-orientation"], track, track, sync
            run.reason += note + "; its recorded image orientation is used"
            return
        note += f" and its recorded image orientation does not match the picture (r = {sync.r_vector:.2f})"
    run.source, run.track, run.gyro_track, run.sync = SOURCES["vision"], None, None, None
    run.reason += note + "; vision is used"
    if not run.full_vision:  # vision measured only the sync window: measure the whole video
        run.full_vision = True
        run.vopts = replace(run.vopts, max_frames=None)
        run.pairs = collect_pairs(run.video, run.camera.intrinsics, run.vopts, run.report("motion (whole video)"))
        run.vision = solve_motion(
            run.pairs, run.camera.intrinsics, calibrate=run.vopts.calibrate, detail_hz=run.vopts.detail_hz
        )


def _choose_lens(run: _Run) -> None:
    """A camera whose file names no lens (a re-muxed GoPro file) but whose lenses have calibrated
    profiles (:func:`~egovid.core.camera.resolve.lens_candidates`): vision re-fitted through each
    lens's profile, distortion included, and the lens whose rotations the synced gyro confirms
    (the focal-length fit's scale nearest 1, within :data:`MAX_SPREAD`) is used, with its
    distortion; where none fits, the gyro fit refines the assumed lens mode as before.

    A focal length fitted through the assumed lens's model (equidistant) is not the profile's
    (its k1..k4 bend the rays differently), so comparing the two numbers picked no lens for the
    HERO6 walk once vision kept its near points' parallax (436 px fitted, Wide's profile 387.6);
    each lens judged through its own model does not depend on that."""
    kept = run.picture is not None and run.picture.verdict == eis.KEPT  # measured: not stabilised in the camera
    candidates = lens_candidates(run.video, run.camera, run.telemetry, stabilized=False if kept else None)
    if not candidates:
        return
    R_gyro = gyro_mod.frame_rotations(run.track, run.sync, run.vision.trajectory.times)
    judged = []
    for cam in candidates:
        pairs = refit_pairs(
            replace(run.pairs, work=cam.intrinsics.scaled(run.pairs.work.width / cam.intrinsics.width)), None, 0.0,
            distortion=cam.intrinsics.distortion,
        )  # fmt: skip
        fit = gyro_mod.fit_focal([(i, j, p.Q) for i, j, p in pairs.pairs if p.ok], R_gyro, cam.intrinsics.focal)
        if fit.well_posed:
            judged.append((abs(np.log(fit.scale)), fit, cam, pairs))
    if not judged:
        return
    off, fit, cam, pairs = min(judged, key=lambda x: x[0])
    if off > np.log1p(MAX_SPREAD):
        return
    others = ", ".join(f"{c.intrinsics.focal:.1f} px: {f.scale:.3f}" for _, f, c, _ in judged if c is not cam)
    run.camera = replace(
        cam,
        detail=f"{cam.detail}; the file names no lens: the profile the gyro confirms (vision/gyro "
        f"{fit.scale:.3f} on {fit.pairs} frame pairs" + (f"; other lenses {others}" if others else "") + ")",
    )
    run.pairs = pairs
    _resolve_and_resync(run, run.camera)


def _resolve_and_resync(run: _Run, camera: CameraModel) -> None:
    """Vision solved again from ``run.pairs`` through ``camera``, the sensor synced to it again
    and, for a gyro, integrated again with the new sync's bias."""
    run.vision = solve_motion(
        run.pairs, camera.intrinsics, calibrate=run.vopts.calibrate, detail_hz=run.vopts.detail_hz
    )
    run.sync = _sync(run.gyro_track, run.vision, run.source.orientation)
    if not run.source.orientation:
        run.track = gyro_mod.integrate(run.telemetry.imu, bias=run.sync.bias)


def _fit_focal(run: _Run) -> None:
    """Fit the focal length from the gyro against vision's matched points, re-fit vision with it
    and sync again (at most twice); the fit confirms the file's focal length when it holds."""
    before = camera = run.camera
    for attempt in range(2):  # vision angles are nearly, not exactly, proportional to 1/focal
        step = gyro_mod.fit_focal(
            [(i, j, p.Q) for i, j, p in run.pairs.pairs if p.ok],
            gyro_mod.frame_rotations(run.track, run.sync, run.vision.trajectory.times),
            camera.intrinsics.focal,
        )
        if attempt == 0:
            run.fit = step
        if not step.well_posed or abs(step.scale - 1.0) <= _REFIT_TOLERANCE:
            break
        previous = camera
        camera = before.with_focal(
            step.focal_px,
            "gyro-fit",
            f"fitted from the gyro on {step.pairs} frame pairs (the {before.source} gave "
            f"{before.intrinsics.focal:.1f} px: {before.detail})",
        )
        if len(run.pairs.times) <= run.keep:  # every pair's matches are kept: re-fit them (cheap)
            run.pairs = refit(run.pairs, previous.intrinsics, step.focal_px)
        elif run.source.whole_vision and attempt == 0:  # a long clip: measure it again
            run.pairs = collect_pairs(run.video, camera.intrinsics, run.vopts, run.report("motion (refit)"))
        else:
            run.pairs = None
            break
        _resolve_and_resync(run, camera)
    if run.fit is not None and run.fit.well_posed:
        run.fit = replace(run.fit, focal_px=camera.intrinsics.focal)
        if camera is before:
            camera = camera.with_focal(
                camera.intrinsics.focal, camera.source, camera.detail + "; confirmed by the gyro"
            )
    run.camera = camera


def _correct_rolling_shutter(run: _Run) -> None:
    """Vision re-fitted with every matched point moved to its frame's time stamp for the camera's
    readout (:mod:`egovid.core.motion.rolling_shutter`): with the synced gyro's rates where there is
    one (one pass), else with vision's own rates (two passes: the first corrected estimate gives
    better rates). Only for clips whose matches are all kept (no second decode)."""
    t0 = time.perf_counter()
    readout_s = run.camera.readout_ms / 1000.0
    times = run.vision.trajectory.times
    raw = run.pairs
    use_gyro = run.track is not None and run.sync is not None
    for _ in range(1 if use_gyro else 2):
        R = gyro_mod.frame_rotations(run.track, run.sync, times) if use_gyro else run.vision.trajectory.R
        run.pairs = refit_pairs(raw, frame_rates(R, times), readout_s, distortion=run.camera.intrinsics.distortion)
        run.vision = solve_motion(
            run.pairs, run.camera.intrinsics, calibrate=run.vopts.calibrate, detail_hz=run.vopts.detail_hz
        )
    run.seconds["rolling_shutter"] = time.perf_counter() - t0
    run.reason += (
        f"; rolling shutter ({run.camera.readout_ms:g} ms readout, {run.camera.readout_source}) corrected with "
        + ("the gyro's rates" if use_gyro else "vision's own rates")
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
