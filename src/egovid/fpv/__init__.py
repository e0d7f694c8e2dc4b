"""First-person video (thesis Part II): the smooth-pursuit viewing-experience scores
(:mod:`egovid.fpv.perception`) and the FPMI-preserving stabiliser (:mod:`egovid.fpv.stabilize`).

The ``egovid fpv`` commands, one function each: :func:`egovid.fpv.motion.save_motion` (``fpv
motion``), :func:`egovid.fpv.score.score_video` (``fpv score``) and
:func:`egovid.fpv.stabilize.run.stabilize_video` (``fpv stabilize``)."""
