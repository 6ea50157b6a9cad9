"""Where the UI's log lines go while it owns the terminal."""

from __future__ import annotations

import contextlib
import logging
import os


def log_path() -> str:
    return os.path.join(os.path.expanduser("~"), ".cache", "walkcap", "tui.log")


@contextlib.contextmanager
def logging_to_file(path: str):
    """While the UI owns the terminal, log lines go to a file instead of stderr, from INFO
    up: the session's notices and device events, each with its time."""
    root = logging.getLogger()
    saved = root.handlers[:]
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        handler: logging.Handler = logging.FileHandler(path)
        os.chmod(path, 0o600)  # it names subjects (by id): its owner's to read
    except OSError:
        handler = logging.NullHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root.handlers = [handler]
    level = root.level
    # what happened in the session (losses, stalls, reconnects, trials saved) is INFO
    root.setLevel(min(level, logging.INFO) if level else logging.INFO)
    try:
        yield
    finally:
        root.handlers = saved
        root.setLevel(level)
        handler.close()
