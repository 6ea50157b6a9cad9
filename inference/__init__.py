"""Inference: pure algorithms (preprocessing, terrain features, CNN, fusion)."""
