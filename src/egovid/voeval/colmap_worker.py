"""Run pycolmap incremental mapping on a folder of frames (separate process: pycolmap and OpenCV
ship clashing native libraries). Usage: python -m egovid.voeval.colmap_worker IMAGES OUT.json SETTINGS.json

``SETTINGS.json``: ``{"fx", "fy", "cx", "cy"}`` (pixels, a fixed pinhole camera). Writes
``{"rotations": {image_name: cam_from_world 3x3}, "positions": {image_name: camera centre},
"notes": {...}}`` for the largest reconstruction. The notes say what the matching found (images,
verified image pairs, their median inlier count) and which mapping attempts were made, so a cell
that built no model says why (:func:`reason`).

**Short, slow clips.** COLMAP starts a model from an image pair seen under a triangulation angle of
at least 16° (relaxed by COLMAP itself to 8° and 4°); a short clip of a slowly moving camera never
reaches that. When the first attempt builds no model, the mapper runs once more with the
initialisation relaxed to :data:`RELAXED` (1.5° and 30 inliers, models from 5 images): rotations
from a narrow baseline are still well determined, positions less so.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

#: The second mapping attempt's initialisation, when the defaults built no model.
RELAXED = {"init_min_tri_angle": 1.5, "init_min_num_inliers": 30, "min_model_size": 5}


def reason(notes: dict) -> str:
    """One line on why COLMAP registered no frame or fewer than all ("" when it needs none)."""
    if not notes or notes.get("registered", 0) >= notes.get("images", 0):
        return ""
    head = (
        f"COLMAP registered {notes.get('registered', 0)} of {notes.get('images', 0)} keyframes"
        f" ({notes.get('attempts', 1)} mapping attempt(s), the last with an initial triangulation angle"
        f" of {notes.get('min_tri_angle_deg', 16.0):g}°)"
    )
    pairs = notes.get("verified_pairs")
    if pairs is not None:
        head += f"; {pairs} image pairs verified, median {notes.get('median_inliers', 0):.0f} inliers"
    return head


def _matching_notes(db_path: Path) -> dict:
    import pycolmap

    db = pycolmap.Database.open(db_path)
    try:
        _, geometries = db.read_two_view_geometries()
        inliers = [len(g.inlier_matches) for g in geometries]
        return {
            "images": db.num_images(),
            "verified_pairs": db.num_verified_image_pairs(),
            "median_inliers": float(np.median(inliers)) if inliers else 0.0,
        }
    finally:
        db.close()


def _options(relaxed: bool):
    import pycolmap

    opts = pycolmap.IncrementalPipelineOptions()
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.num_threads = 1
    if relaxed:
        opts.mapper.init_min_tri_angle = RELAXED["init_min_tri_angle"]
        opts.mapper.init_min_num_inliers = RELAXED["init_min_num_inliers"]
        opts.min_model_size = RELAXED["min_model_size"]
    return opts


def main() -> None:
    import pycolmap  # heavy optional dependency, only in this worker process

    images, out = Path(sys.argv[1]), Path(sys.argv[2])
    cam = json.loads(Path(sys.argv[3]).read_text())
    rotations, positions = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "db.db"
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        reader.camera_params = f"{cam['fx']},{cam['fy']},{cam['cx']},{cam['cy']}"
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.sift.max_num_features = 1024
        extraction.sift.first_octave = 0  # no up-sampled octave: 3x faster at 640x480
        extraction.num_threads = 1
        pycolmap.extract_features(
            db, images, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader, extraction_options=extraction
        )
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = 6
        pycolmap.match_sequential(db, pairing_options=pairing)
        notes = _matching_notes(db)
        recs: dict = {}
        for attempt, relaxed in enumerate((False, True), start=1):
            recs = pycolmap.incremental_mapping(db, images, Path(tmp) / f"sparse{attempt}", options=_options(relaxed))
            notes["attempts"] = attempt
            notes["min_tri_angle_deg"] = RELAXED["init_min_tri_angle"] if relaxed else 16.0
            if recs:
                break
        notes["registered"] = 0
        if recs:
            best = max(recs.values(), key=lambda r: r.num_reg_images())
            for img in best.images.values():
                if img.has_pose:
                    pose = img.cam_from_world()
                    R = pose.rotation.matrix()
                    rotations[img.name] = R.tolist()
                    positions[img.name] = (-R.T @ np.asarray(pose.translation)).tolist()
            notes["registered"] = len(rotations)
    out.write_text(json.dumps({"rotations": rotations, "positions": positions, "notes": notes}))


if __name__ == "__main__":
    main()
