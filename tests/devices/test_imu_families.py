"""The driver against each emulated family: granted rates, refused outputs, link budget.

Profiles: an IMU-only 1-series (MTi-1), a VRU/AHRS 1-series (MTi-2, MTi-3), a 600-series
(MTi-630, MTi-610) and an MTi-20 (status group at 2000 Hz). Facts: devices/imu/family.py.
"""

import time

import numpy as np
import pytest
import serial

from devices import xbus
from devices.errors import DeviceInitError
from devices.imu import XbusImu
from devices.imu import family as imu_family
from devices.imu.emulator import ImuEmulator
from devices.xbus import MID
from tests.devices.imu_streams import collect, collect_n

pytestmark = [pytest.mark.timeout(60), pytest.mark.realtime]

PROFILES = ["MTi-1", "MTi-3", "MTi-630"]


class Line:
    """The host side of the emulator's serial line, by hand."""

    def __init__(self, emulator, baudrate=115200):
        self.port = serial.Serial(emulator.port, baudrate, timeout=0.02)
        self.parser = xbus.XbusParser()

    def ask(self, mid, data=b"", reply=None, timeout=2.0):
        self.port.write(xbus.build(mid, data))
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for msg in self.parser.feed(self.port.read(4096)):
                if msg.mid in (reply, MID.ERROR):
                    return msg
        return None

    def configure(self, settings):
        assert self.ask(MID.GOTO_CONFIG, reply=MID.GOTO_CONFIG_ACK) is not None
        return self.ask(
            MID.SET_OUTPUT_CONFIGURATION,
            xbus.encode_output_configuration(settings),
            reply=MID.OUTPUT_CONFIGURATION,
        )

    def close(self):
        self.port.close()


# ---- the family table ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "code, family, function",
    [
        ("MTi-1-8A7G6", "MTi-1 series", "IMU"),
        ("MTi-2-8A7G6", "MTi-1 series", "VRU"),
        ("MTi-3-8A7G6", "MTi-1 series", "AHRS"),
        ("MTi-7-8A7G6", "MTi-1 series", "GNSS/INS"),
        ("MTi-30-2A8G4", "MTi-10 series", "AHRS"),
        ("MTi-100-2A8G4", "MTi-100 series", "IMU"),
        ("MTi-G-710-2A8G4", "MTi-G-700 series", "GNSS/INS"),
        ("MTi-610", "MTi-600 series", "IMU"),
        ("MTi-630 ", "MTi-600 series", "AHRS"),
        ("MTi-680G", "MTi-600 series", "GNSS/INS"),
    ],
)
def test_the_family_and_function_come_from_the_product_code(code, family, function):
    f = imu_family.family_of(code)
    assert (f.name, f.function) == (family, function)
    assert f.has("quaternion") == (function != "IMU")


def test_rates_are_divisors_of_the_base():
    one = imu_family.family_of("MTi-3")
    assert one.rates(xbus.XDI["quaternion"]) == (100, 50, 25, 20, 10, 5, 4, 2, 1)
    six = imu_family.family_of("MTi-630")
    assert 125 not in six.rates(xbus.XDI["acceleration"])
    assert six.fit(xbus.XDI["acceleration"], 125) == 100
    assert six.fit(xbus.XDI["magnetic_field"], 400) == 100
    assert six.fit(xbus.XDI["status_word"], 400) == 400  # an explicit rate: fitted
    assert six.fit(xbus.XDI["acceleration"], xbus.EVERY_PACKET) == 400  # the maximum
    assert six.fit(xbus.XDI["packet_counter"], xbus.EVERY_PACKET) == xbus.EVERY_PACKET
    assert imu_family.family_of("MTi-20").fit(xbus.XDI["status_word"], 1000) == 1000
    assert imu_family.family_of("Something") is None


# ---- configure and stream against each family ------------------------------------------------


@pytest.mark.parametrize("model", PROFILES)
def test_configures_and_streams_what_the_family_has(mock_imu, model):
    imu = mock_imu(model=model, rate_hz=100)
    imu.start()
    samples = collect(imu, 0.5)
    request = imu.emulator.settings.last_output_request
    # Nothing but the timestamp group at 0xFFFF; the status word at the data rate.
    assert {s.name for s in request if s.rate_hz == xbus.EVERY_PACKET} == {
        "packet_counter",
        "sample_time_fine",
    }
    assert {s.name: s.rate_hz for s in request}["status_word"] == 100
    assert imu.configured_rate_hz == 100 and not imu.info["granted"]
    assert len(samples) >= 35
    has_orientation = model != "MTi-1"
    assert all((s.quaternion is not None) == has_orientation for s in samples)
    assert all(s.acceleration is not None and s.rate_of_turn is not None for s in samples)
    if not has_orientation:
        assert "quaternion" not in {s.name for s in request}
        assert any("leveling needs a VRU or AHRS" in a for a in imu.info["adjusted"])
    assert imu.info["function"] == imu_family.family_of(imu.info["product_code"]).function


@pytest.mark.parametrize(
    "model, requested, used", [("MTi-3", 125, 100), ("MTi-630", 125, 100), ("MTi-630", 300, 200)]
)
def test_a_rate_the_family_lacks_becomes_one_it_has_and_is_said(mock_imu, model, requested, used):
    imu = mock_imu(model=model, rate_hz=min(requested, 100), baudrate=921600)
    imu.rate_hz = requested  # what the session asks for
    imu._settings = xbus.output_settings(xbus.DEFAULT_OUTPUTS, requested)
    imu.open()
    assert imu.configured_rate_hz == used
    assert any(f"at {used} Hz, not {requested} Hz" in a for a in imu.info["adjusted"])


def test_what_the_device_grants_instead_is_said(mock_imu):
    """A product code the driver does not know: it asks for 125 Hz as configured; the
    device (a 1-series) uses 100 Hz, and the driver says so and runs at 100 Hz."""
    imu = mock_imu(model="MTi-3", rate_hz=100)
    imu.emulator.settings.product_code = "MTi-X-PROTOTYPE"
    imu._settings = xbus.output_settings(xbus.DEFAULT_OUTPUTS, 125)
    imu.open()
    assert imu.family is None
    assert "quaternion: asked for 125 Hz, the device uses 100 Hz" in imu.info["granted"]
    assert imu.configured_rate_hz == 100
    assert "output_granted" in [e.kind for e in imu.poll_events()]


def test_the_default_mock_is_an_mti3_at_115200_and_100_hz(mock_imu):
    imu = mock_imu()
    imu.open()
    assert imu.info["product_code"].startswith("MTi-3")
    assert (imu.baudrate, imu.configured_rate_hz) == (115200, 100)
    assert imu.budget.fits and 0.5 < imu.budget.load < 0.8


# ---- the link budget -------------------------------------------------------------------------


def test_output_beyond_the_baud_rate_is_refused_naming_what_fits(mock_imu):
    imu = mock_imu(model="MTi-630", rate_hz=400, baudrate=115200)
    with pytest.raises(DeviceInitError) as e:
        imu.open()
    line = str(e.value)
    assert "\n" not in line
    assert "400 messages/s" in line and "115200 baud" in line
    assert "baudrate = 460800" in line and "rate_hz = 100" in line
    assert MID.GOTO_MEASUREMENT not in imu.emulator.requests  # refused before measuring


def test_400_hz_on_a_600_series_at_921600_streams(mock_imu):
    imu = mock_imu(model="MTi-630", rate_hz=400, baudrate=921600)
    imu.start()
    samples = collect_n(imu, 400)  # a second of samples, however long the host takes
    assert imu.configured_rate_hz == 400 and len(samples) == 400
    # 400 Hz on the device's own clock, every packet counted
    periods = np.diff([s.sample_time_fine for s in samples])  # SampleTimeFine: 10 kHz ticks
    assert np.all(periods == 25) and imu.missing_packets == 0


def test_the_emulator_overflows_and_reports_0x29_when_the_line_is_too_slow():
    with ImuEmulator(model="MTi-630", rate_hz=100, baudrate=115200) as emulator:
        line = Line(emulator)
        try:
            ack = line.configure(xbus.output_settings(xbus.DEFAULT_OUTPUTS, 400))
            assert ack.mid == MID.OUTPUT_CONFIGURATION
            line.port.write(xbus.build(MID.GOTO_MEASUREMENT))
            errors, deadline = [], time.monotonic() + 2.0
            while not errors and time.monotonic() < deadline:
                errors = [m for m in line.parser.feed(line.port.read(4096)) if m.mid == MID.ERROR]
        finally:
            line.close()
    assert errors and errors[0].data[0] == 0x29
    assert emulator.line.overflowed > 0
    assert "data overflow" in xbus.error_text(errors[0].data[0])


def test_an_emulator_thread_catching_up_after_the_host_starved_it_loses_no_sample():
    """Samples taken 2.5 ms apart that a starved emulator thread hands to the wire in one go:
    each left the device's buffer long before the next, so none overflows (an overflow is
    the line being too slow, not this thread being late)."""
    emulator = ImuEmulator(model="MTi-630", rate_hz=400, baudrate=921600)  # not started
    frame = xbus.build(MID.MTDATA2, bytes(60))
    t0 = 10**12
    emulator._power_up(t0)
    for k in range(400):  # a second of samples at once
        emulator.line.transmit(frame, t0 + k * 2_500_000)
    assert emulator.line.overflowed == 0
    assert len(emulator.line.out) + sum(len(f) for _, f in emulator.line.queue) == 400 * len(frame)


# ---- the emulator's rules --------------------------------------------------------------------


@pytest.mark.parametrize("model", ["MTi-3", "MTi-630", "MTi-20", "MTi-320"])
@pytest.mark.parametrize("status", [0, 0xFFFF])
def test_timestamps_and_the_status_word_ride_along_and_0xffff_is_the_maximum_else(model, status):
    """As Xsens' example and ROS driver ask: timestamps (UtcTime too) and the status word at
    0 ride along with every packet, reported as 0xFFFF ("no maximum frequency, sent along
    with appropriate packets", xsoutputconfiguration.h); so does the status word at 0xFFFF
    (not a flood of status-only messages at the group's maximum); acceleration at 0xFFFF
    runs at its maximum."""
    with ImuEmulator(model=model, baudrate=921600) as emulator:
        line = Line(emulator, 921600)
        try:
            settings = [
                xbus.OutputSetting(xbus.XDI["packet_counter"], 0),
                xbus.OutputSetting(xbus.XDI["sample_time_fine"], 0),
                xbus.OutputSetting(xbus.XDI["utc_time"], 0),
                xbus.OutputSetting(xbus.XDI["status_word"], status),
                xbus.OutputSetting(xbus.XDI["acceleration"], 0xFFFF),
            ]
            ack = line.configure(settings)
            assert ack.mid == MID.OUTPUT_CONFIGURATION, xbus.error_text(ack.data[0])
            line.port.write(xbus.build(MID.GOTO_MEASUREMENT))
            packets, deadline = [], time.monotonic() + 10.0
            while len(packets) < 20 and time.monotonic() < deadline:
                packets += [
                    m.mtdata2.values
                    for m in line.parser.feed(line.port.read(4096))
                    if m.mid == MID.MTDATA2
                ]
        finally:
            line.close()
    granted = {s.name: s.rate_hz for s in xbus.decode_output_configuration(ack.data)}
    assert granted == {
        "packet_counter": 0xFFFF,
        "sample_time_fine": 0xFFFF,
        "utc_time": 0xFFFF,
        "status_word": 0xFFFF,
        "acceleration": imu_family.family_of(model).max_rate(),
    }
    assert len(packets) >= 20
    assert all(set(p) == set(granted) for p in packets)  # every output in every packet


def _configure(model: str, outputs: list[str], rate_hz: int):
    """The reply of a fresh emulated `model` to one output configuration."""
    with ImuEmulator(model=model) as emulator:
        line = Line(emulator)
        try:
            return line.configure(xbus.output_settings(outputs, rate_hz))
        finally:
            line.close()


def test_the_emulator_grants_the_rate_it_uses_in_the_ack():
    ack = _configure("MTi-3", ["packet_counter", "acceleration"], 125)
    assert ack.mid == MID.OUTPUT_CONFIGURATION
    assert {s.name: s.rate_hz for s in xbus.decode_output_configuration(ack.data)} == {
        "packet_counter": 0xFFFF,
        "acceleration": 100,
    }


def test_an_imu_only_model_refuses_orientation_outputs():
    reply = _configure("MTi-1", ["packet_counter", "quaternion"], 100)
    assert reply.mid == MID.ERROR and reply.data[0] == xbus.INVALID_PARAMETER


def test_a_slow_settings_write_is_waited_for(mock_imu):
    imu = mock_imu(model="MTi-3", settings_write_s=0.9)  # the SDK's figure for the 1-series
    start = time.monotonic()
    imu.open()
    assert time.monotonic() - start >= 0.9
    assert imu._settings_timeout_s() >= 1.8


def test_the_emulator_keeps_its_baud_rate_until_told_and_reset():
    with ImuEmulator(model="MTi-3", baudrate=115200) as emulator:
        with pytest.raises(DeviceInitError, match="no answer to GoToConfig"):
            XbusImu(emulator.port, 921600, config_timeout_s=0.5).open()  # another rate
        XbusImu(emulator.port, 115200).change_baudrate(460800)
        assert emulator.baudrate == 460800
        with pytest.raises(DeviceInitError, match="no answer to GoToConfig"):
            XbusImu(emulator.port, 115200, config_timeout_s=0.5).open()
        imu = XbusImu(emulator.port, 460800)
        try:
            imu.open()
            assert imu.info["baudrate"] == 460800
        finally:
            imu.close()


def test_set_baud_refuses_a_rate_an_mti_lacks():
    with pytest.raises(DeviceInitError, match="not a baud rate an MTi has"):
        XbusImu("/dev/null", 115200).change_baudrate(12345)
