"""Ingest of drives into an archive, as a pipeline of named stages (thesis Part III):

    probe -> track -> split -> baseline -> align -> encode -> commit

* :mod:`videos` — :func:`ingest_videos`, the ingest of video files and folders: the one route of
  ``egovid dashcam ingest``, the demo, the benchmarks and the tests;
* :mod:`sources`, :mod:`fleet` — the files examined (GPS, clock, kind, trips) and made drives;
* :mod:`records` — what the stages hand each other (small, typed, picklable);
* :mod:`stages` — probe, track, split, choose baseline, commit (no pictures);
* :mod:`piece`, :mod:`frames` — baseline, align, encode and verify of one piece (pictures);
* :mod:`run` — a drive's stages with the archive's locks (:func:`ingest_drive`), many drives on
  the task engine.
"""

from egovid.dashcam.align import ALIGNERS
from egovid.dashcam.ingest.options import BASELINE_ALIGN, IngestOptions
from egovid.dashcam.ingest.records import DriveInput, IngestReport, PieceReport
from egovid.dashcam.ingest.run import ingest_drive
from egovid.dashcam.ingest.sources import ClockOptions
from egovid.dashcam.ingest.videos import DriveOutcome, IngestHooks, IngestResult, ingest_videos

__all__ = [
    "ALIGNERS",
    "BASELINE_ALIGN",
    "ClockOptions",
    "DriveInput",
    "DriveOutcome",
    "IngestHooks",
    "IngestOptions",
    "IngestReport",
    "IngestResult",
    "PieceReport",
    "ingest_drive",
    "ingest_videos",
]
