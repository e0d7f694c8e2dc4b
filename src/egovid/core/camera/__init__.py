"""What a camera says about itself: intrinsics, ExifTool metadata and embedded telemetry."""
