"""Synthetic content with ground truth: scenes from bundled photos, camera motions, rendering."""
