"""Capture: synchronizes devices, runs the pipeline per frame, records sessions."""

__version__ = "0.1.0"
