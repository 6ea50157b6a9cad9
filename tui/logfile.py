"""Where the UI's log lines go while it owns the terminal, and the filter that keeps the
configuration's secrets out of every log line, wherever it goes."""

from __future__ import annotations

import contextlib
import logging
import os

HIDDEN = "<secret>"


class Redactor(logging.Filter):
    """Replaces every secret value the configuration sets (capture.config.secrets_of) in a
    log record's text (message, arguments, traceback) before any handler writes it."""

    def __init__(self) -> None:
        super().__init__()
        self.secrets: list[str] = []

    def redact(self, text: str) -> str:
        for secret in self.secrets:
            text = text.replace(secret, HIDDEN)
        return text

    def filter(self, record: logging.LogRecord) -> bool:
        if self.secrets:
            message = record.getMessage()
            if record.exc_info and not record.exc_text:
                record.exc_text = logging.Formatter().formatException(record.exc_info)
            record.msg, record.args = self.redact(message), ()
            if record.exc_text:
                record.exc_text = self.redact(record.exc_text)
        return True


REDACTOR = Redactor()  # one for the process: the CLI sets its secrets once configured


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
    handler.addFilter(REDACTOR)
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
