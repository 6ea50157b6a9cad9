"""The recording's metadata records, one typed record per name, and their one builder each.

A walkcap file holds these MCAP metadata records (values as JSON, capture.recording.topics):

    session     the session form and operator (capture.live.trials)
    devices     what was configured, and what the devices say (`devices_record`)
    software    which walkcap, model, fusion and preprocessing made the decisions
    camera      the camera geometry the depth frames' rays come from (the writer, per camera)
    recording   the file's identity, clock, format version (the writer)
    derivation  what a replay, corrected, recovered or shared copy was made from
    sharing     what a copy made for sharing lacks (capture.corpus.share)

Each is a frozen dataclass with `from_dict` (a record as read, old files' too) and
`to_dict` (the record as written). `to_dict(from_dict(d)) == d`, key order included: keys a
record does not name (an older or newer walkcap's, a backend's extras) are kept in `extra`
and written back where they stood, and a key the file lacks stays out. Values are as the
file holds them (JSON types; version 1 files typed by capture.recording.versions).
`Metadata` holds a file's records (`Recording.meta`); code outside capture/recording reads
metadata through these records' attributes only.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from devices.frames import CameraGeometry

_HIDDEN = ("extra", "keys")


@dataclass(frozen=True)
class MetadataRecord:
    """What every metadata record shares: its name, the keys it does not name, key order."""

    NAME: ClassVar[str] = ""

    # keys this record does not name, as read (written back where they stood)
    extra: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)
    # the record's keys in the order the file holds them (or the builder gave them)
    keys: tuple[str, ...] = field(default=(), repr=False, compare=False)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls) if f.name not in _HIDDEN)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None):
        """The record as read; None or a non-mapping (a damaged record): an empty one."""
        values = values if isinstance(values, Mapping) else {}
        named = set(cls.names())
        return cls(
            **{k: v for k, v in values.items() if k in named},
            extra={k: v for k, v in values.items() if k not in named},
            keys=tuple(str(k) for k in values),
        )

    @classmethod
    def build(cls, **values):
        """A new record, its keys in the order given (what the writers call)."""
        return cls.from_dict(values)

    def replaced(self, **values):
        """The record with `values` set: a key it holds keeps its place, a new one is
        added at the end."""
        return self.from_dict({**self.to_dict(), **values})

    def to_dict(self) -> dict[str, Any]:
        """The record's values as written, in its key order."""
        named = set(self.names())
        return {k: getattr(self, k) if k in named else self.extra[k] for k in self.keys}

    def value(self, key: str) -> Any:
        """A value by its name, for tables of columns named after the record's fields (the
        export's, BIDS's); None where the file has none."""
        return getattr(self, key) if key in self.names() else self.extra.get(key)

    def has(self, key: str) -> bool:
        """Whether the file holds this key (a value of None may still be held)."""
        return key in self.keys

    def __bool__(self) -> bool:
        return bool(self.keys)


def _int(value) -> int | None:
    try:
        return int(value) if value not in (None, "") else None
    except (TypeError, ValueError):
        return None


def _float(value) -> float | None:
    try:
        return float(value) if value not in (None, "") else None
    except (TypeError, ValueError):
        return None


@dataclass(frozen=True)
class SessionRecord(MetadataRecord):
    """The session form (capture.live.trials.SubjectInfo), its operator, and the earlier
    files of the same trial it supersedes."""

    NAME: ClassVar[str] = "session"

    subject: str | None = None
    height_m: float | None = None
    weight_kg: float | None = None
    age: int | None = None
    sex: str | None = None
    amputee: bool | None = None
    side: str | None = None
    residual_limb_cm: float | None = None
    condition: str | None = None
    trial: int | None = None
    notes: str | None = None
    operator: str | None = None
    supersedes: list[str] | None = None

    @property
    def trial_number(self) -> int | None:
        """The trial as a number (None: not given or not a number)."""
        return _int(self.trial)


@dataclass(frozen=True)
class DevicesRecord(MetadataRecord):
    """What was configured, and what the devices said about themselves (`devices_record`)."""

    NAME: ClassVar[str] = "devices"

    camera_backend: str | None = None
    camera_fps: float | None = None
    camera_use_case: str | None = None
    camera_details: dict | None = None
    imu_backend: str | None = None
    imu_port: str | None = None
    imu_rate_hz: float | None = None
    imu_info: dict | None = None
    imu_details: dict | None = None
    simulator: dict | None = None

    @property
    def rates_hz(self) -> dict[str, float]:
        """The configured rate of each sensor stream ("camera", "imu") given as a number
        above 0."""
        rates = {"camera": _float(self.camera_fps), "imu": _float(self.imu_rate_hz)}
        return {k: v for k, v in rates.items() if v is not None and v > 0}


def devices_record(
    config,
    *,
    camera_details: dict | None = None,
    imu_info: dict | None = None,
    imu_details: dict | None = None,
    simulated: bool = False,
) -> DevicesRecord:
    """The "devices" record from the configuration (capture.config.Config) and what the
    devices said. `simulated`: a session rendered by the simulator with synthetic IMU
    samples (capture.corpus.synth), no device opened."""
    from capture.recording.topics import jsonable

    if simulated:
        return DevicesRecord.build(
            camera_backend="mock",
            camera_fps=config.camera.fps,
            imu_backend="synthetic",
            imu_rate_hz=config.imu.rate_hz,
            simulator=jsonable(dataclasses.asdict(config.simulator)),
        )
    values = dict(
        camera_backend=config.camera.backend,
        camera_fps=config.camera.fps,
        camera_use_case=config.camera.use_case,
        camera_details=jsonable(camera_details or {}),
        imu_backend=config.imu.backend,
        imu_port=config.imu.port,
        imu_rate_hz=config.imu.rate_hz,
        imu_info=jsonable(imu_info or {}),
        imu_details=jsonable(imu_details or {}),
    )
    if config.camera.backend == "mock":
        values["simulator"] = jsonable(dataclasses.asdict(config.simulator))
    return DevicesRecord.build(**values)


@dataclass(frozen=True)
class SoftwareRecord(MetadataRecord):
    """Which walkcap, model, fusion and preprocessing made the recording's decisions
    (capture.live.pipeline.software_metadata); a replay adds what it replays."""

    NAME: ClassVar[str] = "software"

    walkcap_version: str | None = None
    model_path: str | None = None
    model_hash: str | None = None
    fusion_method: str | None = None
    fusion_window: int | None = None
    fusion_vote_delay: int | None = None
    fusion_transition: Any = None
    preprocess: dict | None = None
    replay_of: str | None = None


@dataclass(frozen=True)
class CameraRecord(MetadataRecord):
    """The camera geometry (devices.frames.CameraGeometry) from a frame on, and the
    attachment holding its rays."""

    NAME: ClassVar[str] = "camera"

    width: int | None = None
    height: int | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    min_range_m: float | None = None
    max_range_m: float | None = None
    name: str | None = None
    serial: str | None = None
    rays_attachment: str | None = None
    from_frame_index: int | None = None

    @classmethod
    def of(cls, geometry: CameraGeometry, rays_attachment: str, frame_index: int):
        return cls.build(
            **dataclasses.asdict(geometry),
            rays_attachment=rays_attachment,
            from_frame_index=frame_index,
        )

    def geometry(self) -> CameraGeometry:
        """The geometry recorded (defaults for what the file lacks)."""
        default = CameraGeometry()
        kwargs = {}
        for f in dataclasses.fields(CameraGeometry):
            if self.has(f.name):
                kwargs[f.name] = type(getattr(default, f.name))(getattr(self, f.name))
        return CameraGeometry(**kwargs)


@dataclass(frozen=True)
class RecordingRecord(MetadataRecord):
    """The file's identity, clock and format (capture.recording.writer)."""

    NAME: ClassVar[str] = "recording"

    id: str | None = None
    metadata_values: str | None = None
    format_version: str | None = None
    writer: str | None = None
    clock: str | None = None
    unix_offset_ns: int | None = None
    chunk_interval_s: float | None = None
    depth: str | None = None
    cloud_quantum_m: float | None = None
    cloud_max_points: int | None = None
    cloud_voxel_m: float | None = None
    journal: str | None = None
    topics: dict | None = None

    @property
    def unix_offset(self) -> int | None:
        """unix_offset_ns as a number (None: the file has none)."""
        return _int(self.unix_offset_ns)


@dataclass(frozen=True)
class DerivationRecord(MetadataRecord):
    """What a derived file (replay, corrected, recovered, shared) was made from
    (capture.recording.lineage.derivation)."""

    NAME: ClassVar[str] = "derivation"

    id: str | None = None
    kind: str | None = None
    source_id: str | None = None
    source_name: str | None = None
    how: str | None = None
    subject: str | None = None
    condition: str | None = None
    trial: int | None = None
    model_hash: str | None = None
    model_path: str | None = None
    source_kind: str | None = None


@dataclass(frozen=True)
class SharingRecord(MetadataRecord):
    """What a copy made for sharing lacks (capture.corpus.share)."""

    NAME: ClassVar[str] = "sharing"

    rules: dict | None = None
    removed: list[str] | None = None
    source_id: str | None = None
    unchanged: str | None = None


RECORDS: tuple[type[MetadataRecord], ...] = (
    SessionRecord,
    DevicesRecord,
    SoftwareRecord,
    CameraRecord,
    RecordingRecord,
    DerivationRecord,
    SharingRecord,
)


@dataclass(frozen=True)
class Metadata:
    """A file's metadata records, typed: the last record of each name (an empty record
    where the file has none)."""

    session: SessionRecord = field(default_factory=SessionRecord)
    devices: DevicesRecord = field(default_factory=DevicesRecord)
    software: SoftwareRecord = field(default_factory=SoftwareRecord)
    camera: CameraRecord = field(default_factory=CameraRecord)
    recording: RecordingRecord = field(default_factory=RecordingRecord)
    derivation: DerivationRecord = field(default_factory=DerivationRecord)
    sharing: SharingRecord = field(default_factory=SharingRecord)

    @classmethod
    def from_dict(cls, records: Mapping[str, Mapping[str, Any]]) -> Metadata:
        """From the records by name (typed values, as `Recording.metadata` holds them)."""
        return cls(**{r.NAME: r.from_dict(records.get(r.NAME)) for r in RECORDS})

    def records(self) -> list[MetadataRecord]:
        return [getattr(self, r.NAME) for r in RECORDS]


def as_dicts(*records: MetadataRecord) -> dict[str, dict[str, Any]]:
    """Records by name as the Recorder takes them ({name: values})."""
    return {r.NAME: r.to_dict() for r in records}
