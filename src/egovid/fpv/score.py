"""How watchable a first-person video is: ``egovid fpv score`` as one function.

:func:`score_video` scores a video (its camera motion from :func:`egovid.core.motion.source.camera_motion`
for VE and SVE, its optical flow for 2D-VE) or a motion CSV (VE and SVE only), with the viewing
model of the thesis (ch. 7-8) or the parameters given, and writes the JSON, the plot and the
motion CSV asked for. The CLI, the demo, the benchmarks and the tests call it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from egovid.core.camera.intrinsics import Intrinsics, resolve_intrinsics
from egovid.core.camera.resolve import resolve_camera
from egovid.core.errors import EgovidError
from egovid.core.files import atomic_write_text
from egovid.core.motion.source import CameraMotion, camera_motion
from egovid.core.plots import plot_scores
from egovid.core.trajectory import Trajectory, read_motion_csv, write_motion_csv
from egovid.core.video import probe
from egovid.fpv.perception.model import ViewingModel
from egovid.fpv.perception.score import MotionScore, score_angles
from egovid.fpv.perception.ve2d import VE2DResult, ve2d_video

#: The scoring methods, in the order they run and are reported.
METHODS = ("ve", "sve", "ve2d")
#: The size assumed for a motion CSV whose video is not given, pixels.
DEFAULT_SIZE = (1920, 1080)


@dataclass
class ScoreReport:
    """The scores of one video or motion CSV.

    ``results`` maps each method (``ve``, ``sve``, ``ve2d``) to its score (per-window curves and
    overall); ``intrinsics`` are those the scores used, with ``intrinsics_source`` saying where they
    came from; ``motion`` is the camera motion estimated from the video (None for a motion CSV or
    2D-VE alone)."""

    input: Path
    results: dict[str, MotionScore | VE2DResult]
    intrinsics: Intrinsics
    intrinsics_source: str
    motion: CameraMotion | None = None

    def to_dict(self) -> dict:
        """JSON-ready: the input, the intrinsics and every method's result with its curves."""
        intr = self.intrinsics
        return {
            "input": str(self.input),
            "intrinsics": {
                "width": intr.width,
                "height": intr.height,
                "focal_px": intr.focal,
                "hfov_deg": intr.hfov_deg,
                "vfov_deg": intr.vfov_deg,
                "source": self.intrinsics_source,
            },
            "results": {m: r.to_dict() for m, r in self.results.items()},
        }


def check_request(video: object, motion: object, method: str) -> None:
    """Refuse an unknown ``method`` (``ve``, ``sve``, ``ve2d`` or ``all``) and a request that gives
    both or neither of a video and a motion CSV (before any work)."""
    for m in METHODS if method == "all" else (method,):
        if m not in METHODS:
            raise EgovidError(f"unknown method {m!r}", "choose ve, sve, ve2d or all")
    if (video is None) == (motion is None):
        raise EgovidError("give either a VIDEO or --motion CSV", "e.g. `egovid fpv score clip.mp4`")


def _methods(method: str, from_motion: bool) -> tuple[str, ...]:
    """The methods ``method`` names (``all``: every method the input allows); 2D-VE needs the
    pictures, so a motion CSV cannot have it."""
    methods = METHODS if method == "all" else (method,)
    if from_motion and "ve2d" in methods:
        if method != "all":
            raise EgovidError("2D-VE needs the video, not a motion CSV", "pass the VIDEO instead of --motion")
        methods = ("ve", "sve")
    return methods


def score_video(
    video: str | os.PathLike | None = None,
    *,
    motion: str | os.PathLike | None = None,
    method: str = "all",
    focal: float | None = None,
    hfov: float | None = None,
    size: tuple[int, int] | None = None,
    fps: float | None = None,
    d_over_f: float = 4.0,
    bias: float | None = None,
    mar: float = 0.02,
    sve_variant: str = "coverage",
    source: str = "auto",
    json_out: str | os.PathLike | None = None,
    plot: str | os.PathLike | None = None,
    save_motion: str | os.PathLike | None = None,
    estimated: CameraMotion | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> ScoreReport:
    """Score ``video`` (or the motion CSV ``motion``: frame,time,yaw,pitch,roll) with ``method``
    (``ve``, ``sve``, ``ve2d`` or ``all``).

    ``focal`` (pixels) / ``hfov`` (degrees) override the intrinsics; ``size`` (pixels) and ``fps``
    describe the video a motion CSV came from (default 1920x1080 and the rate of its time column);
    ``d_over_f``, ``bias`` (degrees; default the thesis' b of each model) and ``mar`` (degrees) set
    the viewing model; ``source`` is where the camera motion of a video comes from. Writes the
    JSON (``json_out``), the plot of the per-window curves (``plot``) and the estimated motion
    (``save_motion``) when given. ``estimated`` is the camera motion of ``video`` where the caller
    has it already (it is not estimated again). ``progress(stage, done, total)`` reports the stages.
    """
    check_request(video, motion, method)
    methods = _methods(method, motion is not None)
    if video is not None:
        camera = resolve_camera(video, focal, hfov)
        report = ScoreReport(Path(video), {}, camera.intrinsics, camera.source)
        traj, rate = None, probe(video).fps
    else:
        report, traj, rate = _csv_motion(motion, focal, hfov, size, fps)
    model3d = ViewingModel(d_over_f=d_over_f, mar_deg=mar, **({} if bias is None else {"bias_deg": bias}))
    model2d = ViewingModel.model_2d().with_(
        d_over_f=d_over_f, mar_deg=mar, **({} if bias is None else {"bias_deg": bias})
    )
    if traj is None and any(m in ("ve", "sve") for m in methods):
        cm = estimated or camera_motion(video, source, focal=focal, hfov=hfov, progress=progress)
        traj, report.motion = cm.trajectory, cm
        report.intrinsics, report.intrinsics_source = cm.camera.intrinsics, cm.camera.source
        if save_motion is not None:
            write_motion_csv(save_motion, traj, cm.confidence)
    intr = report.intrinsics
    for m in methods:
        if m == "ve2d":
            cb = (lambda d, t: progress("2D-VE", d, t)) if progress else None
            report.results[m] = ve2d_video(video, intr, model2d, progress=cb)
        else:
            report.results[m] = score_angles(
                traj.euler(), rate, intr.hfov_deg, intr.vfov_deg, model=model3d, method=m, sve_variant=sve_variant
            )
    if json_out is not None:
        atomic_write_text(json_out, json.dumps(report.to_dict(), indent=1))
    if plot is not None:
        plot_scores(plot, report.results, f"Viewing experience of {report.input.name}")
    return report


def _csv_motion(
    motion: str | os.PathLike,
    focal: float | None,
    hfov: float | None,
    size: tuple[int, int] | None,
    fps: float | None,
) -> tuple[ScoreReport, Trajectory, float]:
    """A motion CSV's trajectory, the intrinsics of its video (``size``, ``focal``/``hfov``) and
    its frame rate (``fps``, else from its time column)."""
    w, h = size or DEFAULT_SIZE
    intr = resolve_intrinsics(w, h, focal, hfov)
    traj = read_motion_csv(motion)
    if fps is None:
        dt = np.diff(traj.times)
        if len(dt) == 0 or not np.all(dt > 0):
            raise EgovidError(f"{motion} has no increasing time column", "pass --fps")
        fps = float(1.0 / np.median(dt))
    source = "flag" if focal or hfov else "default"
    return ScoreReport(Path(motion), {}, intr, source), traj, fps
