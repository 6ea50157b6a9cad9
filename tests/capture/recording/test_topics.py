"""The topic registry: every registered topic goes into a file and comes back as it was
given, under the schema the registry names; every sink accepts every write of a session."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from capture.recording import topics as T
from capture.recording.encode import message
from capture.recording.reader import open_recording
from capture.recording.sink import Sink
from capture.recording.writer import Recorder
from devices.base import DeviceEvent
from devices.frames import MODES, GaitEvent, ImuSample
from devices.simulator.synthetic import synthetic_frame
from tests.recording_fixtures import T0

_SAMPLE = ImuSample(
    host_time_ns=T0 + 1_000,
    time_ns=T0,
    packet_counter=7,
    sample_time_fine=700,
    quaternion=np.array([1.0, 0.0, 0.0, 0.0]),
    acceleration=np.array([0.0, 0.25, 9.75]),
    rate_of_turn=np.array([0.5, 0.0, -0.5]),
    status_word=3,
)
_FUSED = {"frame_index": 3, "decision": "US", "posterior": [0.1, 0.6, 0.1, 0.1, 0.1]}
_RANGE = np.arange(12, dtype="<u2").reshape(3, 4) * 100
_CLOUD = np.array([[0.5, 0.0, -0.5], [0.25, 0.125, -0.5], [1.0, -0.25, 0.0]], np.float32)

# topic -> (what its builder is given, what the reader gives back)
CASES = {
    T.DEPTH: ((_RANGE, T0), _RANGE),
    T.CONFIDENCE: ((np.full((3, 4), 200, np.uint8), T0), np.full((3, 4), 200)),
    T.GRAY: ((np.arange(12).reshape(3, 4), T0), np.arange(12).reshape(3, 4)),
    T.CLOUD: ((_CLOUD, T0), _CLOUD[np.argsort(_CLOUD[:, 0])]),  # a set, stored sorted by x
    T.BINARY_IMAGE: ((np.eye(4, dtype=np.uint8), T0), np.eye(4) * 255),
    T.PREPROCESS: (
        (4, T0, "", True, 300, 120),
        {
            "frame_index": 4,
            "time_ns": T0,
            "flag": "",
            "oriented": True,
            "cloud_points": 300,
            "cloud_points_recorded": 120,
        },
    ),  # fmt: skip
    T.TF: ((np.array([0.5, 0.5, -0.5, 0.5]), T0), np.array([0.5, 0.5, -0.5, 0.5])),
    T.IMU: (
        (_SAMPLE,),
        {
            "host_time_ns": T0 + 1_000,
            "time_ns": T0,
            "packet_counter": 7,
            "sample_time_fine": 700,
            "quaternion": [1.0, 0.0, 0.0, 0.0],
            "acceleration": [0.0, 0.25, 9.75],
            "rate_of_turn": [0.5, 0.0, -0.5],
            "status_word": 3,
            "extra": {},
        },
    ),  # fmt: skip
    T.LABELS: ((T0, "UR", "operator"), {"time_ns": T0, "mode": "UR", "source": "operator"}),
    T.EVENTS: (
        (DeviceEvent(T0, "imu", "gap", "3 samples missing", {"missing": 3}),),
        {
            "time_ns": T0,
            "device": "imu",
            "kind": "gap",
            "message": "3 samples missing",
            "details": {"missing": 3},
        },
    ),  # fmt: skip
    T.CNN: (
        (4, T0, [0.1, 0.1, 0.6, 0.1, 0.1]),
        {
            "frame_index": 4,
            "time_ns": T0,
            "probabilities": [0.1, 0.1, 0.6, 0.1, 0.1],
            "decision": "DS",
        },
    ),  # fmt: skip
    T.FUSED: ((4, T0, _FUSED), {**_FUSED, "source_frame_index": 4, "time_ns": T0}),
    T.FEATURES: (
        (4, T0, {"riser_m": 0.17, "tread_m": float("nan")}),
        {"riser_m": 0.17, "tread_m": None, "frame_index": 4, "time_ns": T0},
    ),
    T.TRUTH: ((4, T0, {"mode": "LG"}), {"mode": "LG", "frame_index": 4, "time_ns": T0}),
    T.GAIT: (
        (GaitEvent(T0, "heel_contact", "imu"),),
        {"time_ns": T0, "event": "heel_contact", "source": "imu", "mode": None},
    ),
    T.SIM_GAIT: (
        (GaitEvent(T0, "toe_off", "simulator", "US"),),
        {"time_ns": T0, "event": "toe_off", "source": "simulator", "mode": "US"},
    ),
}


def test_every_registered_topic_has_a_round_trip_case():
    assert list(CASES) == list(T.TOPICS)  # a new topic comes with its case below


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """Each topic's message, built by the registry, written by a Recorder, read back."""
    path = tmp_path_factory.mktemp("topics") / "topics.mcap"
    messages = [message(topic, T0 + 5, T0, *data, sequence=4) for topic, (data, _) in CASES.items()]
    with Recorder(path, metadata={}) as rec:
        rec.write_encoded(4, T0, T0 + 5, messages)
    return path


@pytest.mark.parametrize("topic", list(T.TOPICS))
def test_a_topic_round_trips_through_a_recording(written, topic):
    spec = T.TOPICS[topic]
    (got,) = open_recording(written).read(topic)
    expected = CASES[topic][1]
    assert (got.log_time_ns, got.publish_time_ns, got.sequence) == (T0 + 5, T0, 4)
    if isinstance(expected, dict):
        assert got.data == expected
        jsonschema.validate(got.data, spec.schema)
    else:
        np.testing.assert_array_equal(got.data, expected)
    with open(written, "rb") as f:
        summary = make_reader(f).get_summary()
    (channel,) = [c for c in summary.channels.values() if c.topic == topic]
    schema = summary.schemas[channel.schema_id]
    assert channel.message_encoding == spec.message_encoding
    assert (schema.name, schema.encoding, schema.data) == (
        spec.schema_name,
        spec.schema_encoding,
        spec.schema_data,
    )
    assert channel.metadata == {"description": spec.description}


def test_the_file_lists_every_topic_with_its_description(written):
    described = open_recording(written).metadata["recording"]["topics"]
    assert described == {name: topic.description for name, topic in T.TOPICS.items()}


def test_only_raw_sensor_topics_span_the_recording():
    assert {t.name for t in T.TOPICS.values() if t.sensor} == {
        T.DEPTH,
        T.CONFIDENCE,
        T.GRAY,
        T.IMU,
    }


# ---- sinks -------------------------------------------------------------------------------

# Every write a session makes, with plausible data (a new Sink method needs its case here).
WRITES = {
    "write_frame": (synthetic_frame(0, T0), T0),
    "write_imu": (_SAMPLE,),
    "write_processed": (4, T0, T0, _CLOUD, np.eye(100), None, "no orientation"),
    "write_inference": (4, T0, T0, np.full(len(MODES), 0.2), _FUSED),
    "write_features": (4, T0, {"riser_m": 0.17}),
    "write_truth": (4, T0, {"mode": "LG"}),
    "write_gait": (GaitEvent(T0, "heel_contact", "imu"), T0 + 5),
    "write_label": (T0, "LG", "operator"),
    "write_event": (DeviceEvent(T0, "operator", "marker", "start"),),
}


def _writes(cls) -> set[str]:
    return {n for n, _ in inspect.getmembers(cls, inspect.isfunction) if n.startswith("write_")}


def test_a_sink_that_implements_nothing_accepts_every_write():
    class Nothing(Sink):
        pass

    sink = Nothing()
    assert _writes(Sink) == set(WRITES)
    for name, args in WRITES.items():
        assert getattr(sink, name)(*args) is None


def test_the_recorder_keeps_every_write_a_session_makes():
    for name in _writes(Sink):  # nothing the session hands out is silently left unrecorded
        assert getattr(Recorder, name) is not getattr(Sink, name), name


def test_the_documented_topic_table_is_the_registry():
    """The topic table of the docs (README or docs/) names every topic, with its schema."""
    root = Path(__file__).resolve().parents[3]
    rows = {}
    for doc in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        for topic, encoding in re.findall(r"^\| `(/[^` ]+)` \| ([^|]+) \|", doc.read_text(), re.M):
            rows.setdefault(topic, encoding.strip())
    # A row such as /lsl/NAME documents a family of topics named at run time (other
    # devices' LSL streams), not a registered topic.
    rows = {topic: encoding for topic, encoding in rows.items() if not topic.endswith("/NAME")}
    assert set(rows) == set(T.TOPICS)
    for topic, encoding in rows.items():
        spec = T.TOPICS[topic]
        assert encoding.split()[0] == (
            "JSON" if spec.message_encoding == "json" else spec.schema_name
        )
