"""Live sessions in tests: a cheap stand-in for the CNN and a session on the mock devices."""

import numpy as np

from capture.config import Config
from capture.live.session import Session
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


def events_of(path) -> list[dict]:
    """The /events messages of a recording, in file order."""
    return [m.data for m in open_recording(path).messages(["/events"])]
