"""Gait events through a recording: the Recorder writes each on its source's topic and
read_gait gives them back as a table in time order, per source or both."""

from __future__ import annotations

import numpy as np
import pytest

from capture.recording import read_gait
from capture.recording import topics as T
from capture.recording.reader import open_recording
from capture.recording.writer import Recorder
from devices.frames import GaitEvent
from tests.recording_fixtures import T0

EVENTS = [
    GaitEvent(T0 + 400_000_000, "heel_contact", "imu"),
    GaitEvent(T0 + 380_000_000, "heel_contact", "simulator", "LG"),
    GaitEvent(T0 + 1_040_000_000, "toe_off", "simulator", "US"),
    GaitEvent(T0 + 1_050_000_000, "toe_off", "imu"),
]


@pytest.fixture(scope="module")
def path(tmp_path_factory):
    p = tmp_path_factory.mktemp("gait") / "gait.mcap"
    with Recorder(p, metadata={}) as rec:
        for e in EVENTS:
            rec.write_gait(e, e.time_ns + 150_000_000 if e.source == "imu" else None)
    return p


def test_each_source_has_its_topic(path):
    rec = open_recording(path)
    assert [m.data["source"] for m in rec.read(T.GAIT)] == ["imu", "imu"]
    assert [m.data["mode"] for m in rec.read(T.SIM_GAIT)] == ["LG", "US"]
    # the detector's events are logged when they were known, published at their own time
    first = rec.read(T.GAIT)[0]
    assert first.publish_time_ns == EVENTS[0].time_ns
    assert first.log_time_ns == EVENTS[0].time_ns + 150_000_000


def test_read_gait_gives_the_events_back_in_time_order(path):
    both = read_gait(path)
    assert both.events() == sorted(EVENTS, key=lambda e: e.time_ns)
    sim = read_gait(path, source="simulator")
    assert list(sim.mode) == ["LG", "US"]
    assert list(sim.mode_index) == [0, 1]
    imu = read_gait(open_recording(path), source="imu")
    assert list(imu.event) == ["heel_contact", "toe_off"]
    assert list(imu.mode_index) == [-1, -1]
    assert imu.heel_contacts().time_ns.tolist() == [EVENTS[0].time_ns]
    assert both.toe_offs().of(source="imu").time_ns.dtype == np.int64


def test_a_recording_without_gait_events_gives_an_empty_table(tmp_path):
    p = tmp_path / "none.mcap"
    with Recorder(p, metadata={}):
        pass
    assert len(read_gait(p)) == 0
    with pytest.raises(ValueError, match="gait source"):
        read_gait(p, source="camera")
