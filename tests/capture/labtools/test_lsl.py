"""Lab Streaming Layer on loopback: walkcap's outlets to an inlet, other streams into MCAP."""

import time
import uuid

import numpy as np
import pytest

from capture.labtools import lsl as L
from capture.recording.reader import open_recording
from capture.recording.writer import Recorder
from devices.clock import now_ns
from devices.frames import MODES, ImuSample
from tests.waiting import wait_for

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


_CLOSING_OUTLET = """
import sys, pylsl
name = sys.argv[1]
outlet = pylsl.StreamOutlet(pylsl.StreamInfo(name, "EMG", 2, 100.0, pylsl.cf_float32, name))
assert outlet.wait_for_consumers(60)
outlet.push_sample([1.0, 2.0])
print("sent", flush=True)
sys.stdin.readline()
del outlet  # the device's program closes its stream and ends
"""


@pytest.mark.subprocess
def test_a_stream_that_disappears_is_an_event_and_is_looked_for_again():
    # The outlet lives in a process of its own, as another device's stream does: liblsl
    # can crash a process that destroys an outlet while an inlet of the same process pulls
    # from it (its transfer threads outlive the destructor's wait under load).
    import subprocess
    import sys

    name = f"Gone-{uuid.uuid4().hex[:6]}"
    device = subprocess.Popen(
        [sys.executable, "-c", _CLOSING_OUTLET, name],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    events = []
    inlets = L.LslInlets([name], lambda: None, events.append)
    inlets.start()
    try:
        assert device.stdout.readline() == "sent\n"
        wait_for(lambda: any(e.kind == "lsl_found" for e in events), what="the stream found")
        device.stdin.write("\n")
        device.stdin.flush()
        device.wait(timeout=30)
        wait_for(lambda: any(e.kind == "lsl_lost" for e in events), what="the stream lost")
        assert [e.kind for e in events][:2] == ["lsl_found", "lsl_lost"]
        wait_for(lambda: inlets.state[name] == "looking", what="a new search")
    finally:
        device.kill()
        device.wait()
        inlets.stop()


# ---- what a stream sent, as it sent it -----------------------------------------------------


def _outlet(name: str, channels: int, fmt, source: str, labels=()):
    info = pylsl.StreamInfo(name, "Test", channels, 0.0, fmt, source)
    if labels:
        chans = info.desc().append_child("channels")
        for label in labels:
            chans.append_child("channel").append_child_value("label", label)
    return pylsl.StreamOutlet(info)


def test_every_channel_and_type_is_recorded_as_sent(tmp_path):
    tag = uuid.uuid4().hex[:6]
    names = [f"Mk-{tag}", f"I64-{tag}", f"F32-{tag}", f"EMG-1-{tag}", f"EMG_1_{tag}"]
    outlets = {
        names[0]: _outlet(names[0], 3, pylsl.cf_string, f"mk-{tag}", ("cue", "side", "note")),
        names[1]: _outlet(names[1], 2, pylsl.cf_int64, f"i64-{tag}"),
        names[2]: _outlet(names[2], 3, pylsl.cf_float32, f"f32-{tag}"),
        names[3]: _outlet(names[3], 1, pylsl.cf_float32, f"e1-{tag}"),
        names[4]: _outlet(names[4], 2, pylsl.cf_float32, f"e2-{tag}"),
    }
    rec = Recorder(tmp_path / "t.mcap", metadata={"session": {"subject": "S1"}})
    rec.start()
    events = []
    inlets = L.LslInlets(names, lambda: rec, events.append)
    inlets.start()
    big = [2**53 + 1, -(2**62) - 3]
    try:
        for outlet in outlets.values():
            assert outlet.wait_for_consumers(30)
        now = pylsl.local_clock()
        outlets[names[0]].push_sample(["go", "left", "café ☕"], now)
        outlets[names[1]].push_sample(big, now)
        outlets[names[2]].push_sample([float("inf"), float("nan"), float("-inf")], now)
        outlets[names[2]].push_sample([1.5, 2.5, 3.5], 1e11)  # a time beyond the clock
        outlets[names[3]].push_sample([1.0], now)
        outlets[names[4]].push_sample([2.0, 3.0], now)
        wait_for(lambda: inlets.received[names[2]] == 2)
        wait_for(lambda: all(inlets.received[n] >= 1 for n in names))
    finally:
        inlets.stop()
        rec.close()

    recording = open_recording(tmp_path / "t.mcap")
    (marker,) = [m.data for m in recording.messages(["/events"]) if m.data["kind"] == "marker"]
    assert marker["details"]["values"] == ["go", "left", "café ☕"]  # every channel
    assert marker["details"]["channels"] == ["cue", "side", "note"]

    def values(name):
        return [row for m in recording.messages([L.topic_for(name)]) for row in m.data["values"]]

    assert values(names[1]) == [big]  # int64 exact
    assert values(names[2])[0] == ["inf", None, "-inf"]  # +inf apart from NaN
    read_back = np.asarray(values(names[2])[0], dtype=float)
    assert np.isposinf(read_back[0]) and np.isnan(read_back[1]) and np.isneginf(read_back[2])
    chunks = [m.data for m in recording.messages([L.topic_for(names[2])])]
    times = [(t, lt) for c in chunks for t, lt in zip(c["time_ns"], c["lsl_time"])]
    assert times[1] == (None, pytest.approx(1e11))  # kept as sent, no time on the clock
    assert isinstance(times[0][0], int) and times[0][0] > 0
    assert [e.kind for e in events if e.kind == "lsl_bad_time"] == ["lsl_bad_time"]
    topics = {L.topic_for(n) for n in names}
    assert len(topics) == len(names)  # EMG-1 and EMG_1 apart
    assert values(names[3]) == [[1.0]] and values(names[4]) == [[2.0, 3.0]]


_HANGING_OUTLET = """
import sys, time, pylsl
outlet = pylsl.StreamOutlet(pylsl.StreamInfo(sys.argv[1], "EMG", 1, 0.0, pylsl.cf_float32, "a"))
assert outlet.wait_for_consumers(60)
outlet.push_sample([1.0])
print("sent", flush=True)
while True:
    time.sleep(1)
"""


@pytest.mark.subprocess
def test_a_stream_whose_outlet_hangs_is_replaced_by_its_successor(tmp_path):
    import signal
    import subprocess
    import sys

    name = f"Hang-{uuid.uuid4().hex[:6]}"
    old = subprocess.Popen(
        [sys.executable, "-c", _HANGING_OUTLET, name],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    rec = Recorder(tmp_path / "t.mcap", metadata={"session": {"subject": "S1"}})
    rec.start()
    events = []
    inlets = L.LslInlets([name], lambda: rec, events.append)
    inlets.start()
    try:
        assert old.stdout.readline() == "sent\n"
        wait_for(lambda: inlets.received[name] == 1)
        old.send_signal(signal.SIGSTOP)  # hangs: its connection stays open, silent
        new = _outlet(name, 1, pylsl.cf_float32, "b")  # the device's software, restarted
        assert new.wait_for_consumers(30)
        new.push_sample([2.0])
        wait_for(lambda: inlets.received[name] == 2)
    finally:
        old.kill()
        old.wait()
        inlets.stop()
        rec.close()
    assert [e.kind for e in events] == ["lsl_found", "lsl_lost", "lsl_found"]
    assert [e.details["source_id"] for e in events if e.kind == "lsl_found"] == ["a", "b"]
    recording = open_recording(tmp_path / "t.mcap")
    rows = [row for m in recording.messages([L.topic_for(name)]) for row in m.data["values"]]
    assert rows == [[1.0], [2.0]]
