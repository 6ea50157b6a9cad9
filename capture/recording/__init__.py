"""The walkcap recording: one MCAP file per trial, and everything that reads or writes it.

Public API: `Recorder` (writes a trial), `Sink` (what a session writes to: the recorder and the
live taps), `TOPICS` / `Topic` (every topic's schema and message builder), `Encoded` (a message
ready for the file), `open_recording` / `Recording` (reads one, damaged or not), `read_trial` /
`read_trials` (the per-frame table), `check` and `recover` (damage and rebuilding), `describe` /
`derivation` (a file's identity and lineage), `trial_conflict` (trial numbers), `FORMAT_VERSION`.
"""

from capture.recording._mcap import NotMcapError, check
from capture.recording.encode import Encoded
from capture.recording.lineage import derivation, describe
from capture.recording.naming import trial_conflict
from capture.recording.reader import Recording, open_recording, read_trial, read_trials
from capture.recording.recover import recover
from capture.recording.sink import Sink
from capture.recording.topics import FORMAT_VERSION, TOPICS, Topic
from capture.recording.writer import Recorder

__all__ = [
    "FORMAT_VERSION",
    "TOPICS",
    "Encoded",
    "NotMcapError",
    "Recorder",
    "Recording",
    "Sink",
    "Topic",
    "check",
    "derivation",
    "describe",
    "open_recording",
    "read_trial",
    "read_trials",
    "recover",
    "trial_conflict",
]
