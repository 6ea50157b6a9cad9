"""Test helper: files of format version 1, made from files written now.

`as_version_1` copies a recording record for record into a file that says
`format_version` 1 and holds what version 1 held: no "derivation" record, no record
digests or chunk digests, and fused messages without `source_frame_index`.
"""

from __future__ import annotations

import json
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import Writer

from capture.recording import topics as T


def as_version_1(
    source: Path, target: Path, *, metadata: dict | None = None, version: str = "1"
) -> Path:
    """`source` rewritten as version 1 wrote it into `target`; `metadata` records (plain
    JSON values) are added, replacing those of the same name. `version`: another version
    named in the file instead (its content as version 1's)."""
    extra = {name: T.encode_metadata(values) for name, values in (metadata or {}).items()}
    with open(source, "rb") as f, open(target, "wb") as g:
        reader = make_reader(f)
        w = Writer(g)
        w.start(profile="", library=reader.get_header().library)
        for m in reader.iter_metadata():
            values = dict(m.metadata)
            if m.name in ("derivation", "record_digests", "chunk_digests") or m.name in extra:
                continue
            if m.name == "recording":
                values["format_version"] = T.encode_metadata({"v": version})["v"]
            w.add_metadata(m.name, values)
        for name, values in extra.items():
            w.add_metadata(name, values)
        for a in reader.iter_attachments():
            w.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        schemas, channels = {}, {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas.get(channel.schema_id, 0),
                    dict(channel.metadata),
                )
            data = message.data
            if channel.topic == T.FUSED:
                fused = json.loads(data)
                fused.pop("source_frame_index", None)
                data = T.encode_json(fused)
            w.add_message(
                channels[channel.id],
                message.log_time,
                data,
                message.publish_time,
                message.sequence,
            )
        w.finish()
    return target


def as_version_4(source: Path, target: Path, tf) -> Path:
    """`source` copied record for record (digests sealed anew) into `target`, a file that
    says `format_version` 4 and holds /tf as version 4 wrote it: `tf(sequence)` gives
    frame `sequence`'s IMU quaternion [w, x, y, z]."""
    import dataclasses

    from capture.recording.copy import RecordingCopy, new_recording
    from capture.recording.messages import iter_raw
    from capture.recording.reader import open_recording

    rec = open_recording(source)
    with new_recording(target) as out:
        copy = RecordingCopy(out)
        copy.start(library=rec.library or "walkcap")
        for name, values in rec.metadata_records:
            if name == "recording":
                values = {**values, "format_version": "4"}
            copy.metadata(name, T.encode_metadata(values))
        for schema, channel, message in iter_raw(source, rec.complete, None):
            copy.channel(channel, schema)
            if channel.topic == T.TF:
                transform = T.transform_message(tf(message.sequence), message.publish_time)
                message = dataclasses.replace(message, data=transform.SerializeToString())
            copy.message(message)
        copy.finish()
    return target
