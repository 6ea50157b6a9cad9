"""The recording's topics: names, schemas, and pure functions between walkcap data and messages.

Every topic of a walkcap MCAP file is one `Topic` in the registry TOPICS: its name, schema,
description and message builder; the writer, the live taps and the reader take them from
there. Images, clouds and transforms use Foxglove's protobuf schemas (they display in
Foxglove as they are); everything else is JSON with a JSON Schema. Builders (`*_image`,
`*_message`, `*_json`) turn walkcap data into messages; decoders (`*_from_message`) turn
them back into numpy arrays.

Depth, losslessly at the sensor's precision and compactly:
- /camera/depth is a foxglove.RawImage "16UC1": the radial distance along each pixel's ray
  in millimetres (0 = invalid pixel). The unit ray of every pixel is stored once, as the
  attachment "camera_rays.npy" (float32, height x width x 3), so x, y, z = range * ray.
  Rounding to whole millimetres moves a point at most 0.5 mm along its ray (the pico flexx
  is good to about 1 % of range, i.e. several millimetres); nothing moves across the ray.
- /camera/confidence is a foxglove.RawImage "mono8": royale's per-pixel confidence, as is.
Together they rebuild the frame's xyz and confidence (see capture.recording.reader.depth_frames).

Clouds are foxglove.PointCloud with float32 x, y, z in metres, rounded to 1/1024 m: well
below the sensor's precision, and the zeroed low mantissa bits halve the compressed size.
A cloud is a set of points: it is stored sorted by x (forward), which compresses better.

Times: log_time is the host receive time, publish_time the sample time, both integer
nanoseconds on the session clock (devices.clock.now_ns, monotonic). Message `timestamp`
fields carry the publish time on the same clock.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from devices.frames import GAIT_EVENTS, GAIT_SOURCES, MODES, GaitEvent

FORMAT_VERSION = "5"  # the rule and the reading of older files: capture.recording.versions

DEPTH = "/camera/depth"
CONFIDENCE = "/camera/confidence"
GRAY = "/camera/gray"  # only when the recorder is asked to keep the amplitude image
CLOUD = "/camera/cloud"
BINARY_IMAGE = "/camera/binary_image"
PREPROCESS = "/camera/preprocess"
TF = "/tf"
IMU = "/imu"
LABELS = "/labels"
EVENTS = "/events"
CNN = "/inference/cnn"
FUSED = "/inference/fused"
FEATURES = "/terrain/features"
TRUTH = "/sim/truth"
GAIT = "/gait"  # gait events detected from the thigh IMU (source "imu")
SIM_GAIT = "/sim/gait"  # the simulator's gait events (source "simulator")

CAMERA_FRAME = "camera"  # royale axes: x right, y down, z forward
WORLD_FRAME = "world"  # leveled: x forward, y left, z up
RAYS_ATTACHMENT = "camera_rays.npy"
CLOUD_QUANTUM_M = 1.0 / 1024.0

# ---- helpers ------------------------------------------------------------------------------


def timestamp(ns: int) -> Timestamp:
    return Timestamp(seconds=int(ns) // 1_000_000_000, nanos=int(ns) % 1_000_000_000)


def jsonable(value: Any) -> Any:
    """Plain JSON types: numpy to lists and numbers, NaN and infinity to null."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return jsonable(dataclasses.asdict(value))
    if isinstance(value, bytes):
        return value.hex()
    return str(value)


_ORJSON_OPTIONS = orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_NON_STR_KEYS


def encode_json(value: dict) -> bytes:
    """Compact JSON as jsonable() would give it (NaN and infinity as null), without walking
    the value in Python: the 400 Hz IMU and every frame's messages pass here."""
    return orjson.dumps(value, default=jsonable, option=_ORJSON_OPTIONS)


# ---- metadata ---------------------------------------------------------------------------

# MCAP metadata maps strings to strings. walkcap stores each value as JSON (numbers,
# booleans, lists and objects keep their type) and says so with this key in the
# "recording" record; files without it hold plain strings.
METADATA_VALUES_KEY = "metadata_values"
METADATA_VALUES = "json"
# Records only ever written with JSON values, whatever the rest of the file holds (a
# recovered or corrected copy of an older file adds them).
JSON_ONLY_RECORDS = ("derivation",)


def encode_metadata(values: dict) -> dict[str, str]:
    """A metadata record's values as JSON text, ready for MCAP."""
    return {str(k): encode_json({"v": v})[5:-1].decode() for k, v in values.items()}


def decode_metadata_value(text: str) -> Any:
    """A JSON-encoded metadata value; text that is not JSON stays text."""
    try:
        return orjson.loads(text)
    except orjson.JSONDecodeError:
        return text


# ---- depth --------------------------------------------------------------------------------


def range_mm(xyz: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """Radial distance of every pixel in whole millimetres, uint16; 0 where invalid."""
    r = np.sqrt(np.einsum("...i,...i->...", xyz.astype(np.float64), xyz.astype(np.float64)))
    mm = np.rint(r * 1000.0)
    mm[(confidence == 0) | ~np.isfinite(mm)] = 0
    return np.clip(mm, 0, 65535).astype("<u2")


def xyz_from_range(mm: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Rebuild the camera-frame points (H, W, 3) float32 metres from range and unit rays."""
    return (mm.astype(np.float32)[..., None] * np.float32(0.001)) * rays.astype(np.float32)


def ray_error_m(xyz: np.ndarray, rays: np.ndarray, confidence: np.ndarray) -> float:
    """Largest distance of a valid point from its pixel's ray: 0 when the rays fit the data."""
    valid = confidence > 0
    if not valid.any():
        return 0.0
    p = xyz[valid].astype(np.float64)
    d = rays[valid].astype(np.float64)
    along = np.einsum("ij,ij->i", p, d)[:, None] * d
    return float(np.max(np.linalg.norm(p - along, axis=1)))


def raw_image(
    image: np.ndarray, time_ns: int, encoding: str, frame_id: str = CAMERA_FRAME
) -> RawImage:
    image = np.ascontiguousarray(image)
    h, w = image.shape[:2]
    return RawImage(
        timestamp=timestamp(time_ns),
        frame_id=frame_id,
        width=w,
        height=h,
        encoding=encoding,
        step=w * image.itemsize,
        data=image.tobytes(),
    )


def image_from_message(msg: RawImage) -> np.ndarray:
    """A RawImage back into a numpy array (uint16 for 16UC1/mono16, uint8 for mono8)."""
    dtype = {"16UC1": "<u2", "mono16": "<u2", "mono8": "u1", "8UC1": "u1"}[msg.encoding]
    itemsize = np.dtype(dtype).itemsize
    rows = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.step)
    return rows[:, : msg.width * itemsize].copy().view(dtype).reshape(msg.height, msg.width)


def binary_image_u8(image: np.ndarray) -> np.ndarray:
    """The classifier input as mono8: 0/1 (or bool) become 0/255 so it is visible."""
    a = np.asarray(image)
    if a.dtype == np.uint8 and a.size and a.max() <= 1:  # the preprocessing's image
        return a * np.uint8(255)
    if a.dtype == bool or (a.size and float(np.nanmax(a)) <= 1.0):
        return (np.nan_to_num(a.astype(np.float32)) * 255).round().astype(np.uint8)
    return np.clip(np.nan_to_num(a), 0, 255).astype(np.uint8)


def depth_image(range_mm: np.ndarray, time_ns: int) -> RawImage:
    """/camera/depth: range in whole millimetres (see range_mm)."""
    return raw_image(range_mm, time_ns, "16UC1")


def confidence_image(confidence: np.ndarray, time_ns: int) -> RawImage:
    return raw_image(np.asarray(confidence, np.uint8), time_ns, "mono8")


def gray_image(gray: np.ndarray, time_ns: int) -> RawImage:
    return raw_image(np.asarray(gray).astype("<u2"), time_ns, "16UC1")


def binary_image(image: np.ndarray, time_ns: int) -> RawImage:
    """The classifier input, in no camera's frame."""
    return raw_image(binary_image_u8(image), time_ns, "mono8", frame_id="")


# ---- cloud and transform ------------------------------------------------------------------

_XYZ_FIELDS = [
    PackedElementField(name=n, offset=4 * i, type=PackedElementField.FLOAT32)
    for i, n in enumerate("xyz")
]


def cloud_message(cloud: np.ndarray, time_ns: int, frame_id: str = WORLD_FRAME) -> PointCloud:
    """The cloud as a set: finite points, rounded to CLOUD_QUANTUM_M, sorted by x (forward),
    which makes neighbours alike and the compressed cloud about 13 % smaller."""
    points = np.asarray(cloud).reshape(-1, 3)
    if points.dtype == np.float32:  # the pipeline's clouds: compiled, the same float32s
        from inference.corridor import quantized_cloud

        q = quantized_cloud(np.ascontiguousarray(points), CLOUD_QUANTUM_M)
    else:
        points = points.astype(np.float64)
        points = points[np.all(np.isfinite(points), axis=1)]
        points = points[np.argsort(points[:, 0], kind="stable")]
        q = (np.rint(points / CLOUD_QUANTUM_M) * CLOUD_QUANTUM_M).astype("<f4")
    return PointCloud(
        timestamp=timestamp(time_ns),
        frame_id=frame_id,
        point_stride=12,
        fields=_XYZ_FIELDS,
        data=q.tobytes(),
    )


def cloud_from_message(msg: PointCloud) -> np.ndarray:
    """(N, 3) float32 metres from a PointCloud with float32 x, y, z fields."""
    offsets = {f.name: f.offset for f in msg.fields}
    raw = np.frombuffer(msg.data, dtype=np.uint8).reshape(-1, msg.point_stride)
    return np.stack(
        [raw[:, offsets[n] : offsets[n] + 4].copy().view("<f4")[:, 0] for n in "xyz"], axis=1
    )


def transform_message(quaternion: np.ndarray, time_ns: int) -> FrameTransform:
    """Camera orientation: walkcap's [w, x, y, z] (camera -> world) into Foxglove's x, y, z, w."""
    w, x, y, z = (float(v) for v in quaternion)
    return FrameTransform(
        timestamp=timestamp(time_ns),
        parent_frame_id=WORLD_FRAME,
        child_frame_id=CAMERA_FRAME,
        translation=Vector3(x=0, y=0, z=0),
        rotation=Quaternion(x=x, y=y, z=z, w=w),
    )


def quaternion_from_transform(msg: FrameTransform) -> np.ndarray:
    r = msg.rotation
    return np.array([r.w, r.x, r.y, r.z])


# ---- JSON messages ------------------------------------------------------------------------


def imu_json(sample) -> dict:
    return {
        "host_time_ns": sample.host_time_ns,
        "time_ns": sample.time_ns,
        "packet_counter": sample.packet_counter,
        "sample_time_fine": sample.sample_time_fine,
        "quaternion": sample.quaternion,
        "acceleration": sample.acceleration,
        "rate_of_turn": sample.rate_of_turn,
        "status_word": sample.status_word,
        "extra": sample.extra or {},
    }


def label_json(time_ns: int, mode: str, source: str) -> dict:
    return {"time_ns": int(time_ns), "mode": mode or "", "source": source}


def event_json(event) -> dict:
    """A devices.base.DeviceEvent or a dict with the same keys (time_ns defaults to 0)."""
    if isinstance(event, dict):
        e = dict(event)
        return {
            "time_ns": int(e.pop("time_ns", 0)),
            "device": str(e.pop("device", "")),
            "kind": str(e.pop("kind", "")),
            "message": str(e.pop("message", "")),
            "details": {**e.pop("details", {}), **e},
        }
    return {
        "time_ns": int(event.time_ns),
        "device": event.device,
        "kind": event.kind,
        "message": event.message,
        "details": event.details or {},
    }


def cnn_json(frame_index: int, time_ns: int, probabilities) -> dict:
    p = np.asarray(probabilities, dtype=np.float64).reshape(-1)
    return {
        "frame_index": int(frame_index),
        "time_ns": int(time_ns),
        "probabilities": p,
        "decision": MODES[int(np.nanargmax(p))] if np.isfinite(p).any() else MODES[0],
    }


def fused_json(frame_index: int, time_ns: int, fused: dict) -> dict:
    """The fusion output produced at `frame_index`; `fused` says which frame it refers to."""
    out = dict(fused)
    out["source_frame_index"] = int(frame_index)
    out["time_ns"] = int(time_ns)
    for key in ("decision", "voted"):  # accept mode indices as well as names
        if isinstance(out.get(key), (int, np.integer)) and not isinstance(out[key], bool):
            out[key] = MODES[int(out[key])]
    out.setdefault("frame_index", int(frame_index))
    return out


def features_json(frame_index: int, time_ns: int, features: dict) -> dict:
    return {**features, "frame_index": int(frame_index), "time_ns": int(time_ns)}


def truth_json(frame_index: int, time_ns: int, truth: dict) -> dict:
    out = {**truth, "frame_index": int(frame_index), "time_ns": int(time_ns)}
    out.setdefault("mode", None)
    return out


def gait_json(event: GaitEvent) -> dict:
    return {
        "time_ns": int(event.time_ns),
        "event": event.event,
        "source": event.source,
        "mode": event.mode or None,
    }


def gait_topic(event: GaitEvent) -> str:
    """/gait for the detector's events, /sim/gait for the simulator's."""
    return SIM_GAIT if event.source == "simulator" else GAIT


def gait_from_message(d: dict) -> GaitEvent:
    """A /gait or /sim/gait message, decoded, as the GaitEvent it was written from."""
    return GaitEvent(int(d["time_ns"]), str(d["event"]), str(d["source"]), d.get("mode") or None)


def preprocess_json(
    frame_index: int,
    time_ns: int,
    flag: str,
    oriented: bool,
    cloud_points: int,
    cloud_points_recorded: int,
) -> dict:
    return {
        "frame_index": int(frame_index),
        "time_ns": int(time_ns),
        "flag": flag or "",
        "oriented": bool(oriented),
        "cloud_points": int(cloud_points),
        "cloud_points_recorded": int(cloud_points_recorded),
    }


# ---- the registry -------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Topic:
    """One topic of a walkcap recording: all that the writer, the reader, the live taps and
    the docs know of it. `schema` is a JSON Schema (dict) for JSON topics, a Foxglove
    protobuf message class for the others; `build` turns walkcap data into its message."""

    name: str
    description: str  # one line, in the file's "recording" metadata and on live channels
    schema: dict | type
    build: Callable[..., Any] | None = None  # None: the message is given as it is
    sensor: bool = False  # raw sensor data: its log times span the recording and its chunks

    @property
    def message_encoding(self) -> str:
        return "json" if isinstance(self.schema, dict) else "protobuf"

    @property
    def schema_encoding(self) -> str:
        return "jsonschema" if isinstance(self.schema, dict) else "protobuf"

    @property
    def schema_name(self) -> str:
        if isinstance(self.schema, dict):
            return self.schema.get("title", self.name)
        return self.schema.DESCRIPTOR.full_name

    @functools.cached_property
    def schema_data(self) -> bytes:
        """The schema as written into the file."""
        if isinstance(self.schema, dict):
            return json.dumps(self.schema, separators=(",", ":")).encode()
        from mcap_protobuf.schema import build_file_descriptor_set

        return build_file_descriptor_set(self.schema).SerializeToString()

    def encode(self, *data: Any) -> bytes:
        """The message's bytes: `build(*data)` serialised as the topic's encoding."""
        message = self.build(*data) if self.build is not None else data[0]
        if isinstance(self.schema, dict):
            return encode_json(message)
        return message.SerializeToString()


_NUMBER_OR_NULL = {"type": ["number", "null"]}
_INT = {"type": "integer"}
_INT_OR_NULL = {"type": ["integer", "null"]}
_MODE = {"type": "string", "enum": list(MODES)}
_MODE_OR_EMPTY = {"type": "string", "enum": [*MODES, ""]}
_MODE_OR_NULL = {"type": ["string", "null"], "enum": [*MODES, None]}
_VEC3 = {"type": ["array", "null"], "items": _NUMBER_OR_NULL, "minItems": 3, "maxItems": 3}
_QUAT = {"type": ["array", "null"], "items": _NUMBER_OR_NULL, "minItems": 4, "maxItems": 4}
_PROBS = {"type": "array", "items": _NUMBER_OR_NULL, "minItems": len(MODES), "maxItems": len(MODES)}


def _object(
    title: str, description: str, properties: dict, required: list[str], extra: bool = False
) -> dict:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": required,
        "additionalProperties": extra,
    }


def _gait_schema(title: str, what: str) -> dict:
    return _object(
        title,
        f"A heel contact or toe off of the instrumented leg, {what}: its time (session "
        "clock), and the mode of the terrain under that foot where known.",
        {
            "time_ns": _INT,
            "event": {"type": "string", "enum": list(GAIT_EVENTS)},
            "source": {"type": "string", "enum": list(GAIT_SOURCES)},
            "mode": _MODE_OR_NULL,
        },
        ["time_ns", "event", "source", "mode"],
    )


def json_topic(name: str, schema: dict, description: str) -> Topic:
    """A JSON topic beyond walkcap's own (another device's LSL stream): messages as given."""
    return Topic(name, description, schema)


# Every topic of a walkcap recording, in the order the file's metadata lists them.
TOPICS: dict[str, Topic] = {
    topic.name: topic
    for topic in (
        Topic(
            DEPTH,
            "foxglove.RawImage 16UC1: range along each pixel's ray, mm (0 = invalid)",
            RawImage,
            depth_image,
            sensor=True,
        ),
        Topic(
            CONFIDENCE,
            "foxglove.RawImage mono8: royale depth confidence (0 = invalid)",
            RawImage,
            confidence_image,
            sensor=True,
        ),
        Topic(
            GRAY, "foxglove.RawImage 16UC1: amplitude (optional)", RawImage, gray_image, sensor=True
        ),
        Topic(
            CLOUD,
            "foxglove.PointCloud: leveled, cropped cloud, world frame, float32 m",
            PointCloud,
            cloud_message,
        ),
        Topic(
            BINARY_IMAGE,
            "foxglove.RawImage mono8: the classifier input (255 = terrain)",
            RawImage,
            binary_image,
        ),
        Topic(
            PREPROCESS,
            "JSON: preprocessing flag and cloud size per frame",
            _object(
                "walkcap.Preprocess",
                "How a frame became the classifier input: why the image is empty (flag), "
                "cloud size.",
                {
                    "frame_index": _INT,
                    "time_ns": _INT,
                    "flag": {"type": "string"},
                    "oriented": {"type": "boolean"},
                    "cloud_points": _INT,
                    "cloud_points_recorded": _INT,
                },
                [
                    "frame_index",
                    "time_ns",
                    "flag",
                    "oriented",
                    "cloud_points",
                    "cloud_points_recorded",
                ],
            ),
            preprocess_json,
        ),
        Topic(
            TF,
            "foxglove.FrameTransform world -> camera: camera orientation",
            FrameTransform,
            transform_message,
        ),
        Topic(
            IMU,
            "JSON: every IMU sample",
            _object(
                "walkcap.ImuSample",
                "One IMU sample. Quaternion [w, x, y, z] sensor -> world; vectors in the "
                "sensor frame.",
                {
                    "host_time_ns": _INT,
                    "time_ns": _INT_OR_NULL,
                    "packet_counter": _INT_OR_NULL,
                    "sample_time_fine": _INT_OR_NULL,
                    "quaternion": _QUAT,
                    "acceleration": _VEC3,
                    "rate_of_turn": _VEC3,
                    "status_word": _INT_OR_NULL,
                    "extra": {"type": "object"},
                },
                [
                    "host_time_ns",
                    "time_ns",
                    "packet_counter",
                    "quaternion",
                    "acceleration",
                    "rate_of_turn",
                    "status_word",
                ],
            ),
            imu_json,
            sensor=True,
        ),
        Topic(
            LABELS,
            "JSON: operator mode changes",
            _object(
                "walkcap.Label",
                "The operator's mode from time_ns on ('' = no mode, after undoing the first).",
                {"time_ns": _INT, "mode": _MODE_OR_EMPTY, "source": {"type": "string"}},
                ["time_ns", "mode", "source"],
            ),
            label_json,
        ),
        Topic(
            EVENTS,
            "JSON: markers, notes, device faults, gaps, drops",
            _object(
                "walkcap.Event",
                "A marker, note, device fault, gap or recorder drop.",
                {
                    "time_ns": _INT,
                    "device": {"type": "string"},
                    "kind": {"type": "string"},
                    "message": {"type": "string"},
                    "details": {"type": "object"},
                },
                ["time_ns", "device", "kind", "message", "details"],
            ),
            event_json,
        ),
        Topic(
            CNN,
            "JSON: CNN probabilities per frame",
            _object(
                "walkcap.CnnOutput",
                "The CNN's softmax for one frame, in mode order " + ", ".join(MODES) + ".",
                {"frame_index": _INT, "time_ns": _INT, "probabilities": _PROBS, "decision": _MODE},
                ["frame_index", "time_ns", "probabilities", "decision"],
            ),
            cnn_json,
        ),
        Topic(
            FUSED,
            "JSON: fused posterior, decision and vote, with the frames they refer to",
            _object(
                "walkcap.FusedOutput",
                "HMM fusion output produced at source_frame_index; it refers to frame_index "
                "(and the vote to voted_frame_index), earlier frames because of the smoothing "
                "window.",
                {
                    "source_frame_index": _INT,
                    "time_ns": _INT,
                    "frame_index": _INT,
                    "decision": _MODE,
                    "posterior": _PROBS,
                    "voted": _MODE_OR_NULL,
                    "voted_frame_index": _INT_OR_NULL,
                },
                ["source_frame_index", "time_ns", "frame_index", "decision", "posterior"],
                extra=True,
            ),
            fused_json,
        ),
        Topic(
            FEATURES,
            "JSON: terrain features per frame",
            _object(
                "walkcap.TerrainFeatures",
                "Terrain features of one frame (riser, tread, slope, distance ...), SI units.",
                {"frame_index": _INT, "time_ns": _INT},
                ["frame_index", "time_ns"],
                extra=True,
            ),
            features_json,
        ),
        Topic(
            TRUTH,
            "JSON: simulator truth (mock sessions)",
            _object(
                "walkcap.SimTruth",
                "Simulator ground truth of one frame: the true mode and the camera pose "
                "(4x4, world).",
                {
                    "frame_index": _INT,
                    "time_ns": _INT,
                    "mode": _MODE_OR_NULL,
                    "pose": {"type": ["array", "null"]},
                },
                ["frame_index", "time_ns", "mode"],
                extra=True,
            ),
            truth_json,
        ),
        Topic(
            GAIT,
            "JSON: heel contacts and toe offs detected from the thigh IMU",
            _gait_schema("walkcap.GaitEvent", "detected from the thigh IMU (inference.gait)"),
            gait_json,
        ),
        Topic(
            SIM_GAIT,
            "JSON: simulator gait events, with the terrain under the foot (mock sessions)",
            _gait_schema("walkcap.SimGaitEvent", "the simulated walk's truth"),
            gait_json,
        ),
    )
}
