"""egovid: make egocentric (first-person and dashcam) video more useful.

Three systems, following B. Ma, "Improving the utility of egocentric videos" (Purdue, 2019):

* :mod:`egovid.fpv.perception` and :mod:`egovid.fpv.stabilize` — viewing-experience scores (VE, SVE,
  2D-VE) and an FPMI-preserving stabiliser for first-person video (``egovid fpv``);
* :mod:`egovid.dashcam` — a route-aware archive that compresses a drive against an older drive
  of the same path (``egovid dashcam``);
* :mod:`egovid.voeval` — an evaluation method for visual odometers (``egovid voeval``).
"""

__version__ = "0.1.0"
