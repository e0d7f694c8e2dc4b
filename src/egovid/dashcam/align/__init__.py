"""Which older frame goes with each new one (thesis §15.2–15.3): ORB timeline alignment, the
SeqSLAM baseline, illumination matching and stop detection."""
