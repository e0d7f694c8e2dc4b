"""Input and output at the edges: video (PyAV), camera intrinsics, trajectory files."""
