"""Capture: synchronizes devices, runs the pipeline per frame, records sessions."""

from devices.camera import register_backend

# The replay camera reads recordings, so it lives here; sessions open it by name.
register_backend("replay", "capture.live.replay_camera:ReplayCamera")


def __getattr__(name: str) -> str:
    # pyproject.toml's version, as installed (a source tree run without installing says so);
    # read on first use: importlib.metadata costs the CLI's --help a noticeable 30 ms.
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib import metadata

    try:
        version = metadata.version("walkcap")
    except metadata.PackageNotFoundError:
        version = "0+unknown"
    globals()["__version__"] = version
    return version
