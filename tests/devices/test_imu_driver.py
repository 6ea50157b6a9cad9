"""The Xbus driver against the device emulator over a real pty (pyserial and termios too)."""

import os
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
import serial

from devices import xbus
from devices.errors import DeviceInitError, DeviceNotAvailable
from devices.imu import XbusImu, open_imu
from devices.imu.emulator import ImuEmulator, gait_orientation
from devices.rotations import quat_to_matrix
from devices.xbus import MID
from tests.devices.imu_streams import collect, collect_n, kinds
from tests.waiting import wait_for

pytestmark = [pytest.mark.timeout(60), pytest.mark.realtime]


# ----------------------------------------------------------------------------- configuration


def test_configuration_sequence_and_info(mock_imu):
    imu = mock_imu(rate_hz=100)
    imu.open()
    requests = [r for r in imu.emulator.requests if r != MID.WAKEUP_ACK]
    assert MID.GOTO_CONFIG in requests[:-5]
    assert requests[-5:] == [
        MID.REQ_DID,
        MID.REQ_PRODUCT_CODE,
        MID.REQ_FW_REV,
        MID.SET_OUTPUT_CONFIGURATION,
        MID.GOTO_MEASUREMENT,
    ]
    assert imu.info["device_id"] == "03881234"
    assert imu.info["product_code"] == "MTi-3-8A7G6"
    assert imu.info["firmware"].startswith("1.8.2")
    outputs = {o["output"]: o for o in imu.info["output_configuration"]}
    assert list(outputs) == list(xbus.DEFAULT_OUTPUTS)
    assert outputs["quaternion"]["rate_hz"] == 100
    assert outputs["packet_counter"]["rate_hz"] == "every packet"


class SleepyEmulator(ImuEmulator):
    """A device still booting: it hears nothing but WakeUpAck during its wake-up window."""

    def _handle(self, msg, t):
        if self._wakeup_until and t < self._wakeup_until and msg.mid != MID.WAKEUP_ACK:
            return
        super()._handle(msg, t)


def test_wakeup_is_acknowledged():
    emulator = SleepyEmulator(wakeup_s=3.0)
    port = emulator.start()
    try:
        imu = XbusImu(port)
        imu.open()
        assert imu.info.get("woke_up") is True
        assert MID.WAKEUP_ACK in emulator.requests
        imu.close()
    finally:
        emulator.stop()


def test_a_rate_the_family_lacks_is_fitted_and_said(mock_imu):
    imu = mock_imu(rate_hz=7)  # the 1-series divides 100 Hz: 5 Hz is the nearest below
    imu.open()
    assert imu.configured_rate_hz == 5
    assert any("at 5 Hz, not 7 Hz" in a for a in imu.info["adjusted"])
    assert "output_adjusted" in kinds(imu.poll_events())


def test_a_silent_port_times_out_naming_the_request():
    master, slave = os.openpty()  # a serial line with nothing on the other end
    try:
        imu = XbusImu(os.ttyname(slave), config_timeout_s=0.5)
        start = time.monotonic()
        with pytest.raises(DeviceInitError, match="no answer to GoToConfig within 0.5 s"):
            imu.open()
        assert time.monotonic() - start < 2.0
    finally:
        os.close(master)
        os.close(slave)


def test_missing_port_and_unknown_backend_are_not_available(tmp_path):
    with pytest.raises(DeviceNotAvailable, match="cannot open IMU port"):
        XbusImu(str(tmp_path / "ttyNothing")).open()
    with pytest.raises(DeviceNotAvailable, match="known: mock, serial"):
        open_imu(SimpleNamespace(backend="bluetooth"))
    with pytest.raises(DeviceNotAvailable, match="port"):
        open_imu(SimpleNamespace(backend="serial", port="", baudrate=115200, rate_hz=100))


def test_emulator_answers_malformed_and_unsupported_requests_with_error():
    with ImuEmulator() as emulator:
        port = serial.Serial(emulator.port, 115200, timeout=0.05)
        parser = xbus.XbusParser()

        def ask(mid, data=b""):
            port.write(xbus.build(mid, data))
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                for msg in parser.feed(port.read(256)):
                    if msg.mid != MID.MTDATA2 and msg.mid != MID.WAKEUP:
                        return msg
            raise AssertionError("no answer")

        assert ask(MID.GOTO_CONFIG).mid == MID.GOTO_CONFIG_ACK
        assert (ask(MID.GOTO_CONFIG, b"\x01").mid, ask(MID.REQ_DID, b"x").data) == (
            MID.ERROR,
            bytes([xbus.INVALID_MESSAGE]),
        )
        assert ask(MID.REQ_CONFIGURATION, b"x").data == bytes([xbus.INVALID_MESSAGE])
        assert ask(0x77).data == bytes([xbus.INVALID_MESSAGE])
        assert ask(MID.SET_OUTPUT_CONFIGURATION, b"\x20\x10\x00").data == bytes(
            [xbus.INVALID_MESSAGE]
        )
        assert ask(MID.SET_OUTPUT_CONFIGURATION, b"\x55\x50\x00\x64").data == bytes(
            [xbus.INVALID_PARAMETER]
        )
        assert ask(MID.REQ_BAUDRATE, b"\x42").data == bytes([xbus.INVALID_BAUDRATE])
        assert ask(MID.REQ_BAUDRATE).data == b"\x02"  # 115200
        assert ask(MID.GOTO_MEASUREMENT).mid == MID.GOTO_MEASUREMENT_ACK
        # Measuring: configuration needs GoToConfig first.
        assert ask(MID.REQ_PRODUCT_CODE).data == bytes([xbus.INVALID_MESSAGE])
        port.close()


# ----------------------------------------------------------------------------- streaming


def body_rate(t: float) -> np.ndarray:
    """The default gait's body rate, analytically: roll and pitch (Z-Y-X Euler, no yaw)."""
    w = 2 * np.pi * 0.9
    roll = np.radians(2.0 * np.sin(w * t))
    roll_dot = np.radians(2.0 * w * np.cos(w * t))
    pitch_dot = -np.radians(25.0 * w * np.cos(w * t) + 6.0 * w * np.cos(2 * w * t))
    return np.array([roll_dot, pitch_dot * np.cos(roll), -pitch_dot * np.sin(roll)])


PROFILES = ["MTi-1", "MTi-3", "MTi-630"]  # IMU only, 1-series AHRS, 600-series AHRS


@pytest.mark.parametrize("model", PROFILES)
def test_rate_counters_and_sensor_model_without_noise(mock_imu, model):
    imu = mock_imu(rate_hz=50, noise=False, model=model)
    imu.start()
    samples = [imu.recv(2.0) for _ in range(60)]
    assert all(s is not None for s in samples)
    assert imu.status().configured_rate_hz == 50
    counters = [s.packet_counter for s in samples]
    assert counters == list(range(counters[0], counters[0] + len(counters)))
    ticks = np.diff([s.sample_time_fine for s in samples]) % 2**32
    assert set(ticks) == {200}  # 50 Hz on the device's 10 kHz clock
    for s in samples[::7]:
        t = (imu.true_time_ns(s.sample_time_fine) - imu.emulator.start_time_ns) * 1e-9
        expected = gait_orientation(t)
        if model == "MTi-1":  # IMU only: no orientation output
            assert s.quaternion is None
        else:
            assert abs(abs(np.dot(s.quaternion, expected)) - 1) < 1e-6
        # Acceleration: gravity seen from the sensor; rate of turn: the body rate.
        gravity = quat_to_matrix(expected).T @ [0, 0, 9.81]
        assert np.allclose(s.acceleration, gravity, atol=1e-4)
        assert np.allclose(s.rate_of_turn, body_rate(t), atol=1e-3)
        assert s.host_time_ns >= s.time_ns
    assert imu.status().state == "ok"


def test_ned_output_is_turned_into_the_same_enu_orientation(mock_imu):
    imu = mock_imu(
        rate_hz=100,
        noise=False,
        coordinate_system="NED",
        outputs=("packet_counter", "sample_time_fine", "quaternion", "euler"),
    )
    imu.start()
    samples = collect(imu, 0.5)
    assert imu.info["output_configuration"][2]["coordinate_system"] == "NED"
    for s in samples[::10]:
        t = (imu.true_time_ns(s.sample_time_fine) - imu.emulator.start_time_ns) * 1e-9
        assert abs(abs(np.dot(s.quaternion, gait_orientation(t))) - 1) < 1e-6
        assert len(s.extra["euler"]) == 3


@pytest.mark.slow
def test_drift_and_jitter_mapped_within_half_a_millisecond(mock_imu):
    imu = mock_imu(rate_hz=100, drift_ppm=50.0, jitter_ms=2.0, seed=1)
    imu.start()
    samples = collect(imu, 7.5)
    late = [s for s in samples if s.host_time_ns - samples[0].host_time_ns > 5e9]
    assert len(late) > 200
    errors_ms = np.array([s.time_ns - imu.true_time_ns(s.sample_time_fine) for s in late]) * 1e-6
    assert np.abs(errors_ms).max() < 0.5, (errors_ms.min(), errors_ms.max())
    # Raw receive times carry the wire time and the jitter: several milliseconds off.
    receive_ms = (
        np.array([s.host_time_ns - imu.true_time_ns(s.sample_time_fine) for s in late]) * 1e-6
    )
    assert receive_ms.mean() > 5.0
    details = imu.status().details
    # Over 7 s a busy host leaves the slope loose; test_imu_clock checks it closely.
    assert -50.0 < details["drift_ppm"] < 150.0
    assert details["residual_ms"] > 0.3
    assert {"offset_ms", "device_id", "missing_packets", "resyncs"} <= set(details)


def test_time_ns_is_always_an_estimate_even_for_the_first_sample(mock_imu):
    imu = mock_imu()
    imu.start()
    first = imu.recv(2.0)
    assert isinstance(first.time_ns, int)
    assert abs(first.time_ns - first.host_time_ns) < 50e6


# ----------------------------------------------------------------------------- faults


@pytest.mark.parametrize("model", PROFILES)
def test_corrupted_and_dropped_packets_are_counted(mock_imu, model):
    imu = mock_imu(rate_hz=100, model=model)
    imu.start()
    collect(imu, 0.3)
    imu.emulator.inject("corrupt", count=2)
    imu.emulator.inject("drop", count=4)
    collect(imu, 1.2)
    status = imu.status()
    assert status.details["checksum_errors"] == 2
    assert status.details["missing_packets"] == 6  # dropped, and lost to corruption
    assert status.errors == 8
    assert status.state == "degraded"
    events = kinds(imu.poll_events())
    assert "checksum_error" in events and "missing_packets" in events


@pytest.mark.parametrize("model", PROFILES)
def test_unplug_is_reported_and_replug_recovers(mock_imu, model):
    imu = mock_imu(rate_hz=100, model=model)
    imu.start()
    collect(imu, 0.3)
    imu.emulator.inject("disconnect")
    assert not os.path.exists(imu.port)
    wait_for(lambda: imu.status().state == "lost", 30.0)  # a bound only: fails on timeout
    time.sleep(0.8)
    imu.emulator.inject("reconnect")
    wait_for(lambda: imu.status().state in ("ok", "degraded"), 3.0)
    after = collect(imu, 0.5)
    assert len(after) > 30
    events = [e for e in imu.poll_events() if not e.kind.startswith("output_")]
    assert kinds(events)[:2] == ["lost", "reconnected"]
    lost, back = events[0], events[1]
    gap = back.details
    assert gap["gap_s"] == (gap["gap_end_ns"] - gap["gap_start_ns"]) * 1e-9
    assert gap["gap_start_ns"] <= lost.time_ns and gap["gap_end_ns"] == back.time_ns
    assert back.time_ns - lost.time_ns >= 0.8e9  # unplugged for the 0.8 s slept above
    assert imu.status().details["reconnects"] == 1


def test_a_hang_is_reported_and_recovers(mock_imu):
    imu = mock_imu(rate_hz=100)
    imu.start()
    collect(imu, 0.3)
    imu.emulator.inject("hang", seconds=1.5)
    wait_for(lambda: imu.status().state == "lost", 30.0)  # a bound only: fails on timeout
    wait_for(lambda: imu.status().state in ("ok", "degraded"), 5.0)
    assert len(collect(imu, 0.3)) > 15
    events = imu.poll_events()
    assert kinds(events)[:2] == ["lost", "reconnected"]
    assert events[1].details["gap_s"] > 1.4


@pytest.mark.timeout(300)
def test_a_power_cycled_device_restarts_its_clock_and_the_fit_follows(mock_imu):
    imu = mock_imu(rate_hz=100, drift_ppm=30.0, jitter_ms=1.0)
    imu.start()
    collect_n(imu, 100)  # a second of the device's samples, however long the host takes
    imu.emulator.inject("reconnect", power_cycle=True)
    deadline = time.monotonic() + 120.0
    while imu.status().details["clock_resets"] < 1:  # the samples before it are read on
        assert time.monotonic() < deadline, "no clock reset after the power cycle"
        imu.recv(0.1)
    samples = collect_n(imu, 300)  # three seconds of samples since the new clock
    assert len(samples) == 300, "too few samples after the power cycle"
    last = samples[-50:]
    errors_ms = [abs(s.time_ns - imu.true_time_ns(s.sample_time_fine)) * 1e-6 for s in last]
    assert max(errors_ms) < 1.0


def test_a_slow_consumer_loses_the_oldest_samples_counted(mock_imu):
    imu = mock_imu(rate_hz=200, buffer_size=10, model="MTi-630", baudrate=460800)
    imu.start()
    time.sleep(0.6)
    wait_for(lambda: imu.status().dropped > 0, 2.0)
    assert "drop" in kinds(imu.poll_events()) or imu.status().dropped > 0
    first = imu.recv(0.5)
    assert first is not None


def test_stop_and_close_are_idempotent_and_leave_nothing_running(mock_imu):
    imu = mock_imu()
    with imu:
        assert imu.recv(2.0) is not None
    imu.close()
    imu.stop()
    assert imu.status().state == "stopped"
    assert not imu.emulator.plugged
    assert not any(
        t.name.startswith("walkcap-imu") and t.is_alive()
        for t in __import__("threading").enumerate()
    )


def test_open_imu_mock_from_a_config():
    from devices.config import ImuConfig

    imu = open_imu(ImuConfig(rate_hz=100, drift_ppm=50.0, jitter_ms=2.0))
    try:
        assert imu.backend == "mock"
        assert (imu.emulator.drift_ppm, imu.emulator.jitter_ms) == (50.0, 2.0)
        imu.open()
        imu.start()
        sample = imu.recv(2.0)
        assert sample.quaternion.shape == (4,)
        assert abs(sample.time_ns - imu.true_time_ns(sample.sample_time_fine)) < 50e6
    finally:
        imu.close()


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_host_stall_loses_no_sample_the_port_kept(mock_imu):
    """The reader stands still 3 s (the host stalled) while the IMU streams into the port's
    buffer: afterwards every sample is read, in order, and nothing is 'lost' or reopened."""
    imu = mock_imu(rate_hz=100)
    imu.start()
    first = collect_n(imu, 50)
    port, stalled = imu.link.serial, threading.Event()
    real_read = port.read

    def read(n=1):
        if not stalled.is_set():
            stalled.set()
            time.sleep(3.0)  # the injected stall; any longer (a loaded machine) is the same
        return real_read(n)

    port.read = read
    after = collect_n(imu, 500)  # the 3 s the port kept, then more
    assert stalled.is_set() and len(after) == 500
    counters = [s.packet_counter for s in first + after]
    assert all((b - a) % 65536 == 1 for a, b in zip(counters, counters[1:], strict=False))
    assert imu.missing_packets == 0
    assert not {"lost", "reconnected"} & set(kinds(imu.poll_events()))
    assert imu.status().details["clock_resets"] == 0
