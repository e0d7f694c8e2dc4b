"""Why a stabilised clip still shakes by shake.py's measure: a decomposition of its visible shake.

For each real clip (``../shared/data/real``, or ``--clip``), from one ``--source auto`` motion:
egovid's default output (``stabilize_video``, as ``fpv stabilize`` runs it), an identity render
(the same pipeline with ``strength=0`` and no visible layer: the recorded view re-rendered and
re-encoded) and vid.stab (defaults). Every video is decoded as ``shake.py`` decodes it (OpenCV, grey)
and measured by ``shake.py``'s formula: the frame-to-frame phase-correlation shift at 480 px
width, accumulated, minus its centred 15-frame moving average (edge-padded), RMS per axis, divided
by the output's median zoom. Reported per video:

* ``shake``: x, y and x + y; ``ends_share``: the share of the mean square in the first and last 7
  frames (where the edge padding counts a pan still under way, about 1.9 x its speed);
* for the input and egovid's output, the shake of the image shift the rendered *rotations*
  predict (the centre's shift between consecutive frames through ``K R_k^T R_{k-1}``, times the
  frame's zoom) and of the **model error** (measured minus predicted shift: translation, parallax,
  lens, rolling shutter, sync), over the whole clip and without its first and last 15 frames; and
  the correlation of the measured with the predicted shifts (input);
* egovid's zoom: mean, largest and the share of frames at the ``--max-zoom`` budget;
* ``crop_ceiling``: the lowest shake (x + y) any *image translation path* reaches while staying
  within the crop margin of the input's measured image path at the budget (bounded least squares on
  shake.py's operator): what the budget allows a stabiliser that followed the picture, ignoring
  rotation and the FPMI.

Rotation-predicted = measured says the residual is the rendered path's own motion (the plan, the
path programme); a large model error says a rotation cannot remove it. Not timed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import lsq_linear

from egovid.core.rotations import matrix_from_euler
from egovid.fpv.stabilize.pipeline import stabilize
from egovid.fpv.stabilize.run import stabilize_video
from egovid.fpv.stabilize.vidstab import run_vidstab

from _common import ROOT, cache_dir, report

REAL = ROOT.parent / "shared" / "data" / "real"
CLIPS = ("gopro-hero5-karma.mp4", "gopro-hero6-2s.mp4", "handheld-1080p-pan.mp4")
WIDTH = 480
WINDOW = 15
EDGE = 15


def shifts(video: Path) -> np.ndarray:
    """(K - 1, 2) phase-correlation shifts between consecutive frames at :data:`WIDTH` pixels,
    decoded and reduced exactly as shake.py does."""
    cap = cv2.VideoCapture(str(video))
    prev, win, out = None, None, []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        g = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        s = WIDTH / g.shape[1]
        cur = cv2.resize(g, None, fx=s, fy=s, interpolation=cv2.INTER_AREA).astype(np.float32)
        if win is None:
            win = cv2.createHanningWindow(cur.shape[::-1], cv2.CV_32F)
        if prev is not None:
            out.append(cv2.phaseCorrelate(prev, cur, win)[0])
        prev = cur
    return np.array(out, float)


def shake_operator(n: int, window: int = WINDOW) -> np.ndarray:
    """(n, n) matrix taking a path to its residual: the path minus its centred ``window``-frame
    moving average, the ends padded with the first and last value (shake.py's formula)."""
    h = window // 2
    A = np.eye(n)
    for i in range(n):
        for j in range(i - h, i + h + 1):
            A[i, min(max(j, 0), n - 1)] -= 1.0 / window
    return A


def residual(d: np.ndarray, zoom: float = 1.0) -> np.ndarray:
    """(K - 1, 2) shake residual of the shifts ``d`` (shake.py: the path starts at the first shift)."""
    p = np.cumsum(np.asarray(d, float) / zoom, axis=0)
    return shake_operator(len(p)) @ p


def rms(r: np.ndarray) -> list[float]:
    """RMS per axis, rounded."""
    return [round(float(x), 3) for x in np.sqrt(np.mean(r**2, axis=0))]


def predicted_shifts(angles: np.ndarray, focal_px: float, zoom: np.ndarray) -> np.ndarray:
    """(K - 1, 2) shift of the picture's centre between consecutive frames that the orientations
    ``angles`` (K, 3) degrees predict, in pixels of a copy whose focal length is ``focal_px``, times
    each frame's ``zoom`` (K,)."""
    R = matrix_from_euler(angles[:, 0], angles[:, 1], angles[:, 2])
    v = (np.swapaxes(R[1:], 1, 2) @ R[:-1])[:, :, 2]
    return np.stack([v[:, 0] / v[:, 2], v[:, 1] / v[:, 2]], axis=1) * focal_px * np.asarray(zoom)[1:, None]


def crop_ceiling(d: np.ndarray, size: tuple[float, float], max_zoom: float) -> list[float]:
    """Lowest shake residual RMS per axis of a path within the crop margin of ``max_zoom`` around
    the image path of the shifts ``d`` ((K - 1, 2), pixels of a ``size`` (w, h) copy)."""
    out = []
    for ax in (0, 1):
        o = np.cumsum(d[:, ax])
        m = size[ax] / 2 * (1 - 1 / max_zoom)
        A = shake_operator(len(o))
        x = lsq_linear(A, np.zeros(len(o)), bounds=(o - m, o + m), max_iter=5000).x
        out.append(round(float(np.sqrt(np.mean((A @ x) ** 2))), 3))
    return out


def figures(d: np.ndarray, zoom: float) -> dict:
    """Shake per axis, x + y and the share of the mean square in the first and last 7 frames."""
    r = residual(d, zoom)
    ms = np.sum(r**2, axis=1)
    h = WINDOW // 2
    s = rms(r)
    ends = float(ms[:h].sum() + ms[-h:].sum()) / max(float(ms.sum()), 1e-12)
    return {"shake": s, "shake_sum": round(sum(s), 3), "ends_share": round(ends, 3)}


def decomposition(measured: np.ndarray, predicted: np.ndarray, zoom: float) -> dict:
    """Shake of the rotation-predicted shifts and of the model error (measured - predicted), whole
    clip and without its first and last :data:`EDGE` frames."""
    out = {}
    for name, d in (("measured", measured), ("rotation_predicted", predicted), ("model_error", measured - predicted)):
        r = residual(d, zoom)
        out[name] = {"whole": rms(r), "middle": rms(r[EDGE:-EDGE])}
    return out


def diagnose(clip: Path, folder: Path, max_zoom: float) -> dict:
    """The decomposition of the module docstring for one clip."""
    stem = clip.stem
    res = stabilize_video(clip, folder / f"{stem}.egovid.mp4", source="auto", max_zoom=max_zoom, measure=False)
    cm = res.camera_motion
    intr, lens = cm.camera.intrinsics, cm.camera.lens
    stabilize(
        clip, folder / f"{stem}.identity.mp4", intrinsics=intr, motion=cm.trajectory, lens=lens,
        strength=0.0, visible=False, measure=False, max_zoom=max_zoom,
    )  # fmt: skip
    vs = run_vidstab(clip, folder / f"{stem}.vidstab.mp4", folder, defaults=True)
    zoom = 1.0 / res.keep
    z_med = float(np.median(zoom))
    d_in = shifts(clip)
    d_out = shifts(folder / f"{stem}.egovid.mp4")
    f = intr.focal * WIDTH / intr.width
    p_in = predicted_shifts(res.original, f, np.ones(len(zoom)))
    p_out = predicted_shifts(res.path, f, zoom)
    return {
        "motion_source": cm.source,
        "focal_px": round(intr.focal, 1),
        "lens": lens.kind,
        "input": {
            **figures(d_in, 1.0),
            "rotation_vs_measured_r": [round(float(np.corrcoef(d_in[:, a], p_in[:, a])[0, 1]), 3) for a in (0, 1)],
            **decomposition(d_in, p_in, 1.0),
        },
        "identity": figures(shifts(folder / f"{stem}.identity.mp4"), 1.0),
        "egovid": {
            **figures(d_out, z_med),
            **decomposition(d_out, p_out, z_med),
            "zoom_mean": round(float(zoom.mean()), 3),
            "zoom_max": round(float(zoom.max()), 3),
            "at_budget_share": round(float(np.mean(zoom >= max_zoom - 1e-3)), 3),
            "visible_cutoff_hz": res.visible.cutoff_hz if res.visible else None,
        },
        "vidstab": {**figures(shifts(folder / f"{stem}.vidstab.mp4"), vs.zoom), "zoom": round(vs.zoom, 3)},
        "crop_ceiling": crop_ceiling(d_in, (WIDTH, WIDTH * intr.height / intr.width), max_zoom),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clip", action="append", help="only these clips (file names in ../shared/data/real)")
    ap.add_argument("--max-zoom", type=float, default=1.10, help="egovid's and the ceiling's zoom budget")
    args = ap.parse_args()
    folder = cache_dir("stabilize_diagnose")
    for name in args.clip or CLIPS:
        if (REAL / name).exists():
            report(f"stabilize_diagnose/{Path(name).stem}", diagnose(REAL / name, folder, args.max_zoom))
        else:
            print(f"skipped {name}: not in {REAL}")


if __name__ == "__main__":
    main()
