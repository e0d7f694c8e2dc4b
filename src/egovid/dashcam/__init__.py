"""Route-aware dashcam archive with joint compression (thesis Part III)."""
