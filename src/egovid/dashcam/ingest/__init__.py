"""Ingest of drives into an archive, as a pipeline of named stages (thesis Part III):

    probe -> track -> split -> baseline -> align -> encode -> commit

* :mod:`records` — what the stages hand each other (small, typed, picklable);
* :mod:`stages` — probe, track, split, choose baseline, commit (no pictures);
* :mod:`piece` — baseline, align, encode and verify of one piece (pictures);
* :mod:`run` — a drive's stages with the archive's locks (:func:`ingest`, :func:`ingest_drive`).
"""

from egovid.dashcam.align import ALIGNERS
from egovid.dashcam.ingest.options import BASELINE_ALIGN, IngestOptions
from egovid.dashcam.ingest.records import DriveInput, IngestReport, PieceReport
from egovid.dashcam.ingest.run import ingest, ingest_drive

__all__ = [
    "ALIGNERS",
    "BASELINE_ALIGN",
    "DriveInput",
    "IngestOptions",
    "IngestReport",
    "PieceReport",
    "ingest",
    "ingest_drive",
]
