"""First-person video (thesis Part II): the smooth-pursuit viewing-experience scores
(:mod:`egovid.fpv.perception`) and the FPMI-preserving stabiliser (:mod:`egovid.fpv.stabilize`)."""
