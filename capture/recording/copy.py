"""Copying a recording into a new file, with labels, events and metadata added.

A copy keeps every message as it was recorded (the same schemas, channels, bytes, times
and sequence numbers): unlike capture.recording.writer.Recorder it never re-encodes
(depth from xyz, clouds decimated again) and never drops what a bounded queue cannot
take. `RecordingCopy` copies records one by one (`walkcap recover` feeds it what the scan
of a damaged file finds); `copy_recording` copies a readable recording whole, adding
labels, events and metadata records and naming the copy's own id and its derivation
(the replay screen's label corrections).
"""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording.chunk_digests import CHUNK_DIGESTS
from capture.recording.digests import DIGESTS, Sealer
from capture.recording.lineage import derivation
from capture.recording.messages import iter_raw
from capture.recording.reader import open_recording
from devices.files import check_replaceable

CHUNK_BYTES = 4 * 1024 * 1024


class RecordingCopy:
    """An MCAP writer that takes another file's records and maps their ids."""

    def __init__(self, stream: BinaryIO) -> None:
        from mcap.writer import CompressionType, Writer

        self._writer = Writer(stream, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        self._sealed = Sealer(self._writer)  # the copy's own record digests
        self._schemas: dict[int, int] = {}  # the source's schema id -> the copy's
        self._channels: dict[int, int] = {}  # the source's channel id -> the copy's
        self.topics: dict[int, str] = {}  # the source's channel id -> its topic
        self._by_topic: dict[str, int] = {}  # topic -> the copy's (first) channel for it
        self.counts: dict[str, int] = {}  # messages written per topic
        self.started = False

    def start(self, profile: str = "", library: str = "walkcap") -> None:
        self._sealed.start(profile, library)
        self.started = True

    def schema(self, schema) -> int:
        """The copy's id of a source schema (an mcap Schema record; None: no schema)."""
        if schema is None:
            return 0
        if schema.id not in self._schemas:
            self._schemas[schema.id] = self._sealed.schema(
                schema.name, schema.encoding, schema.data
            )
        return self._schemas[schema.id]

    def channel(self, channel, schema=None) -> int:
        """The copy's id of a source channel (an mcap Channel record); `schema`: its
        schema record, when the source's schema ids are not all known yet."""
        if channel.id not in self._channels:
            if schema is not None:
                sid = self.schema(schema)
            else:
                sid = self._schemas.get(channel.schema_id, 0)
            cid = self._sealed.channel(
                channel.topic, channel.message_encoding, sid, dict(channel.metadata)
            )
            self._channels[channel.id] = cid
            self.topics[channel.id] = channel.topic
            self._by_topic.setdefault(channel.topic, cid)
        return self._channels[channel.id]

    def knows(self, channel_id: int) -> bool:
        return channel_id in self._channels

    def message(self, message) -> None:
        """A source message (an mcap Message record) on its channel, as it was."""
        self._writer.add_message(
            self._channels[message.channel_id],
            message.log_time,
            message.data,
            message.publish_time,
            message.sequence,
        )
        topic = self.topics[message.channel_id]
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def add(self, topic: str, entry: dict) -> None:
        """A new JSON message (a label or an event) at its `time_ns`, on the topic's
        channel: the source's, or one made from the topic's spec when it had none."""
        cid = self._by_topic.get(topic)
        if cid is None:
            spec = T.TOPICS[topic]
            sid = self._sealed.schema(spec.schema_name, spec.schema_encoding, spec.schema_data)
            cid = self._sealed.channel(
                topic, spec.message_encoding, sid, {"description": spec.description}
            )
            self._by_topic[topic] = cid
        t = int(entry["time_ns"])
        self._writer.add_message(cid, t, T.encode_json(entry), t, 0)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """A metadata record as MCAP holds it (values as text: T.encode_metadata); a
        source's record and chunk digests are not copied (the copy's bytes are its own)."""
        if name not in (DIGESTS, CHUNK_DIGESTS):
            self._sealed.metadata(name, values)

    def attachment(self, create_time: int, log_time: int, name: str, media: str, data) -> None:
        self._writer.add_attachment(create_time, log_time, name, media, data)

    def finish(self) -> None:
        if not self.started:
            self.start()
        self._writer.finish()


@contextlib.contextmanager
def new_recording(target: Path) -> Iterator[BinaryIO]:
    """A new recording file written whole: into a partial file beside `target` (a leftover
    one of ours is replaced), synced, then linked to its name, which fails where a file
    exists: a recording is never overwritten. Any OS error is one CaptureError line."""
    tmp = target.with_name(f".{target.name}.partial")
    try:
        with open(tmp, "wb") as out:
            yield out
            out.flush()
            os.fsync(out.fileno())
        os.link(tmp, target)
    except FileExistsError:
        raise CaptureError(f"{target} exists: a recording is never overwritten") from None
    except OSError as e:
        raise CaptureError(f"cannot write {target}: {e.strerror or e}") from None
    finally:
        try:
            tmp.unlink()
        except OSError:
            pass


def _media_type(name: str) -> str:
    if name.endswith(".npy"):
        return "application/x-npy"
    return "application/json" if name.endswith(".json") else "application/octet-stream"


def copy_recording(
    source: str | os.PathLike,
    target: str | os.PathLike,
    *,
    kind: str,
    how: str,
    labels: Iterable[dict] = (),
    events: Iterable[dict] = (),
    metadata: Iterable[tuple[str, dict]] = (),
) -> Path:
    """Copy the recording `source` message for message into the new file `target` (never
    overwritten; the source is never modified), adding `labels` (T.label_json dicts) to
    /labels, `events` (T.event_json dicts) to /events, and the `metadata` records after
    the source's. The copy is a new recording: its own id in "recording", and a
    "derivation" record naming the source, `kind` (capture.recording.lineage) and `how`.
    Metadata values are written as JSON, whatever the source held."""
    source, target = Path(source), Path(target)
    if target.resolve() == source.resolve():
        raise CaptureError("the copy must be a new file: the original is never modified")
    check_replaceable(target)
    rec = open_recording(source)
    with new_recording(target) as out:
        copy = RecordingCopy(out)
        copy.start(library=rec.library or "walkcap")
        copy_id = str(uuid.uuid4())
        for name, values in rec.metadata_records:
            if name == "recording":
                values = {**values, "id": copy_id, T.METADATA_VALUES_KEY: T.METADATA_VALUES}
            if name != "derivation":
                copy.metadata(name, T.encode_metadata(values))
        copy.metadata("derivation", T.encode_metadata(derivation(rec, copy_id, kind, how)))
        for name, values in metadata:
            copy.metadata(name, T.encode_metadata(values))
        t0 = rec.start_ns or 0
        for name, data in rec.attachments.items():
            copy.attachment(t0, t0, name, _media_type(name), data)
        for schema, channel, message in iter_raw(source, rec.complete, None):
            copy.channel(channel, schema)
            copy.message(message)
        added = [(T.LABELS, e) for e in labels] + [(T.EVENTS, e) for e in events]
        for topic, entry in sorted(added, key=lambda x: x[1]["time_ns"]):
            copy.add(topic, entry)
        copy.finish()
    return target
