"""How a drive's pictures and side streams are stored: segment bitstreams behind one codec
interface (:mod:`~egovid.dashcam.codec.registry`: VP9 coded with the older drive's aligned frames as
a free reference, thesis §14.2, and AV1 standalone), their settings, and the audio/telemetry blob."""
