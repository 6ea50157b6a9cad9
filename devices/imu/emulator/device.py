"""The emulated MTi: its life cycle, its modes (configuration, measurement) and its faults.

`ImuEmulator` runs one device on a `PtyLine` (line.py): on open and configuration it
answers what a device of its family answers (settings.py), streams MTData2 at the
configured rate from its own clock (which drifts against the host's by `drift_ppm`)
with values from its `Motion` (samples.py), paces each message by its wire time at
`baudrate` plus random transmit jitter, and injects faults on command. It plays one model
(`model`, `[imu] emulate`: "MTi-3", "MTi-630", "MTi-1", ...) by that family's rules, takes
its time over settings writes, keeps its baud rate until SetBaudrate and a Reset change it
(it then boots for `reset_s`, deaf and silent, before its WakeUp), and hears only a host
whose line runs at that rate.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable

import numpy as np

from devices import clock, xbus
from devices.clock import now_ns
from devices.imu.emulator.line import PtyLine
from devices.imu.emulator.samples import EmulatorClock, Motion, gait_orientation
from devices.imu.emulator.settings import Answer, DeviceSettings, error
from devices.imu.family import emulated_model
from devices.orientation_error import OrientationErrorModel
from devices.xbus import MID

log = logging.getLogger(__name__)

FAULTS = ("corrupt", "drop", "hang", "disconnect", "reconnect", "error")
# Requests a device in measurement mode accepts; the rest need GoToConfig first.
_MEASUREMENT_OK = frozenset(
    {MID.GOTO_CONFIG, MID.GOTO_MEASUREMENT, MID.RESET, MID.REQ_DID, MID.WAKEUP_ACK}
)
# Requests that carry no data, and their replies.
_NO_DATA = {
    MID.GOTO_CONFIG: MID.GOTO_CONFIG_ACK,
    MID.GOTO_MEASUREMENT: MID.GOTO_MEASUREMENT_ACK,
    MID.REQ_DID: MID.DEVICE_ID,
    MID.INIT_MT: MID.INIT_MT_RESULTS,
    MID.REQ_FW_REV: MID.FIRMWARE_REV,
    MID.REQ_PRODUCT_CODE: MID.PRODUCT_CODE,
    MID.RESET: MID.RESET_ACK,
}
_SPIN_NS = 200_000


def _precise_timers() -> None:
    """Wake this thread on time: Linux lets a sleep overrun by its timer slack (50 us by
    default); a device sends on its own clock, so the emulator asks for 1 us."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(29, 1000, 0, 0, 0)  # PR_SET_TIMERSLACK, this thread only
    except (OSError, AttributeError):
        pass


class ImuEmulator:
    """An MTi on a pty. `start()` returns the port path; see the package docstring."""

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
        code, model_id, self.family = emulated_model(model)
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
        self.noise = noise
        self.orientation_error = orientation_error
        if device_id_size not in (4, 8):
            raise ValueError(f"IMU emulator: a DeviceID has 4 or 8 bytes, not {device_id_size}")
        self.reset_s = reset_s  # silent this long after a Reset, then WakeUp
        self.settings = DeviceSettings(
            self.family,
            self.rate_hz,
            model_id if device_id is None else device_id,
            device_id_size,
            code if product_code is None else product_code,
            firmware,
        )
        self.wakeup_s = wakeup_s
        self._rng = np.random.default_rng(seed)
        self._start_ticks = (
            int(self._rng.integers(0, 2**32)) if start_ticks is None else start_ticks % 2**32
        )
        self.motion = Motion(
            orientation_at or gait_orientation,
            self._rng,
            noise,
            orientation_error,
            gnss=self.family.function == "GNSS/INS",
        )
        self.line = PtyLine(baudrate)
        self._pending_baudrate: int | None = None  # SetBaudrate: applies after a Reset
        self._commands: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self.port: str | None = None
        self.start_time_ns: int | None = None  # session clock at start()
        self.sent = 0  # MTData2 messages written
        self.requests: list[int] = []  # MIDs received, for tests and `--verbose`
        self.last_request_data: dict[int, bytes] = {}  # MID -> data of its latest request
        self._error_ahead: int | None = None  # an Error to send ahead of the next reply

    @property
    def baudrate(self) -> int:
        """The device's UART rate (a SetBaudrate applies from the next Reset)."""
        return self.line.baudrate

    @property
    def product_code(self) -> str:
        return self.settings.product_code

    @property
    def plugged(self) -> bool:
        return self.line.plugged

    # ---- life cycle -----------------------------------------------------------------------

    def start(self) -> str:
        """Power up, plug in, start streaming; returns the stable port path."""
        if self._thread is not None:
            return self.port  # type: ignore[return-value]
        self.port = self.line.create()
        self.start_time_ns = now_ns()  # orientation_at(0) is this instant
        self._utc_at_start_ns = time.time_ns()
        self.clock = EmulatorClock(self.start_time_ns, self._start_ticks, self.drift_ppm)
        self._power_up(self.start_time_ns)
        self.line.plug()
        self._thread = threading.Thread(target=self._run, name="walkcap-imu-emulator", daemon=True)
        self._thread.start()
        return self.port

    def stop(self) -> None:
        self._stopping.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self.line.remove()

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

    def true_time_ns(self, sample_time_fine: int) -> int:
        """When the emulator took the sample stamped sample_time_fine (session clock)."""
        return self.clock.true_time_ns(sample_time_fine, now_ns())

    # ---- the device -----------------------------------------------------------------------

    def _power_up(self, t: int, restart_clock: bool = False) -> None:
        if restart_clock:  # a real power cycle: clock and counter start again
            self.clock = EmulatorClock(t, 0, self.drift_ppm)
        self._counter = 0
        self._measuring = False
        self._wakeup_until = t + clock.to_ns(self.wakeup_s)
        self._next_wakeup = t
        self._hang_until = 0
        self._corrupt = 0
        self._garbage = b""
        self._drop = 0
        self._reconnect_at: int | None = None
        self.line.reset(t)

    def _start_measurement(self, t: int) -> None:
        self._measuring = True
        self._wakeup_until = 0
        rates = [
            s.rate_hz
            for s in self.settings.outputs
            if not xbus.rides_every_packet(s.xdi) and s.rate_hz not in (0, xbus.EVERY_PACKET)
        ]
        # Messages go out at the fastest output's rate (the others divide it).
        self._rate = max(rates) if rates else self.rate_hz
        self._period_ticks = 10_000 / self._rate
        self._meas_ticks0 = int(self.clock.ticks_at(t)) + 1  # the next tick
        self._sample_index = 0

    def _run(self) -> None:
        _precise_timers()
        try:
            while not self._stopping.is_set():
                self._step()
        except Exception:  # the device dies, the process must not
            log.exception("IMU emulator stopped")

    def _step(self) -> None:
        line = self.line
        t = now_ns()
        line.flush(t)  # first: what is due goes out before any other work
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
        if line.plugged and not self._measuring and self._next_wakeup <= t < self._wakeup_until:
            # An MTi announces itself once; repeating it lets a host that opens late see it.
            line.transmit(xbus.build(MID.WAKEUP), t)
            self._next_wakeup = t + 100_000_000
        elif self._wakeup_until and t >= self._wakeup_until and not self._measuring:
            self._start_measurement(t)  # no WakeUpAck: measure with the stored settings
        line.flush(t)
        timeout = 0.02
        due = line.next_due()
        if due is not None:
            if due - now_ns() < _SPIN_NS:  # the last moments are waited for by spinning
                while now_ns() < due:
                    time.sleep(0)  # yields the GIL: a bare spin would stall the host's threads
                return
            timeout = min(timeout, clock.seconds(due - now_ns() - _SPIN_NS))
        if self._measuring:
            next_ticks = self._meas_ticks0 + self._sample_index * self._period_ticks
            wait = clock.seconds(self.clock.time_of_ticks(next_ticks) - now_ns())
            timeout = min(timeout, max(0.0, wait))
        if line.plugged:
            if line.wait_readable(timeout):
                self._read(hung)
        else:
            self._stopping.wait(timeout)

    def _read(self, hung: bool) -> None:
        data = self.line.read()
        if hung:
            return  # a hung device does not read its UART
        if not self.line.matches_host():
            return  # the host's UART runs at another rate: the device hears noise
        for msg in self.line.parser.feed(data):
            self.requests.append(msg.mid)
            del self.requests[:-200]
            self.last_request_data[msg.mid] = msg.data
            self._handle(msg, now_ns())

    # ---- samples --------------------------------------------------------------------------

    def _take_samples(self, t: int) -> None:
        while True:
            ticks = self._meas_ticks0 + round(self._sample_index * self._period_ticks)
            taken_at = self.clock.time_of_ticks(ticks)
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
            if not self.line.plugged:
                continue
            since_start = taken_at - (self.start_time_ns or 0)
            payload = self.motion.mtdata2(
                self.settings.outputs,
                self._rate,
                index,
                counter,
                ticks,
                clock.seconds(since_start),
                self._utc_at_start_ns + since_start,  # the host's UTC at start, then its own
            )
            frame = bytearray(xbus.build(MID.MTDATA2, payload))
            if self._corrupt > 0:
                self._corrupt -= 1
                frame[len(frame) // 2] ^= 0xA5
            if self._garbage:
                frame[:0] = self._garbage
                self._garbage = b""
            jitter = self._rng.uniform(0, self.jitter_ms * 1e6) if self.jitter_ms > 0 else 0
            self.line.transmit(bytes(frame), taken_at + int(jitter))
            self.sent += 1

    # ---- requests -------------------------------------------------------------------------

    def _reply(self, mid: int, data: bytes, t: int) -> None:
        if self._error_ahead is not None and mid != MID.ERROR:
            code, self._error_ahead = self._error_ahead, None
            self.line.transmit(xbus.build(MID.ERROR, bytes([code])), t)  # an asynchronous report
        self.line.transmit(xbus.build(mid, data), t)

    def _answer(self, answer: Answer, t: int) -> None:
        if answer.slow:  # the ack of a settings write, once the (slow) write to flash is done
            self.line.transmit(
                xbus.build(answer.mid, answer.data), t + clock.to_ns(self.settings_write_s)
            )
        else:
            self._reply(answer.mid, answer.data, t)

    def _handle(self, msg: xbus.Message, t: int) -> None:
        mid, data = msg.mid, msg.data
        if mid == MID.WAKEUP_ACK:
            if self._wakeup_until and t < self._wakeup_until:
                self._wakeup_until = 0  # stay in configuration
            return
        if self._measuring and mid not in _MEASUREMENT_OK:
            self._answer(error(xbus.INVALID_MESSAGE), t)
            return
        if mid in _NO_DATA and data:
            self._answer(error(xbus.INVALID_MESSAGE), t)  # these requests carry no data
            return
        settings = self.settings
        if mid == MID.GOTO_CONFIG:
            self._measuring = False
            self._wakeup_until = 0
            self._reply(MID.GOTO_CONFIG_ACK, b"", t)
        elif mid == MID.GOTO_MEASUREMENT:
            self._reply(MID.GOTO_MEASUREMENT_ACK, b"", t)
            self._start_measurement(t)
        elif mid in (MID.REQ_DID, MID.INIT_MT):
            self._reply(_NO_DATA[mid], settings.device_id_bytes(), t)
        elif mid == MID.REQ_FW_REV:
            self._reply(MID.FIRMWARE_REV, settings.firmware_bytes(), t)
        elif mid == MID.REQ_PRODUCT_CODE:
            self._reply(MID.PRODUCT_CODE, settings.product_code_bytes(), t)
        elif mid in settings.REQUESTS:
            self._answer(settings.answer(mid, data), t)
        elif mid == MID.REQ_BAUDRATE:
            self._baudrate_request(data, t)
        elif mid == MID.SET_OUTPUT_CONFIGURATION:
            self._answer(settings.output_configuration(data), t)
        elif mid == MID.RESET:
            self._reset(t)
        else:  # anything this device does not know
            self._answer(error(xbus.INVALID_MESSAGE), t)

    def _reset(self, t: int) -> None:
        line = self.line
        self._reply(MID.RESET_ACK, b"", t)
        queued, last = line.queue, line.last_send
        self._power_up(t)
        line.queue, line.last_send = queued, last  # the ack still goes out
        if self._pending_baudrate is not None:  # SetBaudrate applies from the reset
            # The ack leaves at the old rate; then the UART switches.
            line.flush_at_old_rate()
            line.baudrate, self._pending_baudrate = self._pending_baudrate, None
        # Booting: deaf and silent for reset_s, then it announces itself (WakeUp).
        boot = clock.to_ns(self.reset_s)
        self._hang_until = t + boot
        self._next_wakeup = t + boot
        self._wakeup_until = t + boot + clock.to_ns(self.wakeup_s)

    def _baudrate_request(self, data: bytes, t: int) -> None:
        if not data:
            self._reply(MID.REQ_BAUDRATE_ACK, bytes([xbus.BAUD_CODE.get(self.baudrate, 0x02)]), t)
        elif len(data) == 1 and data[0] in xbus.BAUD_CODES:
            self._pending_baudrate = xbus.BAUD_CODES[data[0]]  # effective after a reset
            self._answer(Answer(MID.REQ_BAUDRATE_ACK, slow=True), t)
        elif len(data) == 1:
            self._answer(error(xbus.INVALID_BAUDRATE), t)
        else:
            self._answer(error(xbus.INVALID_MESSAGE), t)

    # ---- faults ---------------------------------------------------------------------------

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
            self._hang_until = t + clock.to_ns(float(kw.get("seconds", 2.0)))
            self.line.queue.clear()
        elif fault == "disconnect":
            self.line.unplug()
            seconds = kw.get("seconds")
            self._reconnect_at = t + clock.to_ns(float(seconds)) if seconds is not None else None
        elif fault == "reconnect":
            self._reconnect_at = None
            if not self.line.plugged:
                self.line.plug()
            if kw.get("power_cycle"):
                self._power_up(t, restart_clock=True)
