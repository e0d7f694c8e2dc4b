"""Synthetic content with ground truth: scenes from bundled photos, camera motions, rendering.

The ``egovid synth`` commands, one function each: :func:`egovid.synth.fpv.synth_fpv` (a
first-person clip of a named motion) and :func:`egovid.synth.drive.render_drive` (a dashcam drive
with its GPS track)."""
