"""What a camera says about itself: intrinsics (and which a video file has), ExifTool metadata and
embedded telemetry."""
