"""Reading walkcap recordings in Python: metadata, topics decoded into numpy and dicts.

    with open_recording("S01_indoor_t01.mcap") as rec:
        rec.meta.session.subject                 # typed metadata (capture.recording.metadata)
        for m in rec.messages(["/camera/cloud"], start=t0_ns, end=t1_ns):  # (N, 3) float32
            ...
    table, changes = frame_table(rec)            # every per-frame topic joined by frame
    for frame in depth_frames(path):             # DepthFrame with xyz rebuilt exactly
        ...

Finished files are read through their index: a window of time reads only the chunks
that overlap it. Unfinished ones (a crash, a full disk) are
read record by record up to where they stop (capture.recording.messages), so everything
that reached the disk is readable without `walkcap recover`.
Messages are decoded with the schema stored in the file (protobuf descriptors, JSON).
Metadata comes back typed (JSON values). Files of an older format version are read as
this version holds them (capture.recording.versions), newer ones refused.
Times are session-clock nanoseconds; `Recording.unix_time_ns` and
`RecordedMessage.unix_time_ns` give the same instants as Unix time. The operator's labels
are read with their undos applied (capture.recording.labels); the file keeps both.
"""

from __future__ import annotations

import functools
import io
import os
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from capture.errors import CaptureError
from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording import versions
from capture.recording._mcap import (
    MAGIC,
    Damage,
    ScanResult,
    check_magic,
    digest_damage,
    file_bytes,
    scan,
    summary_damage,
)
from capture.recording.chunk_digests import CHUNK_DIGESTS
from capture.recording.digests import DIGESTS
from capture.recording.frames import FrameJoin, FrameTable
from capture.recording.messages import (
    Decoders,
    damage_is_an_error,
    iter_indexed,
    iter_raw,
    log_times,
)
from capture.recording.metadata import Metadata
from devices import clock
from devices.frames import CameraGeometry, DepthFrame, ImuSample


@dataclass
class RecordedMessage:
    topic: str
    log_time_ns: int  # host receive time, session clock
    publish_time_ns: int  # sample time, session clock
    sequence: int  # frame index for camera topics, packet counter for /imu
    data: Any  # numpy array (images, clouds, quaternions) or dict (JSON topics)
    unix_offset_ns: int | None = None  # the recording's session clock -> Unix time

    @property
    def unix_time_ns(self) -> int | None:
        """The sample time (publish time) as Unix time, ns; None if the file has no offset."""
        return None if self.unix_offset_ns is None else self.publish_time_ns + self.unix_offset_ns


@dataclass
class TopicInfo:
    topic: str
    count: int
    schema_name: str
    message_encoding: str
    description: str = ""


@dataclass
class Recording:
    path: Path
    complete: bool  # finished by the writer (summary and index present)
    reason: str  # why an unfinished file stops where it does
    size: int
    library: str
    metadata: dict[str, dict[str, Any]]  # the last record of each name, values typed
    metadata_records: list[tuple[str, dict[str, Any]]]  # all, in file order, typed
    attachments: dict[str, bytes]  # the last attachment of each name
    attachment_sizes: dict[str, int]
    topics: dict[str, TopicInfo]
    start_ns: int | None  # first and last log time of any message
    end_ns: int | None
    _log_times: dict[str, np.ndarray] | None = field(default=None, repr=False)
    raw_metadata_records: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    # Damaged regions found while opening an unfinished file (a finished one is read
    # through its index: `capture.recording.checking.check` reads and checks every chunk).
    damaged: list[Damage] = field(default_factory=list)
    format_version: str = T.FORMAT_VERSION  # the file's (capture.recording.versions)
    # a finished file's summary (channels, chunk index), read once when opened
    _summary: Any = field(default=None, repr=False)
    _file: Any = field(default=None, repr=False)  # open while in a `with` block

    def __enter__(self) -> Recording:
        if self._file is None and self.complete:
            self._file = open(self.path, "rb")  # noqa: SIM115 (closed by __exit__)
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the file a `with` block holds open (reading again reopens it)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    @functools.cached_property
    def meta(self) -> Metadata:
        """The metadata records typed (capture.recording.metadata): the last of each name."""
        return Metadata.from_dict(self.metadata)

    @property
    def duration_s(self) -> float:
        return 0.0 if self.start_ns is None else clock.seconds(self.end_ns - self.start_ns)

    @property
    def unix_offset_ns(self) -> int | None:
        """Add to a session-clock time (any log or publish time) for Unix time in ns."""
        return self.meta.recording.unix_offset

    def unix_time_ns(self, session_ns):
        """Session-clock time(s) as Unix time in ns (None when the file has no offset)."""
        offset = self.unix_offset_ns
        if offset is None or session_ns is None:
            return None
        if isinstance(session_ns, np.ndarray):
            return session_ns.astype(np.int64) + offset
        return int(session_ns) + offset

    @property
    def id(self) -> str:
        """The recording's unique id; files without one get a stand-in from their name."""
        meta = self.meta
        return str(meta.derivation.id or meta.recording.id or f"file:{self.path.name}")

    @property
    def trial(self) -> tuple[str, str, int | None]:
        """(subject, condition, trial) from the session metadata."""
        session = self.meta.session
        return str(session.subject or ""), str(session.condition or ""), session.trial_number

    def messages(
        self,
        topics: Iterable[str] | str | None = None,
        *,
        start: int | None = None,
        end: int | None = None,
        raw: bool = False,
    ) -> Iterator[RecordedMessage]:
        """Messages of `topics` (a topic, several, or None: all) in file order (which is
        time order per topic), decoded with the file's schemas. `start` / `end`: only the
        messages logged in [start, end), session-clock ns; a finished file reads only the
        chunks of its index that hold a wanted topic in that window. `raw=True` gives the
        protobuf objects and JSON dicts as stored (without conversion, and an older format
        version's messages not upgraded)."""
        if isinstance(topics, str):
            topics = [topics]
        wanted = None if topics is None else set(topics)
        decode = self.decoder(raw=raw)
        with damage_is_an_error(self.path):
            for schema, channel, message in self._raw(wanted, start, end):
                yield decode(schema, channel, message)

    def stored(self, topics: Iterable[str]) -> Iterator[tuple[RecordedMessage, bytes]]:
        """messages(topics), each with its bytes as stored in the file: what a copy writes
        as it is, without encoding it again."""
        decode = self.decoder()
        with damage_is_an_error(self.path):
            for schema, channel, message in self._raw(set(topics), None, None):
                yield decode(schema, channel, message), message.data

    def _raw(self, wanted: set[str] | None, start: int | None, end: int | None):
        """(schema, channel, message) through the file a `with` block holds open, or the
        file opened again for this read."""
        if self._file is not None and self._summary is not None:
            # one chunk read whole at a time: reads may interleave on the one handle
            yield from iter_indexed(self._file, wanted, start, end, self._summary)
            return
        yield from iter_raw(
            self.path, self.complete, wanted, start=start, end=end, summary=self._summary
        )

    def decoder(self, *, raw: bool = False) -> Callable[[Any, Any, Any], RecordedMessage]:
        """decode(schema, channel, message) -> RecordedMessage, as `messages` decodes: for
        readers that walk the records themselves (capture.recording.summary)."""
        decoders = Decoders()
        offset = self.unix_offset_ns
        upgrade = versions.needs_upgrade(self.format_version)
        orientation = versions.orientation_upgrade(
            self.format_version, self.meta.software.preprocess
        )

        def decode(schema, channel, message) -> RecordedMessage:
            decoded = decoders.decode(schema, channel, message.data)
            if not raw:
                decoded = convert(channel.topic, decoded)
                if upgrade:
                    decoded = versions.upgrade_message(channel.topic, decoded)
                if orientation is not None and channel.topic == T.TF:
                    decoded = orientation(decoded)
            return RecordedMessage(
                channel.topic,
                message.log_time,
                message.publish_time,
                message.sequence,
                decoded,
                offset,
            )

        return decode

    def read(self, topic: str, *, raw: bool = False) -> list[RecordedMessage]:
        return list(self.messages([topic], raw=raw))

    def sequences(self, topic: str) -> list[tuple[int, int, int]]:
        """(sequence, publish time, log time) of every message on `topic`, in log-time
        order, without decoding them: a sensor's own count and clock beside the host's."""
        with damage_is_an_error(self.path):
            items = [
                (m.sequence, m.publish_time, m.log_time)
                for _, _, m in self._raw({topic}, None, None)
            ]
        return sorted(items, key=lambda x: x[2])

    def log_times(self) -> dict[str, np.ndarray]:
        """Sorted log times of every topic, from the index when there is one (no decoding)."""
        if self._log_times is None:
            with damage_is_an_error(self.path):
                self._log_times = log_times(self.path, self.complete)
        return self._log_times

    def rays(self) -> np.ndarray:
        """The camera's unit ray per pixel (H, W, 3) float32, as recorded."""
        data = self.attachments.get(T.RAYS_ATTACHMENT)
        if data is None:
            raise CaptureError(f"{self.path}: no {T.RAYS_ATTACHMENT} (no depth frames recorded)")
        return np.load(io.BytesIO(data))

    def geometry(self) -> CameraGeometry:
        return self.meta.camera.geometry()


_BOOKKEEPING = (DIGESTS, CHUNK_DIGESTS)  # records about the file's own bytes, not its data


def convert(topic: str, decoded: Any) -> Any:
    """A decoded message as walkcap data: images as arrays, clouds (N, 3), quaternions."""
    if topic in (T.DEPTH, T.CONFIDENCE, T.GRAY, T.BINARY_IMAGE):
        return T.image_from_message(decoded)
    if topic == T.CLOUD:
        return T.cloud_from_message(decoded)
    if topic == T.TF:
        return T.quaternion_from_transform(decoded)
    return decoded


def open_recording(path: str | os.PathLike) -> Recording:
    """Open a recording: metadata, attachments and topic counts, finished or not.
    Raises CaptureError (one line) for a missing file or one that is not MCAP.

        with open_recording(path) as rec:      # the file held open, its index read once
            for m in rec.messages("/imu", start=t0_ns, end=t1_ns):
                ...
    """

    p = Path(path)
    if not p.exists():
        raise CaptureError(f"{p}: no such file")
    check_magic(p)
    with damage_is_an_error(p):
        return _open(p)


def _open(p: Path) -> Recording:
    from mcap.reader import make_reader

    size = p.stat().st_size
    with open(p, "rb") as f:
        try:
            reader = make_reader(f)
            summary = None if summary_damage(file_bytes(f)) else reader.get_summary()
        except Exception:  # no footer, cut-off summary: read it record by record
            summary = None
        if summary is not None and summary.statistics is not None:
            every = list(reader.iter_metadata())
            raw = [(m.name, dict(m.metadata)) for m in every if m.name not in _BOOKKEEPING]
            version, records = versions.read_metadata(raw, p)
            damaged = summary_digest_damage(reader.get_header(), every, summary, file_bytes(f))
            attachments = {a.name: a.data for a in reader.iter_attachments()}
            sizes = {a.name: a.data_size for a in summary.attachment_indexes}
            stats = summary.statistics
            topics = {}
            for cid, channel in summary.channels.items():
                schema = summary.schemas.get(channel.schema_id)
                topics[channel.topic] = TopicInfo(
                    channel.topic,
                    stats.channel_message_counts.get(cid, 0),
                    schema.name if schema else "",
                    channel.message_encoding,
                    channel.metadata.get("description", ""),
                )
            library = reader.get_header().library
            start = stats.message_start_time if stats.message_count else None
            end = stats.message_end_time if stats.message_count else None
            return Recording(
                p,
                True,
                "",
                size,
                library,
                dict(records),
                records,
                attachments,
                sizes,
                topics,
                start,
                end,
                raw_metadata_records=raw,
                damaged=damaged,
                format_version=version,
                _summary=summary,
            )
    return _open_unfinished(p, size)


def summary_digest_damage(header, metadata: list, summary, data) -> list[Damage]:
    """The header, metadata (every record, digests included, in file order) and the
    summary's schemas and channels checked against their digests, each failure by name.
    Offsets where the summary says (metadata), else 0."""
    indexes = summary.metadata_indexes
    if len(indexes) != len(metadata):
        indexes = [None] * len(metadata)
    (head_length,) = struct.unpack_from("<Q", data, len(MAGIC) + 1)
    head_end = min(len(data), len(MAGIC) + 9 + head_length)
    checked = [(header, len(MAGIC), 0, bytes(data[len(MAGIC) : head_end]))]
    checked += [
        (m, i.offset, i.length, bytes(data[i.offset : i.offset + i.length]))
        if i is not None
        else (m, 0, 0, None)
        for m, i in zip(metadata, indexes, strict=True)
    ]
    checked += [(s, 0, 0, None) for s in summary.schemas.values()]
    checked += [(c, 0, 0, None) for c in summary.channels.values()]
    return digest_damage(checked, finished=True)


def _open_unfinished(p: Path, size: int) -> Recording:
    from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema

    result = ScanResult()
    schemas, channels = {}, {}
    raw, attachments = [], {}
    counts: dict[int, int] = {}
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    library = ""
    with open(p, "rb") as f:
        for record in scan(f, result):
            if isinstance(record, Message):
                cid, t = record.channel_id, record.log_time
                counts[cid] = counts.get(cid, 0) + 1
                first[cid] = min(first.get(cid, t), t)
                last[cid] = max(last.get(cid, t), t)
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Metadata) and record.name not in _BOOKKEEPING:
                raw.append((record.name, dict(record.metadata)))
            elif isinstance(record, Attachment):
                attachments[record.name] = record.data
            elif isinstance(record, Header):
                library = record.library
    if result.records == 0 and result.reason.startswith(("unreadable", "damaged")):
        raise CaptureError(f"{p}: no MCAP record can be read after the magic ({result.reason})")
    topics = {}
    for cid, channel in channels.items():
        schema = schemas.get(channel.schema_id)
        topics[channel.topic] = TopicInfo(
            channel.topic,
            counts.get(cid, 0),
            schema.name if schema else "",
            channel.message_encoding,
            channel.metadata.get("description", ""),
        )
    every = [t[cid] for t in (first, last) for cid in channels if cid in t]
    version, records = versions.read_metadata(raw, p)
    return Recording(
        p,
        False,
        result.reason or "no summary",
        size,
        library,
        dict(records),
        records,
        attachments,
        {k: len(v) for k, v in attachments.items()},
        topics,
        min(every) if every else None,
        max(every) if every else None,
        None,
        raw,
        result.damaged,
        version,
    )


# ---- analysis helpers -------------------------------------------------------------------


def imu_sample(d: dict) -> ImuSample:
    """An /imu message, decoded, as the ImuSample the driver delivered."""

    def arr(key):
        v = d.get(key)
        return None if v is None else np.asarray(v, dtype=np.float64)

    return ImuSample(
        host_time_ns=int(d["host_time_ns"]),
        time_ns=d.get("time_ns"),
        packet_counter=d.get("packet_counter"),
        sample_time_fine=d.get("sample_time_fine"),
        quaternion=arr("quaternion"),
        acceleration=arr("acceleration"),
        rate_of_turn=arr("rate_of_turn"),
        status_word=d.get("status_word"),
        extra=d.get("extra") or {},
    )


def frame_table(
    rec: Recording,
    other_topics: Iterable[str] = (),
    take: Callable[[RecordedMessage], None] | None = None,
    *,
    frame_topics: Iterable[str] = FrameJoin.TOPICS,
    keep_features: bool = True,
) -> tuple[FrameTable, list[L.LabelChange]]:
    """The recording's per-frame table (capture.recording.frames) and its label changes in
    time order, in one pass over the file; `take` gets the messages of `other_topics`
    read in the same pass. `frame_topics`: the per-frame topics joined (default: all);
    `keep_features` False: the terrain features' cues alone (FrameTable.geometry,
    ground_ahead), for a reader that needs no more of them (a few hundred bytes a frame)."""
    # the columns sized once from the summary's counts (a damaged file's: grown as read)
    counts = [rec.topics[t].count for t in (T.CNN, T.PREPROCESS) if t in rec.topics]
    join = FrameJoin(capacity=max(counts, default=0) + 1, keep_features=keep_features)
    changes: list[L.LabelChange] = []
    others = set(other_topics)
    wanted = [t for t in (*frame_topics, T.LABELS, *others) if t in rec.topics]
    for m in rec.messages(wanted):
        if join.add(m):
            continue
        if m.topic == T.LABELS:
            changes.append(L.change_from_message(m.data))
        if m.topic in others and take is not None:
            take(m)
    changes = L.in_time_order(changes)
    return join.table(changes, has_truth=T.TRUTH in rec.topics), changes


_TRUTH_WAIT_FRAMES = 64  # frames held back waiting for their truth, at most


def depth_frames(path: str | os.PathLike) -> Iterator[DepthFrame]:
    """The recorded depth frames with xyz rebuilt from range and rays (within 0.5 mm along
    each ray), confidence as recorded, gray if recorded (else zeros), truth if present.
    device_time_ns is the recorded sample time (publish time)."""
    rec = open_recording(path)
    if T.DEPTH not in rec.topics:
        return
    frames = FrameAssembler(rec)
    for m in rec.messages(frames.topics):
        for entry in frames.add(m):
            yield frames.frame(entry)
    for entry in frames.rest():
        yield frames.frame(entry)


class FrameAssembler:
    """A recording's depth frames put together from their messages (depth, confidence,
    gray, truth) in one pass in file order: `add` each message of `topics`, and take the
    frames it completes, in frame order; `rest` at the end. A frame's truth is written
    next to its depth; a frame goes out once its truth is read, or once a later frame's
    truth shows that it has none. Entries hold the messages; `frame` makes the DepthFrame
    (xyz from range), so that a reader holding frames back holds millimetres only."""

    def __init__(self, rec: Recording, *, gray: bool = True, points: bool = True) -> None:
        """points False: frames without their points (xyz empty), for a reader that works
        from the ranges and `rays` (inference.preprocess.preprocess_ranges)."""
        self.points = points
        self.rays = rec.rays()
        self.geometry = rec.geometry()
        self.parts = (T.DEPTH, T.CONFIDENCE) + ((T.GRAY,) if gray and T.GRAY in rec.topics else ())
        self.with_truth = T.TRUTH in rec.topics
        self.topics = self.parts + ((T.TRUTH,) if self.with_truth else ())
        self._pending: dict[int, dict] = {}  # frames still missing a part
        self._whole: dict[int, dict] = {}  # frames waiting for their truth
        self._truth: dict[int, dict] = {}
        self._last_truth = -1

    def add(self, m: RecordedMessage) -> list[dict]:
        """The entries (index, log and publish time, each part's data, truth) of the frames
        that `m` completes, in frame order."""
        if m.topic == T.TRUTH:
            t = dict(m.data)
            index = int(t.pop("frame_index"))
            self._truth[index] = t
            self._last_truth = max(self._last_truth, index)
        else:
            entry = self._pending.setdefault(
                m.sequence, {"index": m.sequence, "log": m.log_time_ns, "pub": m.publish_time_ns}
            )
            entry[m.topic] = m.data
            if all(p in entry for p in self.parts):
                self._whole[m.sequence] = self._pending.pop(m.sequence)
        whole, truth = self._whole, self._truth
        ready = [i for i in whole if not self.with_truth or i in truth or i < self._last_truth]
        if len(whole) > _TRUTH_WAIT_FRAMES:  # the truth stopped: wait no longer
            ready = list(whole)
        out = []
        for index in sorted(ready):
            entry = whole.pop(index)
            entry["truth"] = truth.pop(index, None)
            out.append(entry)
        return out

    def rest(self) -> list[dict]:
        """The frames still held at the end (a cut file: best effort), in frame order."""
        out = []
        for index, entry in sorted({**self._whole, **self._pending}.items()):
            if T.DEPTH in entry:
                entry["truth"] = self._truth.get(index)
                out.append(entry)
        self._whole, self._pending = {}, {}
        return out

    def frame(self, entry: dict) -> DepthFrame:
        rays = self.rays if self.points else None
        return _frame(entry["index"], entry, rays, self.geometry, entry["truth"])


def _frame(
    index: int, entry: dict, rays: np.ndarray | None, geometry: CameraGeometry, truth: dict | None
) -> DepthFrame:
    """The entry's DepthFrame; rays None: without its points."""
    depth = entry[T.DEPTH]
    confidence = entry.get(T.CONFIDENCE)
    if confidence is None:
        confidence = np.where(depth > 0, 255, 0).astype(np.uint8)
    gray = entry.get(T.GRAY)
    if gray is None:
        gray = np.zeros(depth.shape, np.uint16)
    if truth is not None:
        truth = {k: v for k, v in truth.items() if k != "time_ns"}
    return DepthFrame(
        index=index,
        device_time_ns=entry["pub"],
        host_time_ns=entry["log"],
        xyz=T.xyz_from_range(depth, rays) if rays is not None else np.zeros((0, 0, 3), np.float32),
        confidence=confidence,
        gray=gray,
        geometry=geometry,
        truth=truth,
        range_mm=depth,
    )
