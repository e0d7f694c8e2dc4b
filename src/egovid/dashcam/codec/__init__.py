"""How a drive's pictures and side streams are stored: segment bitstreams coded with the older
drive's aligned frames as a free reference (thesis §14.2), and the audio/telemetry blob."""
