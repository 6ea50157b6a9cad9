"""The walkcap recording: one MCAP file per trial, and everything that reads or writes it.

Public API, the reader, the writer and their errors:

    with open_recording(path) as rec:                 # Recording: metadata, topics, index
        rec.meta.session.subject                      # Metadata: typed records
        for m in rec.messages("/imu", start=t0_ns, end=t1_ns):   # RecordedMessage
            ...

`open_recording` / `Recording` / `RecordedMessage` / `TopicInfo` read one file, damaged or
not; `Metadata` holds its metadata records typed (capture.recording.metadata); `Recorder`
writes a trial; `CaptureError` is every error a recording raises, `NotMcapError` the one for
a file that is not MCAP. The rest are modules of their own: topics (every topic's schema
and message builder), frames (the per-frame join, `frame_table` in the reader), summary
(`walkcap info`), checking and recover (damage and rebuilding), copy (a copy with labels,
events and metadata added), lineage (a file's identity), naming (trial numbers), personal
(what is personal and how a shared copy reduces it), versions (how older files are read),
labels (the label rules).
"""

from capture.errors import CaptureError
from capture.recording._mcap import NotMcapError
from capture.recording.metadata import Metadata
from capture.recording.reader import RecordedMessage, Recording, TopicInfo, open_recording
from capture.recording.writer import Recorder

__all__ = [
    "CaptureError",
    "Metadata",
    "NotMcapError",
    "RecordedMessage",
    "Recorder",
    "Recording",
    "TopicInfo",
    "open_recording",
]
