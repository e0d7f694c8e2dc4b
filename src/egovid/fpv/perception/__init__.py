"""The smooth-pursuit viewing-experience model (thesis ch. 7–8): object-position intervals B(k),
VE, SVE and 2D-VE. Pure functions on angle arrays (degrees); see :mod:`egovid.fpv.perception.score`
for the one-call API."""
