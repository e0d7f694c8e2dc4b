"""Evaluation methodology for visual odometers (thesis Part IV)."""
