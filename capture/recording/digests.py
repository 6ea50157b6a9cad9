"""Record digests: the check MCAP leaves out of header, metadata, schema and channel records.

MCAP's CRCs cover chunks, attachments and the summary, not a record's own bytes elsewhere:
one bit flipped in the session's metadata (subject `S77` read back as `S76`) would pass
every reader. So the writer puts a digest of each such record into a metadata record of
its own, `record_digests` (format version 3 on), written before the record reaches the
file (the header's just after it): a crash can cut a record off, never leave one without
its digest. Each digest record is a map from the record's key to the CRC-32 of the
record's bytes as MCAP writes them (opcode, length, body; eight hex digits), and checks
itself: `crc32`, over its other keys canonically encoded.

Keys name the record: `header`; `metadata <name>` (`metadata <name> #2` for a name's
second record); `schema <id>`; `channel <id>`. A reader gathers the records and the digest
maps it finds, in whatever way it reads the file (record by record, or through the
summary), and hands both to `check_records`, which names every record that does not match
its digest, has none, or (in a finished file) is missing.
"""

from __future__ import annotations

import collections
import json
import zlib
from collections.abc import Iterable
from dataclasses import dataclass

from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Header, McapRecord, Metadata, Schema

DIGESTS = "record_digests"  # the metadata record that holds them
SELF_CHECK = "crc32"
FIRST_VERSION = 3  # the format version that writes them (capture.recording.versions)


def record_bytes(record: McapRecord) -> bytes:
    """A record's bytes as MCAP writes them: the same for a chunk's copy and the summary's."""
    builder = RecordBuilder()
    record.write(builder)
    return bytes(builder.end())


def _crc(data: bytes) -> str:
    return f"{zlib.crc32(data):08x}"


def _self_check(values: dict[str, str]) -> str:
    rest = {k: v for k, v in values.items() if k != SELF_CHECK}
    return _crc(json.dumps(rest, sort_keys=True, separators=(",", ":")).encode())


class Keys:
    """The key of each record in the order a file holds them (counts metadata names)."""

    def __init__(self) -> None:
        self._names: collections.Counter = collections.Counter()

    def key(self, record: McapRecord) -> str | None:
        """None for a record no digest covers (messages, chunks, the digests themselves)."""
        if isinstance(record, Header):
            return "header"
        if isinstance(record, Metadata):
            if record.name == DIGESTS:
                return None
            self._names[record.name] += 1
            n = self._names[record.name]
            return f"metadata {record.name}" + (f" #{n}" if n > 1 else "")
        if isinstance(record, Schema):
            return f"schema {record.id}"
        if isinstance(record, Channel):
            return f"channel {record.id}"
        return None


def seal(records: Iterable[tuple[str, bytes]]) -> dict[str, str]:
    """The digest record's values for (key, record bytes) pairs."""
    values = {key: _crc(data) for key, data in records}
    values[SELF_CHECK] = _self_check(values)
    return values


class Sealer:
    """Digests written beside an mcap Writer's header, metadata, schema and channel records
    (the recorder's ChunkWriter and RecordingCopy alike)."""

    def __init__(self, writer) -> None:
        self._writer = writer
        self._keys = Keys()

    def start(self, profile: str, library: str, metadata: Iterable[tuple[str, dict]] = ()):
        """The header, then one digest record for it and the `metadata` records that follow."""
        self._writer.start(profile=profile, library=library)
        records = [Metadata(name, values) for name, values in metadata]
        self._write([Header(profile, library), *records])
        for record in records:
            self._writer.add_metadata(record.name, record.metadata)

    def metadata(self, name: str, values: dict[str, str]) -> None:
        record = Metadata(name, values)
        self._write([record])
        self._writer.add_metadata(name, values)

    def schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = self._writer.register_schema(name, encoding, data)
        self._write([Schema(sid, data, encoding, name)])
        return sid

    def channel(self, topic: str, encoding: str, schema_id: int, metadata: dict) -> int:
        cid = self._writer.register_channel(topic, encoding, schema_id, metadata)
        self._write([Channel(cid, topic, encoding, dict(metadata), schema_id)])
        return cid

    def _write(self, records: list[McapRecord]) -> None:
        pairs = [(self._keys.key(r), record_bytes(r)) for r in records]
        # a schema or channel is in its chunk only when the chunk is written: this first
        self._writer.add_metadata(DIGESTS, seal((k, b) for k, b in pairs if k is not None))


@dataclass
class RecordDamage:
    key: str  # "metadata session", "channel 5", ...
    why: str
    offset: int = 0  # where the record is, when the reader knows (else 0, 0)
    length: int = 0

    def describe(self) -> str:
        return f"{self.key} {self.why}"


def check_records(
    records: Iterable[tuple[str, bytes]],
    stored: Iterable[dict[str, str]],
    *,
    required: bool,
    finished: bool,
) -> list[RecordDamage]:
    """Every record (key, bytes) that its digest does not prove, by key.

    `stored`: the values of every `record_digests` record found. `required`: the file
    carries digests (format version 3 on, or any digest record found): then a record
    without one is damage. `finished`: the file ends with its footer: a header or metadata
    record that a digest names and the file lacks is damage too (in a file cut off by a
    crash it may simply not have been written; a schema or channel lives in a chunk, whose
    loss is reported as the chunk's)."""
    problems: list[RecordDamage] = []
    known: dict[str, str] = {}
    for n, values in enumerate(stored, 1):
        if values.get(SELF_CHECK) != _self_check(values):
            why = "fails its own CRC: the records it names are unchecked"
            problems.append(RecordDamage(f"{DIGESTS} #{n}", why))
            continue
        known.update({k: v for k, v in values.items() if k != SELF_CHECK})
    seen = set()
    for key, data in records:
        seen.add(key)
        want = known.get(key)
        if want is None:
            if required:
                problems.append(RecordDamage(key, "has no digest (its name or its digest damaged)"))
        elif want != _crc(data):
            problems.append(RecordDamage(key, "fails its digest: damaged, read as it is"))
    if finished:
        for key in known:
            if key not in seen and key.startswith(("header", "metadata ")):
                why = "is missing: a digest names it, the file has none"
                problems.append(RecordDamage(key, why))
    return problems


def record_damage(
    records: Iterable[McapRecord],
    *,
    required: bool,
    finished: bool,
    raw: Iterable[bytes | None] | None = None,
) -> list[RecordDamage]:
    """check_records on parsed mcap records in file order (the digest records among them).
    `raw`: each record's bytes as the file holds them, where the reader has them (None:
    written again from the parsed record); a parser may read past a damaged length that
    writing the record again would hide."""
    keys, pairs, stored, odd = Keys(), [], [], []
    records = list(records)
    raws = list(raw) if raw is not None else [None] * len(records)
    for record, data in zip(records, raws, strict=True):
        if isinstance(record, Metadata) and record.name == DIGESTS:
            if data is not None and bytes(data) != record_bytes(record):
                # a length the parser read past: its values may read right, its bytes do not
                why = "is damaged: its bytes are not what its values write"
                odd.append(RecordDamage(f"{DIGESTS} #{len(stored) + 1}", why))
            stored.append(dict(record.metadata))
            continue
        key = keys.key(record)
        if key is not None:
            pairs.append((key, bytes(data) if data is not None else record_bytes(record)))
    return odd + check_records(pairs, stored, required=required or bool(stored), finished=finished)


def carries_digests(records: Iterable[McapRecord]) -> bool:
    """Whether a file's "recording" metadata names format version 3 or later (the versions
    that write digests): then a record without one is damage."""
    version = 0
    for record in records:
        if isinstance(record, Metadata) and record.name == "recording":
            try:
                version = int(json.loads(record.metadata.get("format_version", "0")))
            except (ValueError, TypeError):
                version = 0
    return version >= FIRST_VERSION


def located_damage(checked: Iterable[tuple], *, finished: bool) -> list[RecordDamage]:
    """record_damage on (record, offset, length, raw bytes or None) in file order, each
    finding placed at its record (the first of its key)."""
    checked = list(checked)
    where: dict[str, tuple[int, int]] = {}
    keys = Keys()
    for record, offset, length, _ in checked:
        key = keys.key(record)
        if key is not None:
            where.setdefault(key, (offset, length))
    records = [c[0] for c in checked]
    problems = record_damage(
        records, required=carries_digests(records), finished=finished, raw=[c[3] for c in checked]
    )
    for p in problems:
        p.offset, p.length = where.get(p.key, (0, 0))
    return problems
