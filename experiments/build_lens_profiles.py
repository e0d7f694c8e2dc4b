"""Build egovid's compact lens-profile index (shipped as src/egovid/data/lens_profiles.json.gz).

Input: Gyroflow's CC0 lens-profile database, the tarball ``gyroflow-lens-profiles.tar.xz`` in
``../shared/data/lens_profiles/`` (9,810 JSON calibrations; see its SOURCES.md). Output: one gzip
JSON table with only what egovid looks up and uses, stored column by column (``columns[name][i]``
is profile i's value; strings are indices into ``strings``):

* who: camera brand, camera model, lens model, the setting words (``note`` and
  ``camera_setting``: "HS EIS", "NO-EIS", "Medium", ...);
* at which picture: calibration width and height (pixels), frame rate, the other resolutions
  Gyroflow lists as compatible, the horizontal stretch of anamorphic footage, Gyroflow's
  "digital lens" (SuperView-style non-linear stretch) where one applies;
* the calibration: OpenCV fisheye camera matrix (fx, fy, cx, cy in pixels at the calibration
  size) and distortion k1..k4, its RMS error (pixels) and image count, the "official" flag;
* the rolling-shutter frame readout time in milliseconds (signed: negative reads bottom to top)
  where calibrated.

Every profile of this database uses the OpenCV fisheye model (none sets another
``distortion_model``); a profile that names another model is skipped and counted, so the index
never holds coefficients egovid would misread. Matching rules (model names, lens modes,
stabilisation words) live in :mod:`egovid.core.camera.lens_profiles`, not here: the index keeps
the words as the database has them.

Usage: ``python experiments/build_lens_profiles.py [TARBALL]``; prints the counts and the size.
"""

from __future__ import annotations

import gzip
import json
import math
import sys
import tarfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARBALL = ROOT.parent / "shared" / "data" / "lens_profiles" / "gyroflow-lens-profiles.tar.xz"
OUT = ROOT / "src" / "egovid" / "data" / "lens_profiles.json.gz"
#: The database's commit (from its SOURCES.md), recorded in the index.
SOURCE = "gyroflow/lens_profiles @ 886fc616c9c2c788856f54c21d451b9cb7fc4f44 (CC0 1.0)"
COLUMNS = (
    "brand", "model", "lens", "setting",
    "w", "h", "fps", "fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4",
    "rms", "images", "official", "readout_ms", "stretch", "digital_lens", "compatible",
)  # fmt: skip
STRING_COLUMNS = {"brand", "model", "lens", "setting", "digital_lens"}


def _num(v, digits: int = 6) -> float | None:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    if not math.isfinite(x):
        return None
    return float(f"{x:.{digits}g}")


def _text(v) -> str:
    return " ".join(str(v).split()) if v not in (None, "") else ""


def row_of(doc: dict) -> tuple[list | None, str]:
    """One index row of a profile document, or None and why it is skipped."""
    model = str(doc.get("distortion_model") or "opencv_fisheye")
    if model not in ("opencv_fisheye", "opencv fisheye"):
        return None, f"distortion model {model}"
    fp = doc.get("fisheye_params") or {}
    K = fp.get("camera_matrix") or []
    D = list(fp.get("distortion_coeffs") or [])
    calib = doc.get("calib_dimension") or {}
    w, h = calib.get("w"), calib.get("h")
    try:
        fx, fy, cx, cy = float(K[0][0]), float(K[1][1]), float(K[0][2]), float(K[1][2])
        w, h = int(w), int(h)
    except (TypeError, ValueError, IndexError):
        return None, "no camera matrix or size"
    if not (w > 0 and h > 0 and fx > 0 and fy > 0) or not all(map(math.isfinite, (fx, fy, cx, cy))):
        return None, "no camera matrix or size"
    D = [*D, 0.0, 0.0, 0.0, 0.0][:4]
    if not all(isinstance(d, int | float) and math.isfinite(d) for d in D):
        return None, "bad distortion coefficients"
    setting = " ".join(x for x in (_text(doc.get("note")), _text(doc.get("camera_setting"))) if x)
    compatible = sorted(
        {
            (int(c["width"]), int(c["height"]))
            for c in doc.get("compatible_settings") or []
            if isinstance(c, dict) and c.get("width") and c.get("height")
        }
        - {(w, h)}
    )
    readout = _num(doc.get("frame_readout_time"))
    if readout is not None and str(doc.get("frame_readout_direction") or "").lower().startswith(("bottom", "b")):
        readout = -abs(readout)
    row = {
        "brand": _text(doc.get("camera_brand")),
        "model": _text(doc.get("camera_model")),
        "lens": _text(doc.get("lens_model")),
        "setting": setting,
        "w": w,
        "h": h,
        "fps": _num(doc.get("fps"), 7),
        "fx": _num(fx, 7),
        "fy": _num(fy, 7),
        "cx": _num(cx, 7),
        "cy": _num(cy, 7),
        "k1": _num(D[0]),
        "k2": _num(D[1]),
        "k3": _num(D[2]),
        "k4": _num(D[3]),
        "rms": _num(fp.get("RMS_error"), 3),
        "images": int(doc.get("num_images") or 0),
        "official": 1 if doc.get("official") else 0,
        "readout_ms": readout if readout else None,
        "stretch": _num(doc.get("input_horizontal_stretch")) or 1.0,
        "digital_lens": _text(doc.get("digital_lens")),
        "compatible": [list(c) for c in compatible],
    }
    return [row[c] for c in COLUMNS], ""


def build(tarball: Path) -> dict:
    """The index document from the database tarball (profiles in file-name order)."""
    rows, skipped = [], {}
    with tarfile.open(tarball, mode="r|xz") as tar:  # streamed: an xz tarball cannot seek back
        for m in tar:
            if not (m.isfile() and m.name.endswith(".json")):
                continue
            try:
                doc = json.load(tar.extractfile(m))
            except (ValueError, UnicodeDecodeError):
                skipped["unreadable JSON"] = skipped.get("unreadable JSON", 0) + 1
                continue
            if not isinstance(doc, dict):
                skipped["not a profile"] = skipped.get("not a profile", 0) + 1
                continue
            row, why = row_of(doc)
            if row is None:
                skipped[why] = skipped.get(why, 0) + 1
                continue
            rows.append(row)
    # Independent of the tarball's order; a profile filed twice (same calibration, same words) once.
    unique = {json.dumps(r): r for r in rows}
    skipped["duplicate"] = len(rows) - len(unique)
    rows = sorted(unique.values(), key=lambda r: [str(x) for x in r])
    strings: dict[str, int] = {}
    table = {}  # column by column: similar numbers side by side compress best
    for k, c in enumerate(COLUMNS):
        values = [row[k] for row in rows]
        if c in STRING_COLUMNS:
            values = [strings.setdefault(v, len(strings)) for v in values]
        table[c] = values
    return {
        "source": SOURCE,
        "licence": "CC0 1.0 Universal (Gyroflow lens profiles); index built by experiments/build_lens_profiles.py",
        "model": "opencv_fisheye",
        "count": len(rows),
        "string_columns": sorted(STRING_COLUMNS),
        "strings": list(strings),
        "columns": table,
        "skipped": skipped,
    }


def main() -> None:
    tarball = Path(sys.argv[1]) if len(sys.argv) > 1 else TARBALL
    if not tarball.exists():
        raise SystemExit(f"{tarball} is not here (../shared/data/lens_profiles beside the checkout)")
    doc = build(tarball)
    data = json.dumps(doc, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    OUT.write_bytes(gzip.compress(data, compresslevel=9, mtime=0))
    print(f"{doc['count']} profiles, skipped {doc['skipped']}; {OUT.stat().st_size / 1024:.0f} KiB -> {OUT}")


if __name__ == "__main__":
    main()
