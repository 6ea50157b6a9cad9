"""Capture: synchronizes devices, runs the pipeline per frame, records sessions."""

from importlib import metadata

from devices.camera import register_backend

# pyproject.toml's version, as installed; a source tree run without installing says so.
try:
    __version__ = metadata.version("walkcap")
except metadata.PackageNotFoundError:
    __version__ = "0+unknown"

# The replay camera reads recordings, so it lives here; sessions open it by name.
register_backend("replay", "capture.live.replay_camera:ReplayCamera")
