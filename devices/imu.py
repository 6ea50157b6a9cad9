"""The IMU: one small interface, a registry of backends, and the Xbus serial driver.

Like python-can's bus: `Imu` is the surface every backend shares (open, start, recv,
stop, close, status, poll_events, a context manager); backends are named in `BACKENDS`
and imported only when chosen. There is one real driver, `XbusImu` (Xsens MTi over
pyserial); the mock backend, `EmulatedImu`, is that same driver talking to an
`ImuEmulator` on a pseudo-terminal, so the mock exercises pyserial and termios too.

Samples: `time_ns` is the device's SampleTimeFine mapped onto the session clock by the
clock estimator (devices/imu_clock.py), `host_time_ns` the receive time. Quaternions are
always sensor -> ENU world (z up), whatever coordinate system the device reports in.
A vanished or silent port is reported within a second, retried until it returns, and the
gap reported; the reader thread never dies with the device.

Configuring follows Xsens' own rules (devices/imu_family.py): the family comes from the
product code; every output is asked for at an explicit rate the family has (0xFFFF only
for the packet counter and SampleTimeFine, which ride in every message); outputs the
model lacks are left out with a warning (an IMU-only model sends no orientation, so its
samples carry no quaternion and leveling needs a VRU or AHRS model); the device's reply
is compared with the request and every rate it granted instead is said; and the stream
must fit the baud rate before GoToMeasurement, else one line names a rate or baud rate
that fits. As in Xsens' library (MidReplyObject::isReplyFor), an Error 0x29 (data
overflow) the device sends on its own while the driver waits for a reply is an event,
not the reply; any other Error is the reply.
"""

from __future__ import annotations

import importlib
import logging
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from devices import imu_family, xbus
from devices.base import (
    DEGRADED,
    LOST,
    OK,
    STOPPED,
    BoundedBuffer,
    DeviceEvent,
    DeviceStatus,
    RateMeter,
)
from devices.clock import now_ns
from devices.errors import DeviceError, DeviceInitError, DeviceNotAvailable
from devices.frames import ImuSample
from devices.imu_clock import DeviceClock
from devices.imu_family import Family
from devices.rotations import matrix_to_quat, quat_from_euler, quat_multiply, quat_normalize
from devices.xbus import MID

log = logging.getLogger(__name__)

# name -> (module, class); imported when chosen.
BACKENDS = {
    "mock": ("devices.imu", "EmulatedImu"),
    "serial": ("devices.imu", "XbusImu"),
}

# sensor -> ENU = (frame -> ENU) * (sensor -> frame)
_FRAME_TO_ENU = {
    name: matrix_to_quat(np.array(m, dtype=np.float64).T) for name, m in xbus.FRAME_FROM_ENU.items()
}
_VECTOR_OUTPUTS = ("acceleration", "rate_of_turn")
_EVENT_INTERVAL_NS = 1_000_000_000  # repeated faults of one kind: one event a second
HOST_STALL_NS = 250_000_000  # no reader step for this long: the host stalled (reads take 20 ms)
_NOT_MEASUREMENTS = frozenset(
    {"packet_counter", "sample_time_fine", "sample_time_coarse", "utc_time", "status_word"}
)


def open_imu(config: Any, orientation_at: Callable[[float], np.ndarray] | None = None) -> Imu:
    """The IMU a configuration asks for (an ImuConfig or anything with its attributes).

    Not yet opened: call open() (or start(), or use it as a context manager).
    """
    backend = getattr(config, "backend", "mock")
    if backend not in BACKENDS:
        raise DeviceNotAvailable(
            f"unknown IMU backend {backend!r} (known: {', '.join(sorted(BACKENDS))})"
        )
    module_name, class_name = BACKENDS[backend]
    cls = getattr(importlib.import_module(module_name), class_name)
    return cls.from_config(config, orientation_at=orientation_at)


class Imu:
    """What every IMU backend offers. Backends deliver samples with `_deliver`."""

    backend = "?"

    def __init__(self, buffer_size: int = 1024) -> None:
        self._buffer: BoundedBuffer[ImuSample] = BoundedBuffer(buffer_size)
        self._events: list[DeviceEvent] = []
        self._lock = threading.Lock()
        self._rate = RateMeter()
        self.delivered = 0
        self.info: dict[str, Any] = {}

    def open(self) -> None:
        raise NotImplementedError

    def start(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def status(self) -> DeviceStatus:
        raise NotImplementedError

    def recv(self, timeout: float | None = None) -> ImuSample | None:
        """The oldest sample not yet received; None after `timeout` seconds without one."""
        return self._buffer.get(timeout)

    def poll_events(self) -> list[DeviceEvent]:
        """Events since the last call (lost, reconnected, checksum errors, ...)."""
        with self._lock:
            events, self._events = self._events, []
        return events

    def __enter__(self) -> Imu:
        self.open()
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self) -> Iterator[ImuSample]:
        while self.status().state != STOPPED:
            sample = self.recv(0.2)
            if sample is not None:
                yield sample

    def _deliver(self, sample: ImuSample) -> None:
        self._buffer.put(sample)
        with self._lock:  # by sample time: a catch-up burst after a gap is no faster rate
            self._rate.tick(sample.host_time_ns if sample.time_ns is None else sample.time_ns)
        self.delivered += 1

    def _event(self, kind: str, message: str, t_ns: int | None = None, **details: Any) -> None:
        # a message that names the device is a sentence already ("IMU lost (...)")
        log.info("%s", message if message.startswith("IMU") else f"IMU {kind}: {message}")
        event = DeviceEvent(now_ns() if t_ns is None else t_ns, "imu", kind, message, details)
        with self._lock:
            self._events.append(event)
            del self._events[:-1000]  # nobody polls: keep the latest

    def _measured_rate(self) -> float:
        with self._lock:
            return self._rate.rate()


class _Stop(Exception):
    """stop() was called while configuring."""


class XbusImu(Imu):
    """An Xsens MTi (or anything speaking Xbus) on a serial port."""

    backend = "serial"

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        rate_hz: int = 100,
        outputs: tuple[str, ...] | None = xbus.DEFAULT_OUTPUTS,
        *,
        precision: int = xbus.FLOAT32,
        coordinate_system: str = "ENU",
        request_timeout_s: float = 1.0,
        config_timeout_s: float = 2.0,
        reset_timeout_s: float = 10.0,
        silence_s: float | None = None,
        retry_s: float = 0.5,
        buffer_size: int = 1024,
        raw_sink: Callable[[bytes], None] | None = None,
    ) -> None:
        """outputs None: keep the device's output configuration (read it, do not set it)."""
        super().__init__(buffer_size)
        if not port:
            raise DeviceNotAvailable(
                "no IMU serial port given (set [imu] port, e.g. "
                "/dev/ttyUSB0, or use the mock backend)"
            )
        self.port = port
        self.baudrate = int(baudrate)
        self.rate_hz = int(rate_hz)
        if outputs is not None and not 1 <= self.rate_hz <= 2000:
            raise DeviceInitError(f"IMU rate {rate_hz} Hz is out of range (1..2000)")
        self.outputs = tuple(outputs) if outputs is not None else None
        try:
            self._settings = (
                xbus.output_settings(outputs, self.rate_hz, precision, coordinate_system)
                if outputs is not None
                else None
            )
        except (ValueError, KeyError) as e:
            raise DeviceInitError(f"IMU outputs: {e}") from None
        self.request_timeout_s = request_timeout_s
        self.config_timeout_s = config_timeout_s
        # After a Reset (SetBaudrate): how long the device may take to answer again.
        self.reset_timeout_s = reset_timeout_s
        self.family: Family | None = None
        self.budget: xbus.LinkBudget | None = None
        self.adjusted: list[str] = []  # what walkcap changed to fit the family
        self.granted: list[str] = []  # what the device granted instead of the request
        self._said: set[str] = set()
        # Silence longer than this is a lost device: half a second, or 3 periods when slow.
        self.silence_ns = int(
            (silence_s if silence_s is not None else max(0.5, 3.0 / max(self.rate_hz, 1))) * 1e9
        )
        self.retry_ns = int(retry_s * 1e9)
        self.raw_sink = raw_sink
        self.configured_rate_hz = float(self.rate_hz)
        self.clock = DeviceClock()
        self._parser = xbus.XbusParser()
        self._serial = None  # serial.Serial while connected
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._state = STOPPED
        self._message = "not started"
        self._last_sample_ns: int | None = None
        self._lost_at_ns: int | None = None
        self._next_retry_ns = 0
        self._last_counter: int | None = None
        self.missing_packets = 0
        self.reconnects = 0
        self.device_errors = 0
        # kind -> [last event time, count not yet reported]
        self._pending: dict[str, list[int]] = {}
        self._seen = {"checksum_errors": 0, "resyncs": 0, "dropped": 0}
        self._last_problem_ns = 0
        self._started_ns = now_ns()
        self._last_step_ns = 0
        self._host_resumed_ns = 0  # the end of the last host stall (see _step)

    @classmethod
    def from_config(cls, config: Any, orientation_at=None) -> XbusImu:
        return cls(
            getattr(config, "port", ""),
            getattr(config, "baudrate", 115200),
            getattr(config, "rate_hz", 100),
        )

    # ---- connection -------------------------------------------------------------------

    def open(self) -> None:
        """Open the port and configure the device; then it measures. Idempotent."""
        if self._serial is not None:
            return
        self._stopping.clear()
        self._connect()
        self._message = f"configured, {self.configured_rate_hz:g} Hz"

    def _connect(self) -> None:
        ser = self._open_port()
        try:
            self._configure(ser)
        except BaseException:
            _close_quietly(ser)
            raise
        self._serial = ser

    def _open_port(self):
        import serial  # pyserial, imported when a port is opened

        try:
            return serial.Serial(self.port, self.baudrate, timeout=0.02, write_timeout=1.0)
        except (serial.SerialException, OSError, ValueError) as e:
            raise DeviceNotAvailable(f"cannot open IMU port {self.port}: {_reason(e)}") from None

    def _configure(self, ser) -> None:
        """WakeUp/GoToConfig, identify, set (or read) the outputs, check the link budget,
        GoToMeasurement."""
        self._parser.clear()
        self._woke_up = False
        self._goto_config(ser)
        device_id = self._request(ser, MID.REQ_DID, reply=MID.DEVICE_ID)
        product = self._request(ser, MID.REQ_PRODUCT_CODE, reply=MID.PRODUCT_CODE)
        firmware = self._request(ser, MID.REQ_FW_REV, reply=MID.FIRMWARE_REV)
        product_code = product.decode("ascii", "replace").strip("\x00 ")
        self.family = imu_family.family_of(product_code)
        if self.family is None:
            log.warning(
                "IMU on %s: product code %r is not a family this driver knows: "
                "asking for the configured outputs as they are",
                self.port,
                product_code,
            )
        request = self._fit(self._settings, product_code) if self._settings else None
        reply = self._request(
            ser,
            MID.SET_OUTPUT_CONFIGURATION,
            xbus.encode_output_configuration(request) if request else b"",
            reply=MID.OUTPUT_CONFIGURATION,
            timeout=self._settings_timeout_s(),
        )
        try:
            settings = xbus.decode_output_configuration(reply)
        except ValueError as e:
            raise DeviceInitError(f"IMU on {self.port}: bad OutputConfiguration: {e}") from None
        if request:
            self._compare(request, settings, product_code)
        self.budget = xbus.link_budget(settings, self.baudrate)
        if request and not self.budget.fits:
            raise DeviceInitError(self._budget_refusal(settings, product_code))
        self._request(ser, MID.GOTO_MEASUREMENT, reply=MID.GOTO_MEASUREMENT_ACK)
        self.configured_rate_hz = _sampling_rate(settings) or float(self.rate_hz)
        self.info = {
            "device_id": device_id_text(device_id),
            "product_code": product_code,
            "family": self.family.name if self.family else "unknown",
            "function": self.family.function if self.family else "unknown",
            "firmware": _firmware_text(firmware),
            "output_configuration": [s.describe() for s in settings],
            "adjusted": list(self.adjusted),
            "granted": list(self.granted),
            "link_budget": self.budget.describe(),
            "port": self.port,
            "baudrate": self.baudrate,
            "woke_up": self._woke_up,  # it had just powered up and sent WakeUp
        }
        self._last_counter = None

    def _settings_timeout_s(self) -> float:
        """Settings writes are slow (about 900 ms on the 1-series): twice that, at least."""
        slowest = self.family.settings_write_s if self.family else 0.9
        return max(self.request_timeout_s, 2.0 * slowest + 0.2)

    def _fit(self, settings: list[xbus.OutputSetting], product_code: str) -> list:
        """The request fitted to the family: outputs it lacks left out, each rate one it
        has (said once, as `adjusted`)."""
        family = self.family
        if family is None:
            return settings
        fitted, self.adjusted = [], []
        for s in settings:
            if not family.has(s.name):
                why = (
                    "an IMU-only model has no orientation (leveling needs a VRU or AHRS)"
                    if s.name in imu_family.NEEDS_ORIENTATION and not family.has_orientation
                    else f"the {family.name} has no such output"
                )
                self.adjusted.append(f"{s.name} left out: {why}")
                continue
            rate = family.fit(s.xdi, s.rate_hz)
            if rate != s.rate_hz:
                self.adjusted.append(
                    f"{s.name} at {rate} Hz, not {s.rate_hz} Hz "
                    f"({product_code}: {imu_family.describe_rates(family, s.xdi)} Hz)"
                )
            fitted.append(xbus.OutputSetting(s.xdi, rate))
        for text in self.adjusted:
            self._say("output_adjusted", f"IMU: {text}")
        return fitted

    def _say(self, kind: str, text: str) -> None:
        """A warning and an event, once per driver (a reconnect configures again)."""
        if text in self._said:
            return
        self._said.add(text)
        log.warning("%s (%s)", text, self.port)
        self._event(kind, text)

    def _compare(self, request: list, reply: list, product_code: str) -> None:
        """Say every difference between the request and what the device uses."""
        asked = {s.xdi: s.rate_hz for s in request}
        got = {s.xdi: s.rate_hz for s in reply}
        self.granted = []
        for xdi, rate in asked.items():
            name = xbus.OutputSetting(xdi, rate).name
            if xdi not in got:
                self.granted.append(f"{name}: asked for at {_rate_text(rate)}, not granted")
            elif got[xdi] != rate:
                self.granted.append(
                    f"{name}: asked for {_rate_text(rate)}, the device uses {_rate_text(got[xdi])}"
                )
        for xdi, rate in got.items():
            if xdi not in asked:
                name = xbus.OutputSetting(xdi, rate).name
                self.granted.append(f"{name}: not asked for, the device adds it")
        for text in self.granted:
            self._say("output_granted", f"IMU {product_code}: {text}")

    def _budget_refusal(self, settings: list, product_code: str) -> str:
        """One line: what the stream needs, and a rate or baud rate that carries it."""
        budget = self.budget
        assert budget is not None
        fits = xbus.baud_that_fits(settings)
        hints = []
        if fits is not None:
            hints.append(
                f"set [imu] baudrate = {fits} (the device too: walkcap imu set-baud "
                f"{self.port} {fits})"
            )
        rate = _rate_that_fits(settings, self.baudrate, self.family)
        if rate:
            hints.append(f"or rate_hz = {rate}")
        return (
            f"IMU {product_code} on {self.port}: the output needs {budget.describe()}: "
            f"more than {self.baudrate} baud carries; " + " ".join(hints)
        )

    def change_baudrate(self, baudrate: int) -> None:
        """Set the device's baud rate as Xsens' tools do: SetBaudrate (acknowledged at the
        old rate; 921600 as code 0x80, as xsbaud.c sends it), Reset, then the new rate on
        both ends, the device found again within reset_timeout_s. The device keeps it
        across power cycles. The port must not be open in this driver."""
        if baudrate not in xbus.BAUD_CODE:
            known = ", ".join(str(b) for b in xbus.BAUDRATES)
            raise DeviceInitError(f"{baudrate} is not a baud rate an MTi has (known: {known})")

        ser = self._open_port()
        try:
            self._parser.clear()
            self._woke_up = False
            self._goto_config(ser)
            product = self._request(ser, MID.REQ_PRODUCT_CODE, reply=MID.PRODUCT_CODE)
            self.family = imu_family.family_of(product.decode("ascii", "replace"))
            code = xbus.BAUD_CODE[baudrate]
            self._request(
                ser,
                MID.REQ_BAUDRATE,
                bytes([code]),
                reply=MID.REQ_BAUDRATE_ACK,
                timeout=self._settings_timeout_s(),
            )
            self._request(ser, MID.RESET, reply=MID.RESET_ACK)  # the new rate applies now
            before = self.baudrate
            self._line_speed(ser, baudrate)
            self._redetect(ser, before)
            reply = self._request(ser, MID.REQ_BAUDRATE, reply=MID.REQ_BAUDRATE_ACK)
            if not reply or xbus.BAUD_CODES.get(reply[0]) != baudrate:
                raise DeviceInitError(
                    f"IMU on {self.port} reports baud code {reply.hex() or 'none'} "
                    f"after SetBaudrate {baudrate}"
                )
        finally:
            _close_quietly(ser)

    def _line_speed(self, ser, baudrate: int) -> None:
        import serial

        try:
            ser.baudrate = baudrate
        except (serial.SerialException, OSError, ValueError) as e:
            raise DeviceNotAvailable(
                f"IMU port {self.port} cannot run at {baudrate} baud: {_reason(e)}"
            ) from None
        self._parser.clear()
        self.baudrate = baudrate

    def _redetect(self, ser, before: int) -> None:
        """Find the device again after the Reset of a baud-rate change. It boots for a while
        (Xsens' scanner waits 2 s, then scans the baud rates): GoToConfig at the new rate
        until reset_timeout_s; then one look at the old rate, to say which it is."""
        after = self.baudrate
        if self._goto_config(ser, self.reset_timeout_s, raise_=False):
            return  # acknowledges the WakeUp after the reset: stays in configuration
        self._line_speed(ser, before)
        if self._goto_config(ser, self.config_timeout_s, raise_=False):
            raise DeviceInitError(
                f"IMU on {self.port} still answers at {before} baud, not {after}, after "
                f"SetBaudrate and Reset: the change did not take"
            )
        raise DeviceInitError(
            f"IMU on {self.port}: no answer at {after} baud within {self.reset_timeout_s:g} s "
            f"of the Reset, nor at {before} baud"
        )

    def _goto_config(self, ser, timeout: float | None = None, *, raise_: bool = True) -> bool:
        """Into configuration: acknowledge a WakeUp, else GoToConfig until it is acked."""
        timeout = self.config_timeout_s if timeout is None else timeout
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self._write(ser, xbus.build(MID.GOTO_CONFIG), "GoToConfig")
            if self._await(ser, MID.GOTO_CONFIG_ACK, "GoToConfig", 0.25) is not None:
                return True
        if not raise_:
            return False
        raise DeviceInitError(
            f"IMU on {self.port}: no answer to GoToConfig within "
            f"{timeout:g} s (is an Xsens device on it, at "
            f"{self.baudrate} baud?)"
        )

    def _request(
        self, ser, mid: int, data: bytes = b"", *, reply: int, timeout: float | None = None
    ) -> bytes:
        name = _request_name(mid, data)
        timeout = self.request_timeout_s if timeout is None else timeout
        self._write(ser, xbus.build(mid, data), name)
        answer = self._await(ser, reply, name, timeout)
        if answer is None:
            raise DeviceInitError(f"IMU on {self.port}: no answer to {name} within {timeout:g} s")
        return answer

    def _write(self, ser, frame: bytes, name: str) -> None:
        import serial

        try:
            ser.write(frame)
        except (serial.SerialException, OSError) as e:
            raise DeviceNotAvailable(
                f"IMU port {self.port} failed sending {name}: {_reason(e)}"
            ) from None

    def _await(self, ser, reply: int, name: str, timeout: float) -> bytes | None:
        """The data of the first `reply` message; None on timeout; Error raises."""
        import serial

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self._stopping.is_set():
                raise _Stop()
            try:
                waiting = ser.in_waiting
                chunk = ser.read(waiting if waiting > 0 else 1)
            except (serial.SerialException, OSError) as e:
                raise DeviceNotAvailable(
                    f"IMU port {self.port} failed waiting for the answer to {name}: {_reason(e)}"
                ) from None
            for msg in self._parser.feed(chunk):
                if msg.mid == reply:
                    return msg.data
                if msg.mid == MID.ERROR and msg.data[:1] == bytes([xbus.DATA_OVERFLOW]):
                    # Output the line could not carry, sent on its own: an event, not the
                    # answer (Xsens' MidReplyObject::isReplyFor skips it the same way).
                    self.device_errors += 1
                    self._event(
                        "device_error",
                        f"IMU sent {xbus.error_text(xbus.DATA_OVERFLOW)} while waiting for "
                        f"the answer to {name}",
                        code=xbus.DATA_OVERFLOW,
                    )
                    continue
                if msg.mid == MID.ERROR:
                    code = msg.data[0] if msg.data else 0
                    raise DeviceInitError(
                        f"IMU on {self.port} answered {name} with {xbus.error_text(code, msg.data)}"
                    )
                if msg.mid == MID.WAKEUP:  # just powered up: keep it in configuration
                    self._write(ser, xbus.build(MID.WAKEUP_ACK), "WakeUpAck")
                    self._woke_up = True
        return None

    # ---- streaming --------------------------------------------------------------------

    def start(self) -> None:
        """Start the reader thread (opens first if needed)."""
        if self._thread is not None and self._thread.is_alive():
            return
        self.open()
        self._stopping.clear()
        self._state = OK
        self._message = f"streaming from {self.port}"
        self._last_sample_ns = None
        self._started_ns = now_ns()
        self._thread = threading.Thread(target=self._run, name="walkcap-imu", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the reader thread; the port stays open. Idempotent."""
        self._stopping.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self._thread = None
        self._state = STOPPED
        self._message = "stopped"

    def close(self) -> None:
        self.stop()
        if self._serial is not None:
            _close_quietly(self._serial)
            self._serial = None

    def _run(self) -> None:
        while not self._stopping.is_set():
            try:
                self._step()
            except _Stop:
                break
            except Exception as e:  # a bug or an odd device must not end the session
                log.exception("IMU reader")
                self._lose(f"reader error: {e}")
                self._stopping.wait(0.1)

    def _step(self) -> None:
        import serial

        if self._serial is None:
            self._retry()
            return
        try:
            waiting = self._serial.in_waiting
            chunk = self._serial.read(waiting if waiting > 0 else 1)
        except (serial.SerialException, OSError, TypeError) as e:
            # TypeError: pyserial reading a port closed under it
            log.info("IMU port %s: %s", self.port, _reason(e))  # pyserial's words: the log's
            self._lose("unplugged, or its port closed")
            return
        t = now_ns()
        # A read returns within 20 ms: a longer pause between steps is the host's own stall
        # (stopped, swapped, starved). The samples the IMU sent meanwhile wait in the port's
        # buffer: silence counts from here, or closing the port would lose them.
        if self._last_step_ns and t - self._last_step_ns > HOST_STALL_NS:
            self._host_resumed_ns = t
            self.clock.excuse(t - self._last_step_ns)  # the backlog arrives that late
        self._last_step_ns = t
        if chunk:
            if self.raw_sink is not None:
                self.raw_sink(chunk)
            for msg in self._parser.feed(chunk):
                self._on_message(msg, t)
        # started: (re)connected
        last = max(self._last_sample_ns or 0, self._started_ns, self._host_resumed_ns)
        if t - last > self.silence_ns:
            self._lose(f"no data for {(t - last) * 1e-9:.1f} s")
        self._count_problems(t)

    def _lose(self, reason: str) -> None:
        t = now_ns()
        if self._state != LOST:
            self._state = LOST
            self._lost_at_ns = t
            self._event(
                "lost",
                f"IMU lost ({reason}); retrying {self.port}",
                t,
                reason=reason,
                port=self.port,
                last_sample_ns=self._last_sample_ns,
            )
        self._message = f"{reason}; retrying {self.port}"  # the state says lost
        if self._serial is not None:
            _close_quietly(self._serial)
            self._serial = None
        self._parser.clear()
        self._next_retry_ns = t + self.retry_ns // 2

    def _retry(self) -> None:
        t = now_ns()
        if t < self._next_retry_ns:
            self._stopping.wait(min(0.05, (self._next_retry_ns - t) * 1e-9))
            return
        self._next_retry_ns = t + self.retry_ns
        try:
            self._connect()
        except DeviceError as e:
            log.debug("IMU reconnect: %s", e)
            self._message = f"{e}; retrying"
            return
        # Connected and measuring: "reconnected" when the first sample arrives.
        self._started_ns = now_ns()

    def _on_message(self, msg: xbus.Message, t: int) -> None:
        if msg.mid == MID.MTDATA2 and msg.mtdata2 is not None:
            self._on_sample(msg, msg.mtdata2, t)
        elif msg.mid == MID.ERROR:
            self.device_errors += 1
            code = msg.data[0] if msg.data else 0
            self._event("device_error", f"IMU sent {xbus.error_text(code, msg.data)}", t, code=code)
        elif msg.mid == MID.WAKEUP:
            self._event("device_restarted", "IMU restarted (WakeUp) while streaming", t)

    def _on_sample(self, msg: xbus.Message, data: xbus.MTData2, t: int) -> None:
        values = data.values
        if self._state == LOST:
            self._reconnected(t)
        counter = values.get("packet_counter")
        if counter is not None:
            if self._last_counter is not None:
                missing = (counter - self._last_counter - 1) & 0xFFFF
                if 0 < missing < 0x8000:  # a larger step is a restarted counter
                    self.missing_packets += missing
                    self._count("missing_packets", missing, t)
            self._last_counter = counter
        # The device took the sample before sending it: remove the wire time.
        t_sent = t - xbus.wire_time_ns(
            len(msg.data) + (5 if len(msg.data) < 255 else 7), self.baudrate
        )
        stf = values.get("sample_time_fine")
        if stf is not None:
            resets = self.clock.resets
            time_ns = self.clock.update(stf, t_sent)
            if self.clock.resets != resets:
                self._event("clock_reset", "IMU clock jumped or restarted: refitting", t)
        else:
            time_ns = t_sent
        self._last_sample_ns = t
        if values.keys() <= _NOT_MEASUREMENTS:
            return  # a status-only message (status faster than the data): no sample
        self._deliver(_sample(values, data.coordinate_systems, t, time_ns))

    def _reconnected(self, t: int) -> None:
        lost_at = self._lost_at_ns or t
        last = self._last_sample_ns if self._last_sample_ns is not None else lost_at
        gap_s = (t - last) * 1e-9
        self.reconnects += 1
        self._state = OK
        self._message = f"streaming from {self.port}"
        self._event(
            "reconnected",
            f"IMU back after a gap of {gap_s:.2f} s",
            t,
            gap_s=gap_s,
            gap_start_ns=last,
            gap_end_ns=t,
            port=self.port,
        )

    # ---- problems and status ----------------------------------------------------------

    def _count(self, kind: str, n: int, t: int) -> None:
        """Report a repeated problem at most once a second, with its count."""
        self._last_problem_ns = t
        pending = self._pending.setdefault(kind, [0, 0])
        pending[1] += n
        if t - pending[0] >= _EVENT_INTERVAL_NS:
            self._flush_count(kind, t)

    def _flush_count(self, kind: str, t: int) -> None:
        pending = self._pending[kind]
        count, pending[1], pending[0] = pending[1], 0, t
        text = {
            "missing_packets": "packets missing (packet counter gaps)",
            "checksum_error": "messages with a bad checksum",
            "resync": "resynchronisations on the byte stream",
            "drop": "samples dropped: the consumer is too slow",
        }[kind]
        self._event(kind, f"IMU: {count} {text}", t, count=count)

    def _count_problems(self, t: int) -> None:
        now = {
            "checksum_errors": self._parser.checksum_errors,
            "resyncs": self._parser.resyncs,
            "dropped": self._buffer.dropped,
        }
        for key, kind in (
            ("checksum_errors", "checksum_error"),
            ("resyncs", "resync"),
            ("dropped", "drop"),
        ):
            new = now[key] - self._seen[key]
            if new > 0:
                self._seen[key] = now[key]
                self._count(kind, new, t)
        for kind, (last, count) in self._pending.items():
            if count and t - last >= _EVENT_INTERVAL_NS:
                self._flush_count(kind, t)

    def status(self) -> DeviceStatus:
        t = now_ns()
        state = self._state
        measured = self._measured_rate()
        if state == OK and (
            t - self._last_problem_ns < 2_000_000_000
            or (t - self._started_ns > 2_500_000_000 and measured < 0.9 * self.configured_rate_hz)
        ):
            state = DEGRADED
        clock = self.clock.state()
        return DeviceStatus(
            backend=self.backend,
            state=state,
            message=self._message,
            configured_rate_hz=self.configured_rate_hz,
            measured_rate_hz=measured,
            delivered=self.delivered,
            dropped=self._buffer.dropped,
            # faults of the device or its link, each kind in details: they add up
            errors=self._parser.checksum_errors + self.missing_packets + self.reconnects,
            details={
                "device_id": self.info.get("device_id", ""),
                "product_code": self.info.get("product_code", ""),
                "family": self.info.get("family", ""),
                "function": self.info.get("function", ""),
                "firmware": self.info.get("firmware", ""),
                "link_budget": self.info.get("link_budget", ""),
                "adjusted": self.info.get("adjusted", []),
                "granted": self.info.get("granted", []),
                "port": self.port,
                "offset_ms": clock.offset_ms,
                "drift_ppm": clock.drift_ppm,
                "drift_uncertainty_ppm": clock.drift_uncertainty_ppm,
                "residual_ms": clock.residual_ms,
                "clock_resets": clock.resets,
                "missing_packets": self.missing_packets,
                "checksum_errors": self._parser.checksum_errors,
                "resyncs": self._parser.resyncs,
                "unknown_ids": self._parser.unknown_ids,
                "device_errors": self.device_errors,
                "reconnects": self.reconnects,
            },
        )


class EmulatedImu(XbusImu):
    """The mock backend: the Xbus driver against an ImuEmulator on a pty it owns."""

    backend = "mock"

    def __init__(
        self,
        rate_hz: int = 100,
        drift_ppm: float = 0.0,
        jitter_ms: float = 0.0,
        seed: int = 0,
        orientation_at: Callable[[float], np.ndarray] | None = None,
        noise: bool = True,
        baudrate: int = 115200,
        model: str = "MTi-3",
        settings_write_s: float | None = None,
        **driver: Any,
    ) -> None:
        from devices.imu_emulator import ImuEmulator

        try:
            self.emulator = ImuEmulator(
                rate_hz=rate_hz,
                drift_ppm=drift_ppm,
                jitter_ms=jitter_ms,
                seed=seed,
                orientation_at=orientation_at,
                noise=noise,
                baudrate=baudrate,
                model=model,
                settings_write_s=settings_write_s,
            )
        except ValueError as e:
            raise DeviceInitError(str(e)) from None
        port = self.emulator.start()
        try:
            super().__init__(port, baudrate, rate_hz, **driver)
        except BaseException:
            self.emulator.stop()
            raise

    @classmethod
    def from_config(cls, config: Any, orientation_at=None) -> EmulatedImu:
        return cls(
            rate_hz=getattr(config, "rate_hz", 100),
            drift_ppm=getattr(config, "drift_ppm", 0.0),
            jitter_ms=getattr(config, "jitter_ms", 0.0),
            seed=getattr(config, "seed", 0),
            orientation_at=orientation_at,
            baudrate=getattr(config, "baudrate", 115200),
            model=getattr(config, "emulate", "MTi-3"),
        )

    def true_time_ns(self, sample_time_fine: int) -> int:
        """When the emulator really took that sample (for sync-accuracy checks)."""
        return self.emulator.true_time_ns(sample_time_fine)

    def inject(self, fault: str, **kw) -> None:
        """A fault of the emulated device (see ImuEmulator.inject)."""
        self.emulator.inject(fault, **kw)

    def close(self) -> None:
        super().close()
        self.emulator.stop()


# ---- helpers ------------------------------------------------------------------------------


def _sample(
    values: dict[str, Any], systems: dict[str, str], host_ns: int, time_ns: int
) -> ImuSample:
    extra = {
        k: _plain(v)
        for k, v in values.items()
        if k
        not in ("packet_counter", "sample_time_fine", "quaternion", "status_word", *_VECTOR_OUTPUTS)
    }
    return ImuSample(
        host_time_ns=host_ns,
        time_ns=int(time_ns),
        packet_counter=values.get("packet_counter"),
        sample_time_fine=values.get("sample_time_fine"),
        quaternion=_orientation(values, systems),
        acceleration=np.array(values["acceleration"]) if "acceleration" in values else None,
        rate_of_turn=np.array(values["rate_of_turn"]) if "rate_of_turn" in values else None,
        status_word=values.get("status_word"),
        extra=extra,
    )


def _orientation(values: dict[str, Any], systems: dict[str, str]) -> np.ndarray | None:
    """Sensor -> ENU quaternion from whichever orientation output the device sent."""
    if "quaternion" in values:
        q, name = np.array(values["quaternion"], dtype=np.float64), "quaternion"
    elif "rotation_matrix" in values:
        q, name = matrix_to_quat(np.array(values["rotation_matrix"])), "rotation_matrix"
    elif "euler" in values:
        q, name = quat_from_euler(*np.radians(values["euler"])), "euler"
    else:
        return None
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm < 1e-6:
        return None
    system = systems.get(name, "ENU")
    if system != "ENU":
        q = quat_multiply(_FRAME_TO_ENU[system], q)
    return quat_normalize(q)


def _rate_text(rate: int) -> str:
    return "every packet" if rate == xbus.EVERY_PACKET else f"{rate} Hz"


def _sampling_rate(settings: list[xbus.OutputSetting]) -> float:
    """The rate of the measurements (the status word and timestamps left aside)."""
    rates = [
        s.rate_hz
        for s in settings
        if s.rate_hz not in (0, xbus.EVERY_PACKET) and s.name not in _NOT_MEASUREMENTS
    ]
    return float(max(rates)) if rates else 0.0


def _rate_that_fits(settings: list, baudrate: int, family: Family | None) -> int | None:
    """The highest rate (one the family has) at which these outputs fit the baud rate."""
    top = int(_sampling_rate(settings) or 0)
    if not top:
        return None
    candidates = family.rates(xbus.XDI["acceleration"]) if family else imu_family.divisor_rates(top)
    for rate in candidates:
        if rate >= top:
            continue
        scaled = [
            xbus.OutputSetting(
                s.xdi, s.rate_hz if s.rate_hz == xbus.EVERY_PACKET else min(s.rate_hz, rate)
            )
            for s in settings
        ]
        if xbus.link_budget(scaled, baudrate).fits:
            return rate
    return None


def _plain(value: Any) -> Any:
    """JSON-friendly: tuples to lists, recursively."""
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


def device_id_text(data: bytes) -> str:
    """A DeviceID as Xsens' library shows it (xsdeviceid.c, XsDeviceId_toString): a legacy
    id in 8 hex digits, a 64-bit one (XS_DID64_BIT, 0x8000_0000, set) in 10 or more. An
    8-byte DeviceID is one 64-bit value when either half is a 64-bit id
    (devicecommunicator.cpp), else its first half."""
    if len(data) == 8:
        high, low = int.from_bytes(data[:4], "big"), int.from_bytes(data[4:], "big")
        value = int.from_bytes(data, "big") if (high | low) & _DID64_BIT else high
    elif len(data) >= 4:
        value = int.from_bytes(data[:4], "big")
    else:
        return data.hex()
    return f"{value:08X}" if not value & _DID64_BIT else f"{value:010X}"


_DID64_BIT = 0x8000_0000


def _firmware_text(data: bytes) -> str:
    if len(data) < 3:
        return data.hex()
    text = f"{data[0]}.{data[1]}.{data[2]}"
    if len(data) >= 11:
        build, revision = int.from_bytes(data[3:7], "big"), int.from_bytes(data[7:11], "big")
        text += f" build {build} rev {revision}"
    return text


def _request_name(mid: int, data: bytes) -> str:
    names = {
        MID.REQ_DID: "ReqDID",
        MID.REQ_PRODUCT_CODE: "ReqProductCode",
        MID.REQ_FW_REV: "ReqFWRev",
        MID.GOTO_CONFIG: "GoToConfig",
        MID.GOTO_MEASUREMENT: "GoToMeasurement",
        MID.RESET: "Reset",
        MID.REQ_BAUDRATE: "SetBaudrate" if data else "ReqBaudrate",
        MID.SET_OUTPUT_CONFIGURATION: "SetOutputConfiguration"
        if data
        else "ReqOutputConfiguration",
    }
    return names.get(mid, xbus.mid_name(mid))


def _reason(e: BaseException) -> str:
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    return str(e) or type(e).__name__


def _close_quietly(ser) -> None:
    try:
        ser.close()
    except Exception:  # the port may already be gone
        pass
