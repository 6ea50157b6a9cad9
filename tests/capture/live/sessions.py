"""Live sessions in tests: a cheap stand-in for the CNN and a session on the mock devices."""

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from capture.config import Config
from capture.live.session import Session
from capture.live.trials import SubjectInfo
from capture.recording.reader import open_recording


class StandInClassifier:
    """Scores from the image's column profile: deterministic, cheap, image-dependent."""

    metadata = {"weights_sha256": "stand-in"}

    def predict(self, image):
        cols = image.any(axis=0).sum()
        p = np.full(5, 0.05)
        p[int(cols) % 5] = 0.8
        return p


def session_in(tmp_path) -> Session:
    """A session on the default (mock) devices recording into `tmp_path`."""
    c = Config()
    c.session.recordings = str(tmp_path)
    return Session(c, classifier=StandInClassifier())


@dataclass
class Trial:
    session: Session
    path: Path
    stats: Any = None  # the recorder's stats, once the session has stopped


@contextlib.contextmanager
def recording_in(folder):
    """A started session on the mock devices recording a trial into `folder`; stopped on
    the way out, whatever happened, with the recorder's stats then in `trial.stats`."""
    session = session_in(folder)
    session.start()
    trial = Trial(session, Path())
    try:
        trial.path = session.start_recording(SubjectInfo())
        yield trial
    finally:
        trial.stats = session.stop()


def events_of(path) -> list[dict]:
    """The /events messages of a recording, in file order."""
    return [m.data for m in open_recording(path).messages(["/events"])]
