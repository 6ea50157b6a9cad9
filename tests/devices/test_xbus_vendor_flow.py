"""The emulator and the driver held to what Xsens' own host library does and expects.

The conformance flow follows xspublic (Xsens' public host library, xscontroller), as its
SDK example and ROS driver drive a device: open (GoToConfig, DeviceID, ProductCode,
HardwareVersion, FirmwareRev, InitBus, ReqConfiguration in the vendor's layout), the
read-outs a session reads (option flags, location id, filter profiles, alignment rotation),
configure as the example does (timestamps and status at 0), measure, and change the baud
rate. It runs in pure Python against every emulated family, so a machine without the vendor
source checks the protocol too (tests/devices/test_xspublic_probe.py runs the vendor's library).
The parsing below is written from the vendor's documented layouts, not taken from it.
"""

import os
import struct
import subprocess
import sys
import tempfile
import time

import pytest
import serial

from devices import xbus
from devices.errors import DeviceInitError
from devices.imu import XbusImu, device_id_text
from devices.imu import family as imu_family
from devices.imu.emulator import PORT_NAME_MAX, ImuEmulator
from devices.xbus import MID

pytestmark = [pytest.mark.timeout(120), pytest.mark.realtime]

# One model of every family the emulator plays.
FAMILIES = ["MTi-1", "MTi-3", "MTi-20", "MTi-300", "MTi-320", "MTi-630"]


class Host:
    """The host end of the line, asking as Xsens' library does (one request, one reply; an
    Error other than a data overflow is the reply, MidReplyObject::isReplyFor)."""

    def __init__(self, port: str, baudrate: int = 115200):
        self.port = serial.Serial(port, baudrate, timeout=0.02)
        self.parser = xbus.XbusParser()
        self.packets: list[xbus.MTData2] = []

    def ask(self, mid: int, data: bytes = b"", reply: int | None = None, timeout=5.0):
        reply = mid + 1 if reply is None else reply
        self.port.write(xbus.build(mid, data))
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for msg in self.parser.feed(self.port.read(4096)):
                if msg.mid == MID.MTDATA2 and msg.mtdata2 is not None:
                    self.packets.append(msg.mtdata2)
                elif msg.mid == reply:
                    return msg.data
                elif msg.mid == MID.ERROR and msg.data[:1] != b"\x29":
                    raise AssertionError(f"{xbus.mid_name(mid)}: {xbus.error_text(msg.data[0])}")
        raise AssertionError(f"no answer to {xbus.mid_name(mid)}")

    def receive(self, count: int, timeout: float = 30.0) -> list[xbus.MTData2]:
        deadline = time.monotonic() + timeout
        while len(self.packets) < count and time.monotonic() < deadline:
            for msg in self.parser.feed(self.port.read(4096)):
                if msg.mid == MID.MTDATA2 and msg.mtdata2 is not None:
                    self.packets.append(msg.mtdata2)
        return self.packets

    def close(self):
        self.port.close()


def device_id_of(data: bytes) -> int:
    """As DeviceCommunicator reads a DeviceID: 4 bytes, or 8 as one 64-bit value when
    either half is a 64-bit id."""
    if len(data) == 8:
        high, low = struct.unpack(">II", data)
        return int.from_bytes(data, "big") if (high | low) & 0x8000_0000 else high
    return struct.unpack(">I", data[:4])[0]


def read_configuration(data: bytes) -> dict:
    """The fields XsDeviceConfiguration_readFromMessage takes from a Configuration message."""
    n_devices = struct.unpack_from(">H", data, 96)[0]
    master = struct.unpack_from(">I", data, 0)[0]
    out = {"devices": n_devices, "master_id": master, "product_code": b""}
    if master & 0x8000_0000:  # a 64-bit id: the high half at 4, the product code at 32
        out["master_id"] |= struct.unpack_from(">I", data, 4)[0] << 32
        out["product_code"] = data[32:52]
    out["device"] = []
    for i in range(n_devices):
        base = 98 + 20 * i
        did = struct.unpack_from(">I", data, base)[0]
        if did & 0x8000_0000:
            did |= struct.unpack_from(">I", data, base + 4)[0] << 32
        profile, major, minor, rev = struct.unpack_from(">HBBB", data, base + 12)
        out["device"].append({"id": did, "profile": profile, "firmware": (major, minor, rev)})
    assert len(data) == 98 + 20 * n_devices
    return out


def read_filter_profiles(data: bytes) -> list[tuple[int, int, str]]:
    """ReqAvailableFilterProfiles: records of type, version and a 20-byte label."""
    size = 1 + 1 + 20
    assert len(data) % size == 0
    return [
        (data[i], data[i + 1], data[i + 2 : i + size].decode("ascii").strip())
        for i in range(0, len(data), size)
    ]


@pytest.mark.parametrize("model", FAMILIES)
def test_the_vendor_flow_opens_configures_measures_and_changes_the_baud_rate(model):
    code, device_id, family = imu_family.emulated_model(model)
    with ImuEmulator(model=model, rate_hz=100) as emulator:
        host = Host(emulator.port)
        try:
            # ---- open: what XsControl::openPort reads
            host.ask(MID.GOTO_CONFIG)
            assert device_id_of(host.ask(MID.REQ_DID)) == device_id
            product = host.ask(MID.REQ_PRODUCT_CODE)
            assert len(product) == 20 and product == code.encode().ljust(20, b" ")
            hardware = struct.unpack(">H", host.ask(MID.REQ_HARDWARE_VERSION))[0]
            assert hardware >> 8 >= 1
            firmware = host.ask(MID.REQ_FW_REV)
            assert device_id_of(host.ask(MID.INIT_MT)) == device_id
            config = read_configuration(host.ask(MID.REQ_CONFIGURATION))
            assert config["devices"] == 1 and config["master_id"] == device_id
            assert config["device"][0]["id"] == device_id
            assert config["device"][0]["firmware"] == tuple(firmware[:3])
            if device_id & 0x8000_0000:
                assert config["product_code"] == product
            # ---- the read-outs of a session
            assert len(host.ask(MID.REQ_OPTION_FLAGS)) == 4
            assert len(host.ask(MID.REQ_LOCATION_ID)) == 2
            profiles = read_filter_profiles(host.ask(MID.REQ_AVAILABLE_FILTER_PROFILES))
            assert (profiles == []) == (family.function == "IMU")
            current = host.ask(MID.REQ_FILTER_PROFILE)
            if profiles and current[:1] != b"\x00":  # a label ("Robust/NorthReference")
                labels = {label for _, _, label in profiles}
                assert set(current.decode().split("/")) <= labels
            elif profiles:
                assert struct.unpack(">H", current)[0] in {t for t, _, _ in profiles}
            for frame in (0, 1):
                rotation = host.ask(MID.REQ_ALIGNMENT_ROTATION, bytes([frame]))
                assert rotation[0] == frame
                assert struct.unpack(">4f", rotation[1:]) == (1.0, 0.0, 0.0, 0.0)
            host.ask(MID.REQ_STRING_OUTPUT_TYPE, b"\x00\x00")  # as setOutputConfiguration
            # ---- configure as example_mti_receive_data and the ROS driver ask
            names = ["packet_counter", "sample_time_fine", "utc_time", "status_word"]
            request = [xbus.OutputSetting(xbus.XDI[n], 0) for n in names]
            data = ["acceleration", "rate_of_turn"]
            if family.has_orientation:
                data.insert(0, "quaternion")
            request += [xbus.OutputSetting(xbus.XDI[n], 100) for n in data]
            granted = xbus.decode_output_configuration(
                host.ask(MID.SET_OUTPUT_CONFIGURATION, xbus.encode_output_configuration(request))
            )
            assert {s.name: s.rate_hz for s in granted} == {
                **{n: 0xFFFF for n in names},
                **{n: 100 for n in data},
            }
            # ---- measure
            host.ask(MID.GOTO_MEASUREMENT)
            packets = host.receive(150)
            host.ask(MID.GOTO_CONFIG)
            assert len(packets) >= 150
            counters = [p.values["packet_counter"] for p in packets]
            assert all((b - a) & 0xFFFF == 1 for a, b in zip(counters, counters[1:]))
            assert all(set(p.values) == set(names) | set(data) for p in packets)
        finally:
            host.close()
        # ---- change the baud rate (SetBaudrate 0x80 for 921600, Reset, find it again)
        XbusImu(emulator.port, 115200).change_baudrate(921600)
        assert emulator.baudrate == 921600
        imu = XbusImu(emulator.port, 921600, 100)
        try:
            imu.open()
            assert imu.info["device_id"] == device_id_text(device_id.to_bytes(4, "big"))
        finally:
            imu.close()


# ---- case by case ----------------------------------------------------------------------------


def test_set_baud_921600_sends_the_code_xsens_library_sends():
    """xsbaud.c (XsBaud_rateToCode) sends XBC_921k6Legacy (0x80); 0x0A is "only usable from
    MTi/x FW 2.4.6" (xsbaudcode.h)."""
    with ImuEmulator(model="MTi-3") as emulator:
        sent = []
        handle = emulator._handle

        def spy(msg, t):
            if msg.mid == MID.REQ_BAUDRATE and msg.data:
                sent.append(msg.data)
            handle(msg, t)

        emulator._handle = spy
        XbusImu(emulator.port, 115200).change_baudrate(921600)
    assert sent == [b"\x80"]


def test_set_baud_finds_a_device_that_boots_slower_than_two_seconds():
    """After the Reset the device is silent while it boots (Xsens' scanner waits 2 s and
    then scans): the driver keeps asking at the new rate within a bounded time."""
    with ImuEmulator(model="MTi-3", reset_s=3.0) as emulator:
        XbusImu(emulator.port, 115200, reset_timeout_s=30.0).change_baudrate(460800)
        assert emulator.baudrate == 460800


def test_set_baud_says_when_the_device_kept_its_old_rate():
    with ImuEmulator(model="MTi-3") as emulator:
        emulator._pending_baudrate = None
        handle = emulator._handle

        def forgetful(msg, t):  # acknowledges SetBaudrate, keeps its rate
            handle(msg, t)
            emulator._pending_baudrate = None

        emulator._handle = forgetful
        with pytest.raises(DeviceInitError, match="still answers at 115200 baud, not 460800"):
            XbusImu(emulator.port, 115200, reset_timeout_s=1.0).change_baudrate(460800)


@pytest.mark.parametrize("reply_to", ["open", "set-baud"])
def test_a_data_overflow_ahead_of_a_reply_is_an_event_not_the_reply(reply_to):
    """MidReplyObject::isReplyFor (replyobject.cpp) takes any Error as the reply except
    XRV_DATAOVERFLOW (0x29), which a device sends on its own."""
    with ImuEmulator(model="MTi-3") as emulator:
        emulator.inject("error", code=xbus.DATA_OVERFLOW)  # ahead of the GoToConfigAck
        imu = XbusImu(emulator.port, 115200, outputs=None)
        if reply_to == "open":
            imu.open()
            imu.close()
            assert imu.info["product_code"] == "MTi-3-8A7G6"
        else:
            imu.change_baudrate(230400)
            assert emulator.baudrate == 230400
    assert imu.device_errors == 1
    events = imu.poll_events()
    assert [e.details["code"] for e in events if e.kind == "device_error"] == [0x29]


def test_any_other_error_ahead_of_a_reply_is_the_reply():
    with ImuEmulator(model="MTi-3") as emulator:
        emulator.inject("error", code=xbus.INVALID_PARAMETER)
        with pytest.raises(DeviceInitError, match="answered GoToConfig with Error 0x21"):
            XbusImu(emulator.port, 115200, outputs=None).open()


@pytest.mark.parametrize("model", ["MTi-3", "MTi-630", "MTi-320"])
def test_the_product_code_is_20_characters_padded_with_spaces(model):
    """MtDevice::productCode copies 20 bytes and cuts at the first space (mtdevice.cpp)."""
    code, _, _ = imu_family.emulated_model(model)
    with ImuEmulator(model=model) as emulator:
        host = Host(emulator.port)
        try:
            host.ask(MID.GOTO_CONFIG)
            assert host.ask(MID.REQ_PRODUCT_CODE) == code.encode().ljust(20, b" ")
        finally:
            host.close()
        imu = XbusImu(emulator.port, 115200, outputs=None)
        imu.open()
        imu.close()
    assert imu.info["product_code"] == code


def test_the_port_path_fits_the_32_bytes_xsens_tools_keep_even_under_a_long_tmpdir(
    tmp_path, monkeypatch
):
    """serialinterface.h keeps the port name in char m_portname[32]."""
    long_tmp = tmp_path / ("t" * 60)
    long_tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(long_tmp))
    with ImuEmulator(model="MTi-3") as emulator:
        port = emulator.port
        assert len(port) < PORT_NAME_MAX
        emulator.inject("disconnect", seconds=0.2)
        emulator.inject("reconnect")
        assert emulator.port == port  # stable across a replug
        imu = XbusImu(port, 115200, outputs=None)
        imu.open()
        imu.close()


@pytest.mark.subprocess
def test_walkcap_imu_emulate_prints_a_short_port_path(tmp_path):
    long_tmp = tmp_path / ("t" * 60)
    long_tmp.mkdir()
    out = subprocess.run(
        [sys.executable, "-m", "tui.cli", "imu", "emulate", "--seconds", "0.3"],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "TMPDIR": str(long_tmp), "HOME": str(tmp_path)},
    )
    assert out.returncode == 0, out.stderr
    port = out.stdout.splitlines()[0]
    assert port.endswith("/ttyIMU") and len(port) < PORT_NAME_MAX


def test_the_mti_320_is_a_3x0_device_with_100_hz_bases_and_slow_writes():
    """mti3x0device.cpp: Mti3X0Device, 100 Hz bases, a 2000 ms default timeout ("a settings
    write can occasionally take ~900ms"); xsdid.h: type 0x00D0_0000, function in GPL."""
    family = imu_family.family_of("MTi-320")
    assert (family.name, family.function) == ("MTi-3X0 series", "VRU")
    assert family.max_rate() == 100 and family.settings_write_s == pytest.approx(0.9)
    assert imu_family.family_of("MTi-300-2A8G4").name == "MTi-100 series"
    assert imu_family.family_of("MTi-330").function == "AHRS"
    _, device_id, _ = imu_family.emulated_model("MTi-320")
    assert device_id & 0x00F0_0000 == 0x00D0_0000 and device_id & 0x0F00_0000 == 0x0200_0000
    imu = XbusImu("/dev/null", 115200)
    imu.family = family
    assert imu._settings_timeout_s() >= 2.0


def test_an_8_byte_device_id_is_shown_as_xsens_library_shows_it():
    """DeviceCommunicator reads 8 bytes as one 64-bit id when either half is a 64-bit id
    (devicecommunicator.cpp); XsDeviceId_toString prints it in 10 hex digits."""
    with ImuEmulator(model="MTi-630", device_id_size=8) as emulator:
        imu = XbusImu(emulator.port, 115200, outputs=None)
        imu.open()
        imu.close()
    assert imu.info["device_id"] == "0080001236"
    assert device_id_text(bytes.fromhex("03881234")) == "03881234"
    assert device_id_text(bytes.fromhex("0388123400000000")) == "03881234"


def test_a_reported_0xffff_is_every_packet_for_the_status_word_too():
    """What a device reports at 0xFFFF has "no maximum frequency, but is sent along with
    appropriate packets" (xsoutputconfiguration.h): `walkcap imu info` says so."""
    setting = xbus.OutputSetting(xbus.XDI["status_word"], 0xFFFF)
    assert setting.describe()["rate_hz"] == "every packet"
