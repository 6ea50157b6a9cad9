"""An Xsens-style IMU on a pseudo-terminal: the mock backend is the real driver against this.

The emulator is the device side of a serial line. It opens a pty, points a stable path
(/tmp/walkcap-XXXXXXXX/ttyIMU, a symlink; short, as Xsens' tools keep a port name in 32
bytes) at the slave end, and speaks Xbus on the master end: it answers what a device of
its family answers on open and configuration, so that Xsens' own host library (xspublic)
opens it (DeviceID, a 20-character ProductCode, HardwareVersion, FirmwareRev, InitBus,
ReqConfiguration in the vendor's layout, option flags, location id, filter profiles,
alignment rotation, string output type), streams MTData2 at the configured rate
from its own clock (which drifts against the host's by `drift_ppm`), paces each message
by its wire time at `baudrate` plus random transmit jitter, and injects faults on command.
Unplugging removes the symlink and closes the pty; replugging opens a new pty and
re-points the symlink, as udev would, so the driver reopens the same path.

Its orientation comes from `orientation_at(t)` (seconds since start -> [w, x, y, z],
sensor -> world (ENU)): the simulated walk's thigh when the mock camera runs, else a
simple gait-like swing. Acceleration is gravity in the sensor frame, rate of turn the
orientation's derivative, both with noise and bias.

It plays one model (`model`, `[imu] emulate`: "MTi-3", "MTi-630", "MTi-1", ...) by that
family's rules (devices/imu_family.py): it grants each output the rate the family has
(the ack carries the rates it uses, as a device's does; timestamps, UtcTime among them,
and the status word asked at 0 or 0xFFFF go with every message, reported as 0xFFFF),
answers Error 0x21 (invalid
parameter) for an output the model lacks (an IMU-only model has no orientation), takes
its time over settings writes, keeps its baud rate until SetBaudrate and a Reset change
it (it then boots for `reset_s`, deaf and silent, before its WakeUp), and hears only a
host whose line runs at that rate. Output beyond what the baud rate
carries fills its buffer: messages are lost and it reports Error 0x29 (data overflow).
How a firmware rounds an unsupported rate is not documented publicly: the emulator grants
the highest supported rate not above the request.

Runs in a daemon thread of the calling process (tests, the mock backend) or standalone
(`walkcap imu emulate`).
"""

from __future__ import annotations

import collections
import dataclasses
import datetime
import errno
import fcntl
import logging
import os
import queue
import select
import shutil
import struct
import tempfile
import termios
import threading
import time
import tty
from collections.abc import Callable

import numpy as np

from devices import imu_family, xbus
from devices.clock import now_ns
from devices.orientation_error import OrientationError, OrientationErrorModel
from devices.rotations import (
    matrix_to_quat,
    quat_conjugate,
    quat_from_euler,
    quat_multiply,
    quat_normalize,
    quat_to_euler,
    quat_to_matrix,
)
from devices.xbus import MID

log = logging.getLogger(__name__)

GRAVITY = 9.81  # m/s^2
MAGNETIC_FIELD_ENU = np.array([0.0, 0.42, -0.91])  # arbitrary units: north and down
FAULTS = ("corrupt", "drop", "hang", "disconnect", "reconnect", "error")
# Requests a device in measurement mode accepts; the rest need GoToConfig first.
_MEASUREMENT_OK = frozenset(
    {MID.GOTO_CONFIG, MID.GOTO_MEASUREMENT, MID.RESET, MID.REQ_DID, MID.WAKEUP_ACK}
)
_SPIN_NS = 200_000
_SPEEDS = {getattr(termios, f"B{b}"): b for b in xbus.BAUDRATES if hasattr(termios, f"B{b}")}
_OVERFLOW_REPORT_NS = 1_000_000_000  # Error 0x29 at most once a second
INVALID_FILTER_PROFILE = 0x31


# Xsens' host library copies the port name into a 32-byte buffer (serialinterface.h,
# m_portname[32]): a path must stay below this length, the terminating zero included.
PORT_NAME_MAX = 32


def _short_tmp() -> str:
    """/tmp where it is writable: a port path under a long $TMPDIR would not fit the 32
    bytes Xsens' tools keep for it."""
    if os.path.isdir("/tmp") and os.access("/tmp", os.W_OK | os.X_OK):
        return "/tmp"
    return tempfile.gettempdir()


def _precise_timers() -> None:
    """Wake this thread on time: Linux lets a sleep overrun by its timer slack (50 us by
    default); a device sends on its own clock, so the emulator asks for 1 us."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(29, 1000, 0, 0, 0)  # PR_SET_TIMERSLACK, this thread only
    except (OSError, AttributeError):
        pass


def gait_orientation(t: float) -> np.ndarray:
    """A thigh swinging at 0.9 Hz: pitch about -5 +- 25 degrees, a little roll."""
    phase = 2 * np.pi * 0.9 * t
    flexion = np.radians(5.0 + 25.0 * np.sin(phase) + 3.0 * np.sin(2 * phase))
    roll = np.radians(2.0 * np.sin(phase))
    return quat_from_euler(roll, -flexion, 0.0)


@dataclasses.dataclass(frozen=True)
class EmulatorClock:
    """The emulator's device clock against the session clock (10 kHz ticks, drifting).

    A value, so the host can check sync against it from another process (the mock rig).
    """

    t0_ns: int  # session time at ...
    epoch_ticks: int  # ... which the device clock read this many ticks
    drift_ppm: float

    def ticks_at(self, t_ns: int) -> float:
        """Device clock (SampleTimeFine ticks, unwrapped) at a session time."""
        return self.epoch_ticks + (t_ns - self.t0_ns) * (1 + self.drift_ppm * 1e-6) / 1e5

    def time_of_ticks(self, ticks: float) -> int:
        return self.t0_ns + round((ticks - self.epoch_ticks) * 1e5 / (1 + self.drift_ppm * 1e-6))

    def true_time_ns(self, sample_time_fine: int, now: int) -> int:
        """When the sample stamped sample_time_fine (wrapping) was taken, seen at `now`."""
        wraps = round((self.ticks_at(now) - sample_time_fine) / 2**32)
        return self.time_of_ticks(sample_time_fine + wraps * 2**32)


@dataclasses.dataclass(frozen=True)
class FilterProfile:
    kind: int  # a number on older families; XFPK_Base 195 / XFPK_Heading 197 on the 600
    version: int
    label: str  # at most 20 characters (XS_LEN_FILTERPROFILELABEL)


@dataclasses.dataclass(frozen=True)
class DeviceFacts:
    """What a device of a family answers about itself beyond its outputs. The vendor's
    library reads these on open; the values are typical ones, not any unit's."""

    hardware_version: int  # major << 8 | minor (ReqHardwareVersion)
    profiles: tuple[FilterProfile, ...]  # AHRS and VRU profiles, the first current
    vru_profiles: tuple[FilterProfile, ...]  # a VRU model lists these only
    named_profiles: bool = False  # ReqFilterProfile answers a label ("Robust/VRU")


_ONE_SERIES_PROFILES = (
    FilterProfile(50, 1, "general"),
    FilterProfile(51, 1, "high_mag_dep"),
    FilterProfile(52, 1, "dynamic"),
    FilterProfile(53, 1, "north_reference"),
    FilterProfile(54, 1, "vru_general"),
)
_MK4_PROFILES = (
    FilterProfile(39, 1, "general"),
    FilterProfile(40, 1, "high_mag_dep"),
    FilterProfile(41, 1, "dynamic"),
    FilterProfile(42, 1, "low_mag_dep"),
    FilterProfile(43, 1, "vru_general"),
)
_600_BASE = (FilterProfile(195, 1, "Robust"), FilterProfile(195, 1, "Responsive"))
_DEVICE_FACTS = {
    "MTi-1 series": DeviceFacts(0x0300, _ONE_SERIES_PROFILES, _ONE_SERIES_PROFILES[4:]),
    "MTi-3X0 series": DeviceFacts(0x0200, _ONE_SERIES_PROFILES, _ONE_SERIES_PROFILES[4:]),
    "MTi-10 series": DeviceFacts(0x0200, _MK4_PROFILES, _MK4_PROFILES[4:]),
    "MTi-100 series": DeviceFacts(0x0200, _MK4_PROFILES, _MK4_PROFILES[4:]),
    "MTi-G-700 series": DeviceFacts(0x0200, _MK4_PROFILES, _MK4_PROFILES[4:]),
    "MTi-600 series": DeviceFacts(
        0x0100,
        (*_600_BASE, FilterProfile(197, 1, "NorthReference"), FilterProfile(197, 1, "VRU")),
        (*_600_BASE, FilterProfile(197, 1, "VRU")),
        named_profiles=True,
    ),
}


def _profiles_of(facts: DeviceFacts, function: str) -> tuple[FilterProfile, ...]:
    if function == "IMU":
        return ()  # no attitude filter, no profiles
    return facts.vru_profiles if function == "VRU" else facts.profiles


HOST_BUFFER_BYTES = 65536  # what the host's serial buffer holds while nobody reads it


class ImuEmulator:
    """An MTi on a pty. `start()` returns the port path; see the module docstring."""

    def __init__(
        self,
        rate_hz: int = 100,
        drift_ppm: float = 0.0,
        jitter_ms: float = 0.0,
        seed: int = 0,
        orientation_at: Callable[[float], np.ndarray] | None = None,
        noise: bool = True,
        *,
        baudrate: int = 115200,
        start_ticks: int | None = None,
        model: str = "MTi-3",
        device_id: int | None = None,
        product_code: str | None = None,
        firmware: tuple[int, int, int] = (1, 8, 2),
        wakeup_s: float = 0.5,
        orientation_error: OrientationErrorModel | None = None,
        settings_write_s: float | None = None,
        device_id_size: int = 4,
        reset_s: float = 0.3,
    ) -> None:
        code, model_id, self.family = imu_family.emulated_model(model)
        self.model = model
        accel = xbus.XDI["acceleration"]
        if not 1 <= int(rate_hz) <= self.family.max_rate():
            raise ValueError(
                f"IMU emulator ({model}): rate {rate_hz} Hz is beyond the {self.family.name} "
                f"(1..{self.family.max_rate()} Hz)"
            )
        self.rate_hz = self.family.fit(accel, int(rate_hz))  # its stored power-up rate
        # How long a settings write takes here (the family's usual time unless given).
        self.settings_write_s = (
            self.family.typical_write_s if settings_write_s is None else settings_write_s
        )
        self.drift_ppm = float(drift_ppm)
        self.jitter_ms = float(jitter_ms)
        self.baudrate = baudrate
        self.noise = noise
        self.orientation_error = orientation_error
        self.device_id = model_id if device_id is None else device_id
        if device_id_size not in (4, 8):
            raise ValueError(f"IMU emulator: a DeviceID has 4 or 8 bytes, not {device_id_size}")
        self.device_id_size = device_id_size  # 8: the id as a 64-bit value (xspublic reads both)
        self.reset_s = reset_s  # silent this long after a Reset, then WakeUp
        self.product_code = code if product_code is None else product_code
        facts = _DEVICE_FACTS.get(self.family.name, _DEVICE_FACTS["MTi-1 series"])
        self.hardware_version = facts.hardware_version
        self.filter_profiles = _profiles_of(facts, self.family.function)
        self._named_profiles = facts.named_profiles
        # The current filter profile: a number, or on the 600 series "base/heading" labels.
        self.filter_profile: int | str = 0
        if self.filter_profiles:
            heading = [p.label for p in self.filter_profiles if p.kind == 197]
            self.filter_profile = (
                f"{self.filter_profiles[0].label}/{heading[0]}"
                if facts.named_profiles
                else self.filter_profiles[0].kind
            )
        self.option_flags = 0
        self.location_id = 0
        self.string_output_type = 0
        self.alignment = {0: (1.0, 0.0, 0.0, 0.0), 1: (1.0, 0.0, 0.0, 0.0)}  # frame -> q
        self.firmware = firmware
        self.wakeup_s = wakeup_s
        self.orientation_at = orientation_at or gait_orientation
        self._rng = np.random.default_rng(seed)
        self._start_ticks = (
            int(self._rng.integers(0, 2**32)) if start_ticks is None else start_ticks % 2**32
        )
        self._gyro_bias = self._rng.normal(0.0, 0.003, 3) if noise else np.zeros(3)
        self._accel_bias = self._rng.normal(0.0, 0.02, 3) if noise else np.zeros(3)
        # The attitude filter's error (devices.orientation_error); none: the true orientation.
        self._filter_error = (
            OrientationError(orientation_error, self._rng) if orientation_error else None
        )
        # Stored settings at power-up: the default outputs this model has, at rate_hz.
        self._outputs = [
            s
            for s in xbus.output_settings(xbus.DEFAULT_OUTPUTS, self.rate_hz)
            if self.family.has(s.name)
        ]
        self._pending_baudrate: int | None = None  # SetBaudrate: applies after a Reset
        self._last_overflow_report = 0
        self.overflow_reports = 0  # Error 0x29 messages sent
        self.last_output_request: list[xbus.OutputSetting] = []
        self._commands: queue.SimpleQueue = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._dir: str | None = None
        self.port: str | None = None
        self.start_time_ns: int | None = None  # session clock at start()
        self._master: int | None = None
        self._slave: int | None = None
        self._queue: collections.deque[tuple[int, bytes]] = collections.deque()  # (send at, bytes)
        self._out = bytearray()  # bytes due but not yet taken by the pty
        self.sent = 0  # MTData2 messages written
        self.dropped_on_wire = 0  # bytes lost because nobody read the pty
        self.overflowed = 0  # messages lost because the baud rate cannot carry them
        self.requests: list[int] = []  # MIDs received, for tests and `--verbose`
        self.last_request_data: dict[int, bytes] = {}  # MID -> data of its latest request
        self._error_ahead: int | None = None  # an Error to send ahead of the next reply

    # ---- life cycle -------------------------------------------------------------------

    def start(self) -> str:
        """Power up, plug in, start streaming; returns the stable port path."""
        if self._thread is not None:
            return self.port  # type: ignore[return-value]
        self._dir = tempfile.mkdtemp(prefix="walkcap-", dir=_short_tmp())
        self.port = os.path.join(self._dir, "ttyIMU")  # /tmp/walkcap-XXXXXXXX/ttyIMU
        if len(self.port) >= PORT_NAME_MAX:
            log.warning("IMU emulator port %s is too long for Xsens' tools", self.port)
        self.start_time_ns = now_ns()  # orientation_at(0) is this instant
        self._utc_at_start_ns = time.time_ns()
        self.clock = EmulatorClock(self.start_time_ns, self._start_ticks, self.drift_ppm)
        self._power_up(self.start_time_ns)
        self._plug()
        self._thread = threading.Thread(target=self._run, name="walkcap-imu-emulator", daemon=True)
        self._thread.start()
        return self.port

    def stop(self) -> None:
        self._stopping.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._unplug()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None

    def __enter__(self) -> ImuEmulator:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def inject(self, fault: str, **kw) -> None:
        """Inject a fault: "corrupt" (count=1: flip a byte in the next messages; garbage=b""
        to send bytes first), "drop" (count=1 samples not sent), "hang" (seconds=2.0 of
        silence, requests ignored), "disconnect" (seconds=None: unplug, replug after that
        long if given), "reconnect" (power_cycle=False: plug in again; with a power cycle
        the device restarts its clock and counter and wakes up), "error" (code=0x29: an
        asynchronous Error just ahead of the next reply, as a data overflow reported while
        the host waits for an acknowledgement)."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r} (known: {', '.join(FAULTS)})")
        done = threading.Event()
        self._commands.put((fault, kw, done))
        if self._thread is not None and self._thread.is_alive():
            done.wait(2.0)

    # ---- time -------------------------------------------------------------------------

    def _ticks_at(self, t_ns: int) -> float:
        return self.clock.ticks_at(t_ns)

    def _time_of_ticks(self, ticks: float) -> int:
        return self.clock.time_of_ticks(ticks)

    def true_time_ns(self, sample_time_fine: int) -> int:
        """When the emulator took the sample stamped sample_time_fine (session clock)."""
        return self.clock.true_time_ns(sample_time_fine, now_ns())

    # ---- the device -------------------------------------------------------------------

    def _power_up(self, t: int, restart_clock: bool = False) -> None:
        if restart_clock:  # a real power cycle: clock and counter start again
            self.clock = EmulatorClock(t, 0, self.drift_ppm)
        self._counter = 0
        self._measuring = False
        self._wakeup_until = t + int(self.wakeup_s * 1e9)
        self._next_wakeup = t
        self._hang_until = 0
        self._corrupt = 0
        self._garbage = b""
        self._drop = 0
        self._reconnect_at: int | None = None
        self._queue = collections.deque()
        self._out = bytearray()
        self._last_send = t

    def _start_measurement(self, t: int) -> None:
        self._measuring = True
        self._wakeup_until = 0
        rates = [
            s.rate_hz
            for s in self._outputs
            if not xbus.rides_every_packet(s.xdi) and s.rate_hz not in (0, xbus.EVERY_PACKET)
        ]
        # Messages go out at the fastest output's rate (the others divide it).
        self._rate = max(rates) if rates else self.rate_hz
        self._period_ticks = 10_000 / self._rate
        self._meas_ticks0 = int(self._ticks_at(t)) + 1  # the next tick
        self._sample_index = 0

    def _plug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: a binary serial line
        self._set_line_speed(slave, self.baudrate)
        flags = fcntl.fcntl(master, fcntl.F_GETFL)
        fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self._master, self._slave = master, slave
        tmp = self.port + ".new"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.port)  # atomic: the path always points at a whole device
        self._parser = xbus.XbusParser()
        log.info("IMU emulator plugged in at %s -> %s", self.port, os.ttyname(slave))

    def _unplug(self) -> None:
        if self.port and os.path.lexists(self.port):
            os.unlink(self.port)
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None
        self._queue.clear()
        self._out.clear()

    @property
    def plugged(self) -> bool:
        return self._master is not None

    def _run(self) -> None:
        _precise_timers()
        try:
            while not self._stopping.is_set():
                self._step()
        except Exception:  # the device dies, the process must not
            log.exception("IMU emulator stopped")

    def _step(self) -> None:
        t = now_ns()
        self._flush(t)  # first: what is due goes out before any other work
        while not self._commands.empty():
            fault, kw, done = self._commands.get()
            try:
                self._apply_fault(fault, kw, t)
            finally:
                done.set()
        if self._reconnect_at is not None and t >= self._reconnect_at:
            self._apply_fault("reconnect", {}, t)
        hung = t < self._hang_until
        if self._measuring and not hung:
            self._take_samples(t)
        if (
            self.plugged
            and not self._measuring
            and t < self._wakeup_until
            and t >= self._next_wakeup
        ):
            # An MTi announces itself once; repeating it lets a host that opens late see it.
            self._send_now(xbus.build(MID.WAKEUP), t)
            self._next_wakeup = t + 100_000_000
        elif self._wakeup_until and t >= self._wakeup_until and not self._measuring:
            self._start_measurement(t)  # no WakeUpAck: measure with the stored settings
        self._flush(t)
        timeout = 0.02
        if self._queue:
            due = self._queue[0][0]
            if due - now_ns() < _SPIN_NS:  # the last moments are waited for by spinning
                while now_ns() < due:
                    time.sleep(0)  # yields the GIL: a bare spin would stall the host's threads
                return
            timeout = min(timeout, (due - now_ns() - _SPIN_NS) * 1e-9)
        if self._measuring:
            next_ticks = self._meas_ticks0 + self._sample_index * self._period_ticks
            wait = (self._time_of_ticks(next_ticks) - now_ns()) * 1e-9
            timeout = min(timeout, max(0.0, wait))
        if self.plugged:
            try:
                readable, _, _ = select.select([self._master], [], [], timeout)
            except (OSError, ValueError):
                return
            if readable:
                self._read(hung)
        else:
            self._stopping.wait(timeout)

    def _read(self, hung: bool) -> None:
        try:
            data = os.read(self._master, 4096)
        except OSError as e:
            if e.errno not in (errno.EAGAIN, errno.EIO):
                raise
            return
        if hung:
            return  # a hung device does not read its UART
        if not self._line_matches():
            return  # the host's UART runs at another rate: the device hears noise
        for msg in self._parser.feed(data):
            self.requests.append(msg.mid)
            del self.requests[:-200]
            self.last_request_data[msg.mid] = msg.data
            self._handle(msg, now_ns())

    # ---- samples ----------------------------------------------------------------------

    def _take_samples(self, t: int) -> None:
        while True:
            ticks = self._meas_ticks0 + round(self._sample_index * self._period_ticks)
            taken_at = self._time_of_ticks(ticks)
            if taken_at > t:
                return
            index = self._sample_index
            self._sample_index += 1
            if taken_at < self._hang_until:
                continue  # hung: the sample was never taken
            counter = self._counter
            self._counter = (self._counter + 1) & 0xFFFF
            if self._drop > 0:
                self._drop -= 1
                continue
            if not self.plugged:
                continue
            payload = self._mtdata2(index, counter, ticks, taken_at)
            frame = bytearray(xbus.build(MID.MTDATA2, payload))
            if self._corrupt > 0:
                self._corrupt -= 1
                frame[len(frame) // 2] ^= 0xA5
            if self._garbage:
                frame[:0] = self._garbage
                self._garbage = b""
            jitter = self._rng.uniform(0, self.jitter_ms * 1e6) if self.jitter_ms > 0 else 0
            self._transmit(bytes(frame), taken_at + int(jitter))
            self.sent += 1

    def _mtdata2(self, index: int, counter: int, ticks: int, taken_at: int) -> bytes:
        t = (taken_at - self.start_time_ns) * 1e-9
        dt = 1.0 / self._rate
        q = quat_normalize(np.asarray(self.orientation_at(t), dtype=np.float64))
        rot = quat_to_matrix(q)
        rng = self._rng
        noisy = self.noise

        def noise(sigma: float, n: int = 3) -> np.ndarray:
            return rng.normal(0.0, sigma, n) if noisy else np.zeros(n)

        accel = rot.T @ np.array([0.0, 0.0, GRAVITY]) + self._accel_bias + noise(0.03)
        h = 0.002  # body rate from the orientation's central difference
        q_a = quat_normalize(np.asarray(self.orientation_at(t - h), dtype=np.float64))
        q_b = quat_normalize(np.asarray(self.orientation_at(t + h), dtype=np.float64))
        dq = quat_multiply(quat_conjugate(q_a), q_b)
        if dq[0] < 0:
            dq = -dq
        gyro = dq[1:] / h + self._gyro_bias + noise(0.004)  # 2 * vec / (2 h)
        field_enu = rot.T @ MAGNETIC_FIELD_ENU  # physics sees the true orientation
        if self._filter_error is not None:  # the filter's estimate, not the truth
            q = self._filter_error.apply(q, t)
            rot = quat_to_matrix(q)
        values: dict[str, object] = {}
        encodings: dict[str, tuple[int, str]] = {}  # name -> (precision, coordinate system)
        for setting in self._outputs:
            name = setting.name
            if setting.rate_hz == 0:
                continue
            if setting.rate_hz != xbus.EVERY_PACKET and index % max(
                1, self._rate // setting.rate_hz
            ):
                continue
            system = xbus.COORDINATE_SYSTEMS.get(setting.xdi & 0xC, "ENU")
            encodings[name] = (setting.xdi & 0x3, system)
            to_frame = np.array(xbus.FRAME_FROM_ENU[system], dtype=np.float64)
            if name == "packet_counter":
                values[name] = counter
            elif name == "sample_time_fine":
                values[name] = ticks % 2**32
            elif name == "sample_time_coarse":
                values[name] = (ticks // 10_000) % 2**32
            elif name == "utc_time":
                values[name] = self._utc_time(taken_at)
            elif name == "status_word":
                values[name] = 0b11  # self-test ok, filter valid
            elif name == "quaternion":
                values[name] = tuple(quat_multiply(matrix_to_quat(to_frame), q))
            elif name == "rotation_matrix":
                values[name] = tuple(map(tuple, to_frame @ rot))
            elif name == "euler":
                values[name] = tuple(np.degrees(quat_to_euler(matrix_to_quat(to_frame @ rot))))
            elif name == "acceleration":
                values[name] = tuple(accel)
            elif name == "free_acceleration":
                values[name] = tuple(
                    to_frame @ (rot @ (accel - self._accel_bias) - [0.0, 0.0, GRAVITY])
                )
            elif name == "delta_v":
                values[name] = tuple(accel * dt)
            elif name == "rate_of_turn":
                values[name] = tuple(gyro)
            elif name == "delta_q":
                q_prev = quat_normalize(np.asarray(self.orientation_at(t - dt), dtype=np.float64))
                d = quat_multiply(quat_conjugate(q_prev), q)
                values[name] = tuple(d if d[0] >= 0 else -d)
            elif name == "magnetic_field":
                values[name] = tuple(field_enu + noise(0.01))
            elif name == "temperature":
                values[name] = 31.0 + float(noise(0.05, 1)[0])
            elif name == "baro_pressure":
                values[name] = int(101325 + noise(2.0, 1)[0])
        return b"".join(
            xbus.encode_packet(name, value, *encodings[name]) for name, value in values.items()
        )

    def _utc_time(self, taken_at: int) -> tuple[int, ...]:
        """UtcTime of a sample: the host's UTC at start plus the device's time since. Without
        a GNSS receiver a device has no valid UTC: flags 0 (0x07 on a GNSS model)."""
        ns = self._utc_at_start_ns + (taken_at - (self.start_time_ns or 0))
        when = datetime.datetime.fromtimestamp(ns // 1_000_000_000, datetime.UTC)
        flags = 0x07 if self.family.function == "GNSS/INS" else 0x00
        fields = (when.year, when.month, when.day, when.hour, when.minute, when.second)
        return (ns % 1_000_000_000, *fields, flags)

    # ---- the wire ---------------------------------------------------------------------

    def _transmit(self, frame: bytes, ready_at: int) -> None:
        """Send a frame from ready_at, after the one before it: the host has it all one wire
        time later. More than the line carries piles up, then overflows the device."""
        # The device's buffer at ready_at: frames on the wire by then have left it (this
        # thread catching up after the host starved it is no overflow of the device).
        while self._queue and self._queue[0][0] <= ready_at:
            self._out += self._queue.popleft()[1]
        if len(self._queue) >= 64:  # the device's output buffer is full: the frame is lost
            self.overflowed += 1
            if ready_at - self._last_overflow_report >= _OVERFLOW_REPORT_NS:
                self._last_overflow_report = ready_at
                self.overflow_reports += 1
                error = xbus.build(MID.ERROR, bytes([xbus.DATA_OVERFLOW]))
                start = max(ready_at, self._last_send)
                self._last_send = start + xbus.wire_time_ns(len(error), self.baudrate)
                self._queue.append((self._last_send, error))
            return
        start = max(ready_at, self._last_send)
        self._last_send = start + xbus.wire_time_ns(len(frame), self.baudrate)
        self._queue.append((self._last_send, frame))

    def _send_now(self, frame: bytes, t: int) -> None:
        self._transmit(frame, t)

    def _flush(self, t: int) -> None:
        while self._queue and self._queue[0][0] <= t:
            self._out += self._queue.popleft()[1]
        if not self._out or not self.plugged:
            return
        if not self._line_matches():  # another rate on the host's side: it reads noise
            self._out = bytearray(b ^ 0x5A for b in self._out)
        try:
            n = os.write(self._master, self._out)
            del self._out[:n]
        except OSError as e:
            if e.errno not in (errno.EAGAIN, errno.EIO):
                raise
        if len(self._out) > HOST_BUFFER_BYTES:
            # Nobody reads: as on a UART, the host's full buffer keeps the oldest bytes and
            # the ones arriving now are lost; the host reads what it kept once it runs.
            self.dropped_on_wire += len(self._out) - HOST_BUFFER_BYTES
            del self._out[HOST_BUFFER_BYTES:]

    # ---- requests ---------------------------------------------------------------------

    def _reply(self, mid: int, data: bytes, t: int) -> None:
        if self._error_ahead is not None and mid != MID.ERROR:
            code, self._error_ahead = self._error_ahead, None
            self._send_now(xbus.build(MID.ERROR, bytes([code])), t)  # an asynchronous report
        self._send_now(xbus.build(mid, data), t)

    def _reply_after_write(self, mid: int, data: bytes, t: int) -> None:
        """The ack of a settings write, once the (slow) write to flash is done."""
        self._transmit(xbus.build(mid, data), t + int(self.settings_write_s * 1e9))

    # ---- the line -----------------------------------------------------------------------

    @staticmethod
    def _set_line_speed(fd: int, baudrate: int) -> None:
        speed = next((k for k, v in _SPEEDS.items() if v == baudrate), None)
        if speed is None:
            return
        attrs = termios.tcgetattr(fd)
        attrs[4] = attrs[5] = speed
        termios.tcsetattr(fd, termios.TCSANOW, attrs)

    def _line_matches(self) -> bool:
        """Whether the host's end of the line runs at the device's baud rate."""
        if self._slave is None:
            return True
        try:
            speed = termios.tcgetattr(self._slave)[5]
        except termios.error:
            return True
        host = _SPEEDS.get(speed)
        return host is None or host == self.baudrate

    def _error(self, code: int, t: int) -> None:
        self._reply(MID.ERROR, bytes([code]), t)

    def _handle(self, msg: xbus.Message, t: int) -> None:
        mid, data = msg.mid, msg.data
        if mid == MID.WAKEUP_ACK:
            if self._wakeup_until and t < self._wakeup_until:
                self._wakeup_until = 0  # stay in configuration
            return
        if self._measuring and mid not in _MEASUREMENT_OK:
            self._error(xbus.INVALID_MESSAGE, t)
            return
        no_data = {
            MID.GOTO_CONFIG: MID.GOTO_CONFIG_ACK,
            MID.GOTO_MEASUREMENT: MID.GOTO_MEASUREMENT_ACK,
            MID.REQ_DID: MID.DEVICE_ID,
            MID.INIT_MT: MID.INIT_MT_RESULTS,
            MID.REQ_FW_REV: MID.FIRMWARE_REV,
            MID.REQ_PRODUCT_CODE: MID.PRODUCT_CODE,
            MID.RESET: MID.RESET_ACK,
        }
        if mid in no_data and data:
            self._error(xbus.INVALID_MESSAGE, t)  # these requests carry no data
            return
        if mid == MID.GOTO_CONFIG:
            self._measuring = False
            self._wakeup_until = 0
            self._reply(MID.GOTO_CONFIG_ACK, b"", t)
        elif mid == MID.GOTO_MEASUREMENT:
            self._reply(MID.GOTO_MEASUREMENT_ACK, b"", t)
            self._start_measurement(t)
        elif mid in (MID.REQ_DID, MID.INIT_MT):
            self._reply(no_data[mid], self._device_id_bytes(), t)
        elif mid == MID.REQ_FW_REV:
            major, minor, rev = self.firmware
            self._reply(MID.FIRMWARE_REV, struct.pack(">BBBII", major, minor, rev, 42, 7031), t)
        elif mid == MID.REQ_PRODUCT_CODE:
            # 20 characters padded with spaces, as a device sends it (the library copies 20).
            self._reply(MID.PRODUCT_CODE, self._product_code_bytes(), t)
        elif mid in self._SETTINGS:
            self._setting(mid, data, t)
        elif mid == MID.REQ_BAUDRATE:
            self._baudrate_request(data, t)
        elif mid == MID.SET_OUTPUT_CONFIGURATION:
            self._output_configuration(data, t)
        elif mid == MID.RESET:
            self._reply(MID.RESET_ACK, b"", t)
            queued, last = self._queue, self._last_send
            self._power_up(t)
            self._queue, self._last_send = queued, last  # the ack still goes out
            if self._pending_baudrate is not None:  # SetBaudrate applies from the reset
                # The ack leaves at the old rate; then the UART switches.
                self._flush_at_old_rate()
                self.baudrate, self._pending_baudrate = self._pending_baudrate, None
            # Booting: deaf and silent for reset_s, then it announces itself (WakeUp).
            boot = int(self.reset_s * 1e9)
            self._hang_until = t + boot
            self._next_wakeup = t + boot
            self._wakeup_until = t + boot + int(self.wakeup_s * 1e9)
        else:  # anything this device does not know
            self._error(xbus.INVALID_MESSAGE, t)

    # ---- what a device tells about itself and its settings ----------------------------

    _SETTINGS = frozenset(
        {
            MID.REQ_CONFIGURATION,
            MID.REQ_HARDWARE_VERSION,
            MID.REQ_OPTION_FLAGS,
            MID.REQ_LOCATION_ID,
            MID.REQ_AVAILABLE_FILTER_PROFILES,
            MID.REQ_FILTER_PROFILE,
            MID.REQ_ALIGNMENT_ROTATION,
            MID.REQ_STRING_OUTPUT_TYPE,
        }
    )

    def _device_id_bytes(self) -> bytes:
        return self.device_id.to_bytes(self.device_id_size, "big")

    def _product_code_bytes(self) -> bytes:
        return self.product_code.encode("ascii")[:20].ljust(20, b" ")

    def _configuration(self) -> bytes:
        """The Configuration message (0x0D) of a one-device port, in the layout Xsens'
        library reads (xsdeviceconfiguration.c): master info in 96 bytes, the device count,
        then 20 bytes per device."""
        legacy = not self.device_id & 0x8000_0000  # XS_DID64_BIT clear
        major, minor, rev = self.firmware
        master = bytearray(96)
        if legacy:  # id, sampling period (1/115200 s ticks), output skip factor
            struct.pack_into(">IHH", master, 0, self.device_id, 115200 // self.rate_hz, 0)
        else:  # the 64-bit id as two halves, the product code at 32
            struct.pack_into(">II", master, 0, self.device_id & 0xFFFFFFFF, self.device_id >> 32)
            master[32:52] = self._product_code_bytes()
        device = bytearray(20)
        if legacy:
            struct.pack_into(">I", device, 0, self.device_id)
        else:
            struct.pack_into(">II", device, 0, self.device_id & 0xFFFFFFFF, self.device_id >> 32)
        profile = self.filter_profile if isinstance(self.filter_profile, int) else 0
        struct.pack_into(">HBBBcBB", device, 12, profile, major, minor, rev, b"\x00", 0, 0)
        return bytes(master) + struct.pack(">H", 1) + bytes(device)

    def _setting(self, mid: int, data: bytes, t: int) -> None:
        """Read-outs and settings a device of the family answers on open and configuration."""
        if mid == MID.REQ_CONFIGURATION and not data:
            self._reply(MID.CONFIGURATION, self._configuration(), t)
        elif mid == MID.REQ_HARDWARE_VERSION and not data:
            self._reply(MID.HARDWARE_VERSION, struct.pack(">H", self.hardware_version), t)
        elif mid == MID.REQ_OPTION_FLAGS and not data:
            self._reply(MID.REQ_OPTION_FLAGS_ACK, struct.pack(">I", self.option_flags), t)
        elif mid == MID.REQ_OPTION_FLAGS and len(data) == 8:  # flags to set, flags to clear
            set_, clear = struct.unpack(">II", data)
            self.option_flags = (self.option_flags | set_) & ~clear & 0xFFFFFFFF
            self._reply_after_write(MID.REQ_OPTION_FLAGS_ACK, b"", t)
        elif mid == MID.REQ_LOCATION_ID and not data:
            self._reply(MID.REQ_LOCATION_ID_ACK, struct.pack(">H", self.location_id), t)
        elif mid == MID.REQ_LOCATION_ID and len(data) == 2:
            self.location_id = struct.unpack(">H", data)[0]
            self._reply_after_write(MID.REQ_LOCATION_ID_ACK, b"", t)
        elif mid == MID.REQ_AVAILABLE_FILTER_PROFILES and not data:
            listing = b"".join(
                bytes((p.kind, p.version)) + p.label.encode("ascii").ljust(20, b" ")
                for p in self.filter_profiles
            )
            self._reply(MID.AVAILABLE_FILTER_PROFILES, listing, t)
        elif mid == MID.REQ_FILTER_PROFILE and not data:
            current = self.filter_profile
            answer = (
                current.encode("ascii") if isinstance(current, str) else struct.pack(">H", current)
            )
            self._reply(MID.REQ_FILTER_PROFILE_ACK, answer, t)
        elif mid == MID.REQ_FILTER_PROFILE:
            self._set_filter_profile(data, t)
        elif mid == MID.REQ_ALIGNMENT_ROTATION and len(data) == 1 and data[0] in self.alignment:
            q = self.alignment[data[0]]
            self._reply(MID.REQ_ALIGNMENT_ROTATION_ACK, data + struct.pack(">4f", *q), t)
        elif mid == MID.REQ_ALIGNMENT_ROTATION and len(data) == 17 and data[0] in self.alignment:
            self.alignment[data[0]] = struct.unpack(">4f", data[1:])
            self._reply_after_write(MID.REQ_ALIGNMENT_ROTATION_ACK, b"", t)
        elif mid == MID.REQ_ALIGNMENT_ROTATION and len(data) in (1, 17):
            self._error(xbus.INVALID_PARAMETER, t)  # no such frame
        elif mid == MID.REQ_STRING_OUTPUT_TYPE and not data:
            self._reply(
                MID.REQ_STRING_OUTPUT_TYPE_ACK, struct.pack(">H", self.string_output_type), t
            )
        elif mid == MID.REQ_STRING_OUTPUT_TYPE and len(data) == 2:
            self.string_output_type = struct.unpack(">H", data)[0]
            self._reply_after_write(MID.REQ_STRING_OUTPUT_TYPE_ACK, b"", t)
        else:
            self._error(xbus.INVALID_MESSAGE, t)

    def _set_filter_profile(self, data: bytes, t: int) -> None:
        if self._named_profiles:  # "Robust/VRU": labels this device lists
            labels = {p.label for p in self.filter_profiles}
            text = data.decode("ascii", "replace").strip("\x00 ")
            ok = bool(text) and all(part in labels for part in text.split("/"))
            value: int | str = text
        else:
            ok = len(data) == 2 and struct.unpack(">H", data)[0] in {
                p.kind for p in self.filter_profiles
            }
            value = struct.unpack(">H", data)[0] if len(data) == 2 else 0
        if not ok:
            self._error(INVALID_FILTER_PROFILE, t)
            return
        self.filter_profile = value
        self._reply_after_write(MID.REQ_FILTER_PROFILE_ACK, b"", t)

    def _flush_at_old_rate(self) -> None:
        """Send what is queued now, before the line changes speed."""
        while self._queue:
            self._out += self._queue.popleft()[1]
        if self._out and self.plugged:
            try:
                n = os.write(self._master, self._out)
                del self._out[:n]
            except OSError:
                pass
        self._last_send = now_ns()

    def _baudrate_request(self, data: bytes, t: int) -> None:
        if not data:
            self._reply(MID.REQ_BAUDRATE_ACK, bytes([xbus.BAUD_CODE.get(self.baudrate, 0x02)]), t)
        elif len(data) == 1 and data[0] in xbus.BAUD_CODES:
            self._pending_baudrate = xbus.BAUD_CODES[data[0]]  # effective after a reset
            self._reply_after_write(MID.REQ_BAUDRATE_ACK, b"", t)
        elif len(data) == 1:
            self._error(xbus.INVALID_BAUDRATE, t)
        else:
            self._error(xbus.INVALID_MESSAGE, t)

    def _output_configuration(self, data: bytes, t: int) -> None:
        if not data:
            self._reply(
                MID.OUTPUT_CONFIGURATION, xbus.encode_output_configuration(self._outputs), t
            )
            return
        try:
            settings = xbus.decode_output_configuration(data)
        except ValueError:
            self._error(xbus.INVALID_MESSAGE, t)
            return
        self.last_output_request = settings  # as the host sent it (tests look at it)
        granted = []
        for s in settings:
            known = xbus.OUTPUTS.get(s.xdi & 0xFFF0)
            if known is None or (s.xdi & 0xC) not in xbus.COORDINATE_SYSTEMS:
                self._error(xbus.INVALID_PARAMETER, t)
                return
            if not self.family.has(known[0]):  # e.g. a quaternion from an IMU-only model
                self._error(xbus.INVALID_PARAMETER, t)
                return
            # The timestamp group (any rate) and the status word at 0 or 0xFFFF: with every
            # message (0xFFFF); another output at 0xFFFF: its maximum; at 0: not output.
            rate = self.family.fit(s.xdi, s.rate_hz)
            granted.append(xbus.OutputSetting(s.xdi, rate))
        self._outputs = granted
        self._reply_after_write(
            MID.OUTPUT_CONFIGURATION, xbus.encode_output_configuration(granted), t
        )

    # ---- faults -----------------------------------------------------------------------

    def _apply_fault(self, fault: str, kw: dict, t: int) -> None:
        log.info("IMU emulator fault: %s %s", fault, kw)
        if fault == "corrupt":
            self._corrupt += int(kw.get("count", 1))
            self._garbage += bytes(kw.get("garbage", b""))
        elif fault == "drop":
            self._drop += int(kw.get("count", 1))
        elif fault == "error":
            self._error_ahead = int(kw.get("code", xbus.DATA_OVERFLOW))
        elif fault == "hang":
            self._hang_until = t + int(float(kw.get("seconds", 2.0)) * 1e9)
            self._queue.clear()
        elif fault == "disconnect":
            self._unplug()
            seconds = kw.get("seconds")
            self._reconnect_at = t + int(float(seconds) * 1e9) if seconds is not None else None
        elif fault == "reconnect":
            self._reconnect_at = None
            if not self.plugged:
                self._plug()
            if kw.get("power_cycle"):
                self._power_up(t, restart_clock=True)
