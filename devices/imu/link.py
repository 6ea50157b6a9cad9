"""Xbus over a serial port: frames out, messages in, a request and the reply it waits for.

The transport under the driver (pyserial, imported when a port is opened): it opens and
closes the port, changes the line's speed, writes frames, reads chunks into one
`XbusParser`, and waits for a reply. As in Xsens' library (MidReplyObject::isReplyFor),
an Error 0x29 (data overflow) the device sends on its own while a reply is awaited is a
device error reported on the side, not the reply; any other Error is the reply. A WakeUp
while waiting is acknowledged, which keeps a device that just powered up in configuration.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from devices import xbus
from devices.errors import DeviceInitError, DeviceNotAvailable
from devices.xbus import MID

log = logging.getLogger(__name__)

READ_TIMEOUT_S = 0.02  # a read returns within this even when the device is silent


class Stopped(Exception):
    """The driver was told to stop while the link waited for the device."""


class XbusLink:
    """One serial port speaking Xbus. `serial` is the open port (None when closed)."""

    def __init__(
        self,
        port: str,
        baudrate: int,
        *,
        request_timeout_s: float,
        config_timeout_s: float,
        stopping: threading.Event,
        on_device_error: Callable[[str, int], None],
    ) -> None:
        self.port = port
        self.baudrate = int(baudrate)
        self.request_timeout_s = request_timeout_s
        self.config_timeout_s = config_timeout_s
        self.parser = xbus.XbusParser()
        self.serial = None  # serial.Serial while open
        self.woke_up = False  # a WakeUp came (and was acknowledged) while configuring
        self._stopping = stopping
        self._on_device_error = on_device_error  # (message, code) of an unasked Error

    @property
    def is_open(self) -> bool:
        return self.serial is not None

    def open(self) -> None:
        import serial  # pyserial, imported when a port is opened

        try:
            self.serial = serial.Serial(
                self.port, self.baudrate, timeout=READ_TIMEOUT_S, write_timeout=1.0
            )
        except (serial.SerialException, OSError, ValueError) as e:
            raise DeviceNotAvailable(f"cannot open IMU port {self.port}: {reason(e)}") from None
        self.parser.clear()
        self.woke_up = False

    def close(self) -> None:
        if self.serial is not None:
            try:
                self.serial.close()
            except Exception:  # the port may already be gone
                pass
            self.serial = None
        self.parser.clear()

    def set_speed(self, baudrate: int) -> None:
        """Run the host's end of the line at `baudrate`."""
        import serial

        try:
            self.serial.baudrate = baudrate
        except (serial.SerialException, OSError, ValueError) as e:
            raise DeviceNotAvailable(
                f"IMU port {self.port} cannot run at {baudrate} baud: {reason(e)}"
            ) from None
        self.parser.clear()
        self.baudrate = baudrate

    def read(self) -> bytes | None:
        """What the port holds (waiting at most READ_TIMEOUT_S for a byte); None when the
        port failed (unplugged, closed under the reader)."""
        import serial

        try:
            waiting = self.serial.in_waiting
            return self.serial.read(waiting if waiting > 0 else 1)
        except (serial.SerialException, OSError, TypeError) as e:
            # TypeError: pyserial reading a port closed under it
            log.info("IMU port %s: %s", self.port, reason(e))  # pyserial's words: the log's
            return None

    # ---- configuration ------------------------------------------------------------------

    def goto_config(self, timeout: float | None = None, *, raise_: bool = True) -> bool:
        """Into configuration: acknowledge a WakeUp, else GoToConfig until it is acked."""
        timeout = self.config_timeout_s if timeout is None else timeout
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.write(xbus.build(MID.GOTO_CONFIG), "GoToConfig")
            if self.await_reply(MID.GOTO_CONFIG_ACK, "GoToConfig", 0.25) is not None:
                return True
        if not raise_:
            return False
        raise DeviceInitError(
            f"IMU on {self.port}: no answer to GoToConfig within "
            f"{timeout:g} s (is an Xsens device on it, at "
            f"{self.baudrate} baud?)"
        )

    def request(
        self, mid: int, data: bytes = b"", *, reply: int, timeout: float | None = None
    ) -> bytes:
        """Send a request and return the data of its reply; DeviceInitError on none."""
        name = request_name(mid, data)
        timeout = self.request_timeout_s if timeout is None else timeout
        self.write(xbus.build(mid, data), name)
        answer = self.await_reply(reply, name, timeout)
        if answer is None:
            raise DeviceInitError(f"IMU on {self.port}: no answer to {name} within {timeout:g} s")
        return answer

    def write(self, frame: bytes, name: str) -> None:
        import serial

        try:
            self.serial.write(frame)
        except (serial.SerialException, OSError) as e:
            raise DeviceNotAvailable(
                f"IMU port {self.port} failed sending {name}: {reason(e)}"
            ) from None

    def await_reply(self, reply: int, name: str, timeout: float) -> bytes | None:
        """The data of the first `reply` message; None on timeout; Error raises."""
        import serial

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self._stopping.is_set():
                raise Stopped()
            try:
                waiting = self.serial.in_waiting
                chunk = self.serial.read(waiting if waiting > 0 else 1)
            except (serial.SerialException, OSError) as e:
                raise DeviceNotAvailable(
                    f"IMU port {self.port} failed waiting for the answer to {name}: {reason(e)}"
                ) from None
            for msg in self.parser.feed(chunk):
                if msg.mid == reply:
                    return msg.data
                if msg.mid == MID.ERROR and msg.data[:1] == bytes([xbus.DATA_OVERFLOW]):
                    # Output the line could not carry, sent on its own: an event, not the
                    # answer (Xsens' MidReplyObject::isReplyFor skips it the same way).
                    self._on_device_error(
                        f"IMU sent {xbus.error_text(xbus.DATA_OVERFLOW)} while waiting for "
                        f"the answer to {name}",
                        xbus.DATA_OVERFLOW,
                    )
                    continue
                if msg.mid == MID.ERROR:
                    code = msg.data[0] if msg.data else 0
                    raise DeviceInitError(
                        f"IMU on {self.port} answered {name} with {xbus.error_text(code, msg.data)}"
                    )
                if msg.mid == MID.WAKEUP:  # just powered up: keep it in configuration
                    self.write(xbus.build(MID.WAKEUP_ACK), "WakeUpAck")
                    self.woke_up = True
        return None


def request_name(mid: int, data: bytes) -> str:
    """A request as Xsens names it (the same id sets with data and asks without)."""
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


def reason(e: BaseException) -> str:
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    return str(e) or type(e).__name__
