"""Lab Streaming Layer on loopback: walkcap's outlets to an inlet, other streams into MCAP."""

import time
import uuid

import numpy as np
import pytest

from capture import lsl as L
from capture.reader import open_recording
from capture.recorder import Recorder
from devices.clock import now_ns
from devices.frames import MODES, ImuSample

pylsl = pytest.importorskip("pylsl")


def _inlet(name: str):
    found = pylsl.resolve_byprop("name", name, 1, 5.0)
    assert found, f"no LSL stream {name}"
    inlet = pylsl.StreamInlet(found[0])
    inlet.open_stream(timeout=5.0)
    return inlet


def _pull(inlet, n: int, timeout_s: float = 5.0):
    samples, stamps = [], []
    deadline = time.monotonic() + timeout_s
    while len(samples) < n and time.monotonic() < deadline:
        s, t = inlet.pull_chunk(timeout=0.2)
        samples += s
        stamps += t
    return samples, stamps


def _channels(info):
    out = []
    ch = info.desc().child("channels").child("channel")
    while not ch.empty():
        out.append((ch.child_value("label"), ch.child_value("unit"), ch.child_value("type")))
        ch = ch.next_sibling()
    return out


@pytest.fixture
def outlets():
    name = f"wc-{uuid.uuid4().hex[:8]}"
    out = L.LslOutlets(
        imu_rate_hz=100, camera_fps=15, imu_id="0388ABCD", camera_id="pf-1", name=name
    )
    yield name, out
    out.close()


def test_outlets_carry_metadata_values_and_sample_times(outlets):
    name, out = outlets
    imu, terrain, markers = (
        _inlet(f"{name} IMU"),
        _inlet(f"{name} Terrain"),
        _inlet(f"{name} Markers"),
    )
    info = imu.info(timeout=5.0)
    assert info.type() == "IMU" and info.nominal_srate() == 100 and info.channel_count() == 10
    assert _channels(info)[0] == ("qw", "normalized", "Orientation")
    assert _channels(info)[4] == ("ax", "m/s^2", "Acceleration")
    assert info.source_id() == L.source_id("imu", "0388ABCD")  # stable for the device
    assert _channels(terrain.info(timeout=5.0))[1] == ("p_LG", "probability", "Probability")
    time.sleep(0.3)  # the inlets connect before the first sample

    t0 = now_ns() - 50_000_000
    for k in range(5):
        out.write_imu(
            ImuSample(
                host_time_ns=t0 + k * 10_000_000 + 3_000_000,
                time_ns=t0 + k * 10_000_000,
                quaternion=np.array([1.0, 0.0, 0.0, 0.0]),
                acceleration=np.array([0.0, 0.0, 9.81 + k]),
                rate_of_turn=np.array([0.1, 0.2, 0.3]),
            )
        )
    probs = np.array([0.1, 0.6, 0.1, 0.1, 0.1])
    out.write_inference(7, t0, t0 + 5_000_000, probs, {"frame_index": 5, "decision": "US"})
    out.write_label(t0 + 1_000_000, "DS", "operator")

    samples, stamps = _pull(imu, 5)
    assert len(samples) == 5 and samples[3][6] == pytest.approx(12.81, abs=1e-4)
    correction = imu.time_correction(timeout=5.0)
    expected = [(t0 + k * 10_000_000) * 1e-9 + out.offset_s for k in range(5)]
    assert np.max(np.abs(np.array(stamps) + correction - expected)) < 1e-3  # within 1 ms

    (row,), (stamp,) = _pull(terrain, 1)
    assert row[0] == 7 and row[1:6] == pytest.approx(probs) and row[6] == MODES.index("US")
    assert row[7] == 5 and row[8] == MODES.index("US") and row[10] == L.NO_DECISION
    assert abs(stamp - (t0 * 1e-9 + out.offset_s)) < 1e-3
    (marker,), _ = _pull(markers, 1)
    assert marker == ["label DS (operator)"]


def test_named_streams_are_recorded_into_the_mcap_file(tmp_path):
    name = f"EMG-{uuid.uuid4().hex[:6]}"
    emg_info = pylsl.StreamInfo(name, "EMG", 32, 2000.0, pylsl.cf_float32, "emg-test")
    chans = emg_info.desc().append_child("channels")
    for c in range(32):
        chans.append_child("channel").append_child_value("label", f"ch{c}")
    emg = pylsl.StreamOutlet(emg_info)
    marker_name = f"Markers-{uuid.uuid4().hex[:6]}"
    mk = pylsl.StreamOutlet(
        pylsl.StreamInfo(marker_name, "Markers", 1, 0.0, pylsl.cf_string, "mk-test")
    )
    rec = Recorder(tmp_path / "t.mcap", metadata={"session": {"subject": "S1"}})
    rec.start()
    events = []
    inlets = L.LslInlets([name, marker_name], lambda: rec, events.append)
    inlets.start()
    try:
        deadline = time.monotonic() + 10
        while len(events) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert {e.kind for e in events} == {"lsl_found"}
        time.sleep(0.3)
        sent_at = pylsl.local_clock()
        chunk = np.arange(400 * 32, dtype=np.float32).reshape(400, 32)
        stamps = sent_at + np.arange(400) / 2000.0
        emg.push_chunk(chunk.tolist(), stamps.tolist())
        mk.push_sample(["stimulus 1"], sent_at)
        deadline = time.monotonic() + 10
        while inlets.received[name] < 400 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        inlets.stop()
        rec.close()

    recording = open_recording(tmp_path / "t.mcap")
    messages = list(recording.messages([L.topic_for(name)]))
    values = np.concatenate([m.data["values"] for m in messages])
    times = np.concatenate([m.data["time_ns"] for m in messages])
    assert values.shape == (400, 32) and np.array_equal(values, chunk)
    assert messages[0].data["channels"][3] == "ch3"
    assert "time_correction_uncertainty_s" in messages[0].data
    expected = (stamps - L.lsl_offset_s()) * 1e9
    assert np.max(np.abs(times - expected)) < 1e6  # within 1 ms of the session clock
    markers = [m.data for m in recording.messages(["/events"]) if m.data["kind"] == "marker"]
    assert [m["message"] for m in markers] == ["stimulus 1"]
    assert abs(markers[0]["time_ns"] - (sent_at - L.lsl_offset_s()) * 1e9) < 1e6


def test_a_stream_that_disappears_is_an_event_and_is_looked_for_again():
    name = f"Gone-{uuid.uuid4().hex[:6]}"
    outlet = pylsl.StreamOutlet(pylsl.StreamInfo(name, "EMG", 2, 100.0, pylsl.cf_float32, name))
    events = []
    inlets = L.LslInlets([name], lambda: None, events.append)
    inlets.start()
    try:
        deadline = time.monotonic() + 10
        while not events and time.monotonic() < deadline:
            time.sleep(0.05)
        outlet.push_sample([1.0, 2.0])
        del outlet
        deadline = time.monotonic() + 15
        while not any(e.kind == "lsl_lost" for e in events) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert [e.kind for e in events][:2] == ["lsl_found", "lsl_lost"]
        assert inlets.state[name] == "looking"
    finally:
        inlets.stop()
