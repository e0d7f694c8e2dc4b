"""Camera rotation estimation from a video (thesis ch. 6): local features, pairwise RANSAC
rotations at two frame distances, and a robust pose graph on SO(3)."""
