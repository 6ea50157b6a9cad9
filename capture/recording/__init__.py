"""The walkcap recording: one MCAP file per trial, and everything that reads or writes it.

Public API: `Recorder` (writes a trial), `open_recording` / `Recording` (reads one, damaged or
not), `read_trial` / `read_trials` (the per-frame table), `check` and `recover` (damage and
rebuilding), `describe` / `derivation` (a file's identity and lineage), `trial_conflict`
(trial numbers), `FORMAT_VERSION`.
"""

from capture.recording._mcap import NotMcapError, check
from capture.recording.lineage import derivation, describe
from capture.recording.naming import trial_conflict
from capture.recording.reader import Recording, open_recording, read_trial, read_trials
from capture.recording.recover import recover
from capture.recording.topics import FORMAT_VERSION
from capture.recording.writer import Recorder

__all__ = [
    "FORMAT_VERSION",
    "NotMcapError",
    "Recorder",
    "Recording",
    "check",
    "derivation",
    "describe",
    "open_recording",
    "read_trial",
    "read_trials",
    "recover",
    "trial_conflict",
]
