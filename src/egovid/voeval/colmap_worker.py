"""Run pycolmap incremental mapping on a folder of frames (separate process: pycolmap and OpenCV
ship clashing native libraries). Usage: python -m egovid.voeval.colmap_worker IMAGES OUT.json fx fy cx cy

Writes {"rotations": {image_name: cam_from_world 3x3}} for the largest reconstruction.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path


def main() -> None:
    import pycolmap

    images, out = Path(sys.argv[1]), Path(sys.argv[2])
    fx, fy, cx, cy = (float(v) for v in sys.argv[3:7])
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "db.db"
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        reader.camera_params = f"{fx},{fy},{cx},{cy}"
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
        opts = pycolmap.IncrementalPipelineOptions()
        opts.ba_refine_focal_length = False
        opts.ba_refine_principal_point = False
        opts.ba_refine_extra_params = False
        opts.num_threads = 1
        recs = pycolmap.incremental_mapping(db, images, Path(tmp) / "sparse", options=opts)
        rotations = {}
        if recs:
            best = max(recs.values(), key=lambda r: r.num_reg_images())
            for img in best.images.values():
                if img.has_pose:
                    rotations[img.name] = img.cam_from_world().rotation.matrix().tolist()
    out.write_text(json.dumps({"rotations": rotations}))


if __name__ == "__main__":
    main()
