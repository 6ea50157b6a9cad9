"""The Xbus driver: an Xsens MTi (or anything speaking Xbus) on a serial port.

`XbusImu` is the device's state machine over an `XbusLink`: open puts the device in
configuration (GoToConfig, or acknowledging its WakeUp), identifies it, sets (or reads)
its outputs and checks them against the family and the link budget (devices/imu/outputs.py),
then GoToMeasurement; a reader thread turns MTData2 messages into samples. Samples:
`time_ns` is the device's SampleTimeFine mapped onto the session clock by the clock
estimator (devices/imu/clock.py), `host_time_ns` the receive time. A vanished or silent
port is reported within a second, retried until it returns, and the gap reported; the
reader thread never dies with the device.

Configuring follows Xsens' own rules (devices/imu/family.py): the family comes from the
product code, and the stream must fit the baud rate before GoToMeasurement, else one line
names a rate or baud rate that fits.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from devices import clock, xbus
from devices.base import DEGRADED, LOST, OK, STOPPED, DeviceStatus, Producer
from devices.clock import now_ns
from devices.errors import DeviceError, DeviceInitError, DeviceNotAvailable
from devices.imu import outputs
from devices.imu.base import Imu
from devices.imu.clock import DeviceClock
from devices.imu.family import Family, family_of
from devices.imu.link import Stopped, XbusLink
from devices.watchdog import EventThrottle, SilenceWatch
from devices.xbus import MID

log = logging.getLogger(__name__)

HOST_STALL_NS = 250_000_000  # no reader step for this long: the host stalled (reads take 20 ms)
_PROBLEMS = {  # a repeated problem's kind -> what its event counts
    "missing_packets": "packets missing (packet counter gaps)",
    "checksum_error": "messages with a bad checksum",
    "resync": "resynchronisations on the byte stream",
    "drop": "samples dropped: the consumer is too slow",
}


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
        self._reader = Producer("walkcap-imu", self._run)
        self._stopping = self._reader.halt
        self.link = XbusLink(
            port,
            baudrate,
            request_timeout_s=request_timeout_s,
            config_timeout_s=config_timeout_s,
            stopping=self._stopping,
            on_device_error=self._device_error,
        )
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
        self.retry_ns = clock.to_ns(retry_s)
        self.raw_sink = raw_sink
        self.configured_rate_hz = float(self.rate_hz)
        self.clock = DeviceClock()
        self._state = STOPPED
        self._message = "not started"
        self._last_sample_ns: int | None = None
        self._lost_at_ns: int | None = None
        self._next_retry_ns = 0
        self._last_counter: int | None = None
        self.missing_packets = 0
        self.reconnects = 0
        self.device_errors = 0
        self._problems = EventThrottle(self._report_problems)
        self._seen = {"checksum_errors": 0, "resyncs": 0, "dropped": 0}
        self._last_problem_ns = 0
        self._started_ns = now_ns()
        self._watch = SilenceWatch(HOST_STALL_NS)  # the reader's steps (see _step)

    @classmethod
    def from_config(cls, config: Any, orientation_at=None) -> XbusImu:
        return cls(
            getattr(config, "port", ""),
            getattr(config, "baudrate", 115200),
            getattr(config, "rate_hz", 100),
        )

    @property
    def baudrate(self) -> int:
        """The line's speed on the host's side (the device's after a baud-rate change)."""
        return self.link.baudrate

    # ---- configuration ------------------------------------------------------------------

    def open(self) -> None:
        """Open the port and configure the device; then it measures. Idempotent."""
        if self.link.is_open:
            return
        self._stopping.clear()
        self._connect()
        self._message = f"configured, {self.configured_rate_hz:g} Hz"

    def _connect(self) -> None:
        self.link.open()
        try:
            self._configure()
        except BaseException:
            self.link.close()
            raise

    def _configure(self) -> None:
        """WakeUp/GoToConfig, identify, set (or read) the outputs, check the link budget,
        GoToMeasurement."""
        link = self.link
        link.goto_config()
        device_id = link.request(MID.REQ_DID, reply=MID.DEVICE_ID)
        product = link.request(MID.REQ_PRODUCT_CODE, reply=MID.PRODUCT_CODE)
        firmware = link.request(MID.REQ_FW_REV, reply=MID.FIRMWARE_REV)
        product_code = product.decode("ascii", "replace").strip("\x00 ")
        self.family = family_of(product_code)
        if self.family is None:
            log.warning(
                "IMU on %s: product code %r is not a family this driver knows: "
                "asking for the configured outputs as they are",
                self.port,
                product_code,
            )
        request = self._fit(self._settings, product_code) if self._settings else None
        reply = link.request(
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
            self.granted = outputs.granted_differences(request, settings)
            for text in self.granted:
                self._say("output_granted", f"IMU {product_code}: {text}")
        self.budget = xbus.link_budget(settings, self.baudrate)
        if request and not self.budget.fits:
            raise DeviceInitError(
                outputs.budget_refusal(
                    settings, self.budget, self.baudrate, self.family, self.port, product_code
                )
            )
        link.request(MID.GOTO_MEASUREMENT, reply=MID.GOTO_MEASUREMENT_ACK)
        self.configured_rate_hz = outputs.sampling_rate(settings) or float(self.rate_hz)
        self.info = {
            "device_id": device_id_text(device_id),
            "product_code": product_code,
            "family": self.family.name if self.family else "unknown",
            "function": self.family.function if self.family else "unknown",
            "firmware": firmware_text(firmware),
            "output_configuration": [s.describe() for s in settings],
            "adjusted": list(self.adjusted),
            "granted": list(self.granted),
            "link_budget": self.budget.describe(),
            "port": self.port,
            "baudrate": self.baudrate,
            "woke_up": link.woke_up,  # it had just powered up and sent WakeUp
        }
        self._last_counter = None

    def _settings_timeout_s(self) -> float:
        """Settings writes are slow (about 900 ms on the 1-series): twice that, at least."""
        slowest = self.family.settings_write_s if self.family else 0.9
        return max(self.link.request_timeout_s, 2.0 * slowest + 0.2)

    def _fit(self, settings: list[xbus.OutputSetting], product_code: str) -> list:
        """The request fitted to the family (what changed said once, as `adjusted`)."""
        if self.family is None:
            return settings
        fitted, self.adjusted = outputs.fit_to_family(settings, self.family, product_code)
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

    def change_baudrate(self, baudrate: int) -> None:
        """Set the device's baud rate as Xsens' tools do: SetBaudrate (acknowledged at the
        old rate; 921600 as code 0x80, as xsbaud.c sends it), Reset, then the new rate on
        both ends, the device found again within reset_timeout_s. The device keeps it
        across power cycles. The port must not be open in this driver."""
        if baudrate not in xbus.BAUD_CODE:
            known = ", ".join(str(b) for b in xbus.BAUDRATES)
            raise DeviceInitError(f"{baudrate} is not a baud rate an MTi has (known: {known})")

        link = self.link
        link.open()
        try:
            link.goto_config()
            product = link.request(MID.REQ_PRODUCT_CODE, reply=MID.PRODUCT_CODE)
            self.family = family_of(product.decode("ascii", "replace"))
            code = xbus.BAUD_CODE[baudrate]
            link.request(
                MID.REQ_BAUDRATE,
                bytes([code]),
                reply=MID.REQ_BAUDRATE_ACK,
                timeout=self._settings_timeout_s(),
            )
            link.request(MID.RESET, reply=MID.RESET_ACK)  # the new rate applies now
            before = self.baudrate
            link.set_speed(baudrate)
            self._redetect(before)
            reply = link.request(MID.REQ_BAUDRATE, reply=MID.REQ_BAUDRATE_ACK)
            if not reply or xbus.BAUD_CODES.get(reply[0]) != baudrate:
                raise DeviceInitError(
                    f"IMU on {self.port} reports baud code {reply.hex() or 'none'} "
                    f"after SetBaudrate {baudrate}"
                )
        finally:
            link.close()

    def _redetect(self, before: int) -> None:
        """Find the device again after the Reset of a baud-rate change. It boots for a while
        (Xsens' scanner waits 2 s, then scans the baud rates): GoToConfig at the new rate
        until reset_timeout_s; then one look at the old rate, to say which it is."""
        after = self.baudrate
        if self.link.goto_config(self.reset_timeout_s, raise_=False):
            return  # acknowledges the WakeUp after the reset: stays in configuration
        self.link.set_speed(before)
        if self.link.goto_config(self.link.config_timeout_s, raise_=False):
            raise DeviceInitError(
                f"IMU on {self.port} still answers at {before} baud, not {after}, after "
                f"SetBaudrate and Reset: the change did not take"
            )
        raise DeviceInitError(
            f"IMU on {self.port}: no answer at {after} baud within {self.reset_timeout_s:g} s "
            f"of the Reset, nor at {before} baud"
        )

    # ---- measurement ----------------------------------------------------------------------

    def start(self) -> None:
        """Start the reader thread (opens first if needed)."""
        if self._reader.running:
            return
        self.open()
        self._state = OK
        self._message = f"streaming from {self.port}"
        self._last_sample_ns = None
        self._started_ns = now_ns()
        self._reader.start()

    def stop(self) -> None:
        """Stop the reader thread; the port stays open. Idempotent."""
        self._reader.stop()
        self._state = STOPPED
        self._message = "stopped"

    def close(self) -> None:
        self.stop()
        self.link.close()

    def _run(self) -> None:
        while not self._stopping.is_set():
            try:
                self._step()
            except Stopped:
                break
            except Exception as e:  # a bug or an odd device must not end the session
                log.exception("IMU reader")
                self._lose(f"reader error: {e}")
                self._stopping.wait(0.1)

    def _step(self) -> None:
        if not self.link.is_open:
            self._retry()
            return
        chunk = self.link.read()
        if chunk is None:
            self._lose("unplugged, or its port closed")
            return
        t = now_ns()
        # A read returns within 20 ms: a longer pause between steps is the host's own stall
        # (stopped, swapped, starved). The samples the IMU sent meanwhile wait in the port's
        # buffer: silence counts from here, or closing the port would lose them.
        if self._watch.check(t):
            self.clock.excuse(t)  # the samples taken until now arrive late: a backlog
        if chunk:
            if self.raw_sink is not None:
                self.raw_sink(chunk)
            for msg in self.link.parser.feed(chunk):
                self._on_message(msg, t)
        # started: (re)connected
        last = self._watch.since(max(self._last_sample_ns or 0, self._started_ns))
        if t - last > self.silence_ns:
            self._lose(f"no data for {clock.seconds(t - last):.1f} s")
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
        self.link.close()
        self._next_retry_ns = t + self.retry_ns // 2

    def _retry(self) -> None:
        t = now_ns()
        if t < self._next_retry_ns:
            self._stopping.wait(min(0.05, clock.seconds(self._next_retry_ns - t)))
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
            code = msg.data[0] if msg.data else 0
            self._device_error(f"IMU sent {xbus.error_text(code, msg.data)}", code, t)
        elif msg.mid == MID.WAKEUP:
            self._event("device_restarted", "IMU restarted (WakeUp) while streaming", t)

    def _device_error(self, message: str, code: int, t: int | None = None) -> None:
        self.device_errors += 1
        self._event("device_error", message, t, code=code)

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
        if not outputs.is_measurement(values):
            return  # a status-only message (status faster than the data): no sample
        self._deliver(outputs.imu_sample(values, data.coordinate_systems, t, time_ns))

    def _reconnected(self, t: int) -> None:
        lost_at = self._lost_at_ns or t
        last = self._last_sample_ns if self._last_sample_ns is not None else lost_at
        gap_s = clock.seconds(t - last)
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

    # ---- problems and status ------------------------------------------------------------

    def _count(self, kind: str, n: int, t: int) -> None:
        """Report a repeated problem at most once a second, with its count."""
        self._last_problem_ns = t
        self._problems.add(kind, n, t)

    def _report_problems(self, kind: str, count: int, t: int) -> None:
        self._event(kind, f"IMU: {count} {_PROBLEMS[kind]}", t, count=count)

    def _count_problems(self, t: int) -> None:
        parser = self.link.parser
        now = {
            "checksum_errors": parser.checksum_errors,
            "resyncs": parser.resyncs,
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
        self._problems.flush(t)

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
        parser = self.link.parser
        return DeviceStatus(
            backend=self.backend,
            state=state,
            message=self._message,
            configured_rate_hz=self.configured_rate_hz,
            measured_rate_hz=measured,
            delivered=self.delivered,
            dropped=self._buffer.dropped,
            # faults of the device or its link, each kind in details: they add up
            errors=parser.checksum_errors + self.missing_packets + self.reconnects,
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
                "checksum_errors": parser.checksum_errors,
                "resyncs": parser.resyncs,
                "unknown_ids": parser.unknown_ids,
                "device_errors": self.device_errors,
                "reconnects": self.reconnects,
            },
        )


# ---- what the device says about itself -----------------------------------------------------

_DID64_BIT = 0x8000_0000


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


def firmware_text(data: bytes) -> str:
    if len(data) < 3:
        return data.hex()
    text = f"{data[0]}.{data[1]}.{data[2]}"
    if len(data) >= 11:
        build, revision = int.from_bytes(data[3:7], "big"), int.from_bytes(data[7:11], "big")
        text += f" build {build} rev {revision}"
    return text
