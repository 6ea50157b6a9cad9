"""Copies of recordings a study can share: personal fields reduced, sensor data as recorded.

`share(paths, out, rules)` picks one file per trial as every corpus job does
(capture.corpus.selection: a corrected copy stands for its trial, a superseded recording is
left out, and so on) and writes each into `out` as `<subject>_<condition>_t<NN>.mcap`:
- every message as it was recorded, byte for byte (depth, IMU, labels, decisions, features,
  clouds, truth, other devices' streams), except an operator's marker on /events, whose
  text follows the rules, and an /imu sample that carries the IMU's UTC date, which moves
  with the dates;
- the metadata and the attached configuration reduced by the rules
  (capture.recording.personal.reduce_metadata), Unix times moved by the subject's (or the
  study's) whole-day offset, file names without their times;
- a "derivation" record of kind "shared" naming the source, and a "sharing" record saying
  what was removed (`walkcap info` shows it). No journal goes with a shared copy.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import orjson

from capture.corpus.selection import Corpus, select
from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording.copy import RecordingCopy, _media_type, new_recording
from capture.recording.lineage import SHARED, derivation, describe
from capture.recording.messages import iter_raw
from capture.recording.metadata import DerivationRecord, SharingRecord
from capture.recording.personal import (
    ShareRules,
    date_offset_ns,
    is_personal_event,
    reduce_config_text,
    reduce_event,
    reduce_metadata,
    shared_name,
    shift_unix_ns,
    shift_utc_fields,
    strip_file_time,
)
from capture.recording.reader import open_recording
from devices.files import check_replaceable


@dataclass
class Shared:
    """One shared copy: where it came from, where it is, what changed."""

    source: Path
    path: Path
    removed: list[str]
    messages: int  # messages copied
    rewritten: dict[str, int] = field(default_factory=dict)  # topic -> messages changed


def _shift_imu(data: bytes, offset_ns: int) -> bytes | None:
    """An /imu message with its UTC date moved, or None when it has none."""
    if b'"utc_time"' not in data:
        return None
    sample = orjson.loads(data)
    extra = sample.get("extra") or {}
    utc = extra.get("utc_time")
    if not isinstance(utc, list) or len(utc) < 7:
        return None
    extra["utc_time"] = shift_utc_fields(utc, offset_ns)
    return T.encode_json(sample)


def share_recording(source: Path, target: Path, rules: ShareRules) -> Shared:
    """Write the shared copy of the recording `source` to the new file `target` (never
    overwritten; the source is never modified)."""
    source, target = Path(source), Path(target)
    check_replaceable(target)
    rec = open_recording(source)
    member = describe(rec)
    subject = rec.trial[0] or ""
    offset = date_offset_ns(rules, subject)
    removed: list[str] = []
    rewritten: dict[str, int] = {}
    with new_recording(target) as out:
        copy = RecordingCopy(out)
        copy.start(library=rec.library or "walkcap")
        copy_id = _new_id()
        for name, values in rec.metadata_records:
            if name == "derivation":
                continue  # the copy's own derivation follows
            reduced = reduce_metadata(name, values, rules, offset)
            if name == "recording":
                reduced.values = {
                    **reduced.values,
                    "id": copy_id,
                    T.METADATA_VALUES_KEY: T.METADATA_VALUES,
                }
                reduced.values.pop("journal", None)  # no journal goes with the copy
            removed += [r for r in reduced.removed if r not in removed]
            copy.metadata(name, T.encode_metadata(reduced.values))
        d = DerivationRecord.from_dict(
            derivation(rec, copy_id, SHARED, "shared copy: personal fields reduced")
        )
        d = d.replaced(source_name=strip_file_time(d.source_name), source_kind=member.kind)
        copy.metadata(d.NAME, T.encode_metadata(d.to_dict()))
        start_unix = shift_unix_ns(rec.unix_time_ns(rec.start_ns or 0), offset) or 0
        for name, data in rec.attachments.items():
            if name == "walkcap.toml":
                text = reduce_config_text(bytes(data).decode(errors="replace"), rules)
                if text.encode() != bytes(data):
                    removed.append("walkcap.toml: operator")
                data = text.encode()
            copy.attachment(start_unix, rec.start_ns or 0, name, _media_type(name), data)
        messages = 0
        for schema, channel, message in iter_raw(source, rec.complete, None):
            copy.channel(channel, schema)
            data = _reduced_message(channel.topic, message.data, rules, offset)
            if data is not None:
                rewritten[channel.topic] = rewritten.get(channel.topic, 0) + 1
                message = _with_data(message, data)
            copy.message(message)
            messages += 1
        for topic, n in sorted(rewritten.items()):
            what = "marker text" if topic == T.EVENTS else "UTC date shifted"
            removed.append(f"{topic}: {what} in {n} message(s)")
        if offset:
            removed.append("dates shifted (whole days)")
        sharing = SharingRecord.build(
            rules=rules.describe(),
            removed=removed,
            source_id=rec.id,
            unchanged="every other message, byte for byte",
        )
        copy.metadata(
            sharing.NAME,
            T.encode_metadata(sharing.to_dict()),
        )
        copy.finish()
    return Shared(source, target, removed, messages, rewritten)


def _reduced_message(topic: str, data: bytes, rules: ShareRules, offset: int) -> bytes | None:
    """A message's new bytes when the rules change it; None: copied as it was."""
    if topic == T.EVENTS and b'"operator"' in data:
        entry = orjson.loads(data)
        if is_personal_event(entry):
            new = reduce_event(entry, rules)
            return None if new == entry else T.encode_json(new)
    elif topic == T.IMU and offset:
        return _shift_imu(data, offset)
    return None


def _with_data(message, data: bytes):
    from mcap.records import Message

    return Message(
        channel_id=message.channel_id,
        sequence=message.sequence,
        log_time=message.log_time,
        publish_time=message.publish_time,
        data=data,
    )


def _new_id() -> str:
    import uuid

    return str(uuid.uuid4())


def share(
    paths: Iterable[str | os.PathLike], out: str | os.PathLike, rules: ShareRules
) -> tuple[list[Shared], Corpus]:
    """Shared copies in `out` of one file per trial of `paths`; (copies, the corpus: what was
    left out and why). The rules are checked before anything is written."""
    rules.check()
    out, paths = Path(out), [Path(p) for p in paths]
    # a shared copy among the lab's recordings would be read as one more of them: not beside
    # a file given, nor anywhere in a folder given
    target = out.resolve()
    beside = {p.resolve().parent for p in paths if p.is_file()}
    inside = {p.resolve() for p in paths if p.is_dir()}
    if target in beside or any(target == d or d in target.parents for d in inside):
        raise CaptureError(
            f"{out}: inside the recordings given; shared copies go into a folder of their own"
        )
    corpus = select(paths)
    if not corpus.chosen:
        raise corpus.nothing_left("share")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CaptureError(f"cannot create {out}: {e.strerror}") from None
    names: dict[str, int] = {}
    targets = []
    for m in corpus.chosen:
        subject, condition, trial = m.trial
        name = shared_name(subject, condition, trial)
        n = names[name] = names.get(name, 0) + 1
        if n > 1:  # separate recordings of one trial: each is shared
            name = name.replace(".mcap", f"_{n}.mcap")
        targets.append((m.path, out / name))
    existing = [t for _, t in targets if t.exists()]
    if existing:
        raise CaptureError(f"{existing[0]} exists: a recording is never overwritten")
    return [share_recording(s, t, rules) for s, t in targets], corpus
