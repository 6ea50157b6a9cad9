"""The walkcap recording: one MCAP file per trial, and everything that reads or writes it.

Public API: `Recorder` (writes a trial), `Sink` (what a session writes to: the recorder and the
live taps), `TOPICS` / `Topic` (every topic's schema and message builder), `Encoded` (a message
ready for the file), `open_recording` / `Recording` (reads one, damaged or not), `read_trial` /
`read_trials` (per-frame arrays for evaluation), `frame_table` / `FrameTable` (every per-frame
topic joined by frame), `read_gait` / `GaitTable` (the gait events of /gait and /sim/gait),
`summary` (what a file holds, behind `walkcap info`), `check` and
`recover` (damage and rebuilding), `copy_recording` (a copy with labels, events and metadata
added), `describe` / `derivation` (a file's identity and lineage), `trial_conflict` (trial
numbers), `PERSONAL_FIELDS` / `ShareRules` (capture.recording.personal: what is personal and
how a copy made for sharing reduces it), `FORMAT_VERSION` (capture.recording.versions: how
files of an older version are read). The label rules: capture.recording.labels.
"""

from capture.recording._mcap import NotMcapError
from capture.recording.checking import check
from capture.recording.copy import copy_recording
from capture.recording.encode import Encoded
from capture.recording.frames import FrameTable
from capture.recording.gait import GaitTable, read_gait
from capture.recording.lineage import derivation, describe
from capture.recording.naming import trial_conflict
from capture.recording.personal import PERSONAL_FIELDS, PersonalField, ShareRules
from capture.recording.reader import (
    Recording,
    frame_table,
    open_recording,
    read_trial,
    read_trials,
)
from capture.recording.recover import recover
from capture.recording.sink import Sink
from capture.recording.summary import RecordingSummary, summary
from capture.recording.topics import FORMAT_VERSION, TOPICS, Topic
from capture.recording.writer import Recorder

__all__ = [
    "FORMAT_VERSION",
    "TOPICS",
    "Encoded",
    "FrameTable",
    "GaitTable",
    "PERSONAL_FIELDS",
    "NotMcapError",
    "PersonalField",
    "Recorder",
    "Recording",
    "RecordingSummary",
    "ShareRules",
    "Sink",
    "Topic",
    "check",
    "copy_recording",
    "derivation",
    "describe",
    "frame_table",
    "open_recording",
    "read_gait",
    "read_trial",
    "read_trials",
    "recover",
    "summary",
    "trial_conflict",
]
