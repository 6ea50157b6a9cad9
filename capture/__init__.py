"""Capture: synchronizes devices, runs the pipeline per frame, records sessions."""

from devices.camera import register_backend

__version__ = "0.1.0"

# The replay camera reads recordings, so it lives here; sessions open it by name.
register_backend("replay", "capture.live.replay_camera:ReplayCamera")
