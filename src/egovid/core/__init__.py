"""The shared core of egovid's three systems: errors, the task engine, atomic files, rotations,
video I/O, camera metadata and telemetry, trajectories, camera motion and metrics. Nothing here
imports :mod:`egovid.fpv`, :mod:`egovid.dashcam` or :mod:`egovid.voeval`."""
