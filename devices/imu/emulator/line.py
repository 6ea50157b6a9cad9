"""The device's end of a serial line: a pseudo-terminal, paced like a UART.

The emulator opens a pty, points a stable path (/tmp/walkcap-XXXXXXXX/ttyIMU, a symlink;
short, as Xsens' tools keep a port name in 32 bytes) at the slave end, and speaks Xbus on
the master end. Each frame leaves after the one before it, one wire time at the device's
baud rate later; more than the line carries piles up in the device's output buffer, and
a full buffer loses messages and reports Error 0x29 (data overflow). A host whose end
runs at another rate reads noise and is not heard. Unplugging removes the symlink and
closes the pty; replugging opens a new pty and re-points the symlink, as udev would, so
the driver reopens the same path.
"""

from __future__ import annotations

import collections
import errno
import fcntl
import logging
import os
import select
import shutil
import tempfile
import termios
import tty

from devices import xbus
from devices.clock import now_ns
from devices.xbus import MID

log = logging.getLogger(__name__)

# Xsens' host library copies the port name into a 32-byte buffer (serialinterface.h,
# m_portname[32]): a path must stay below this length, the terminating zero included.
PORT_NAME_MAX = 32
HOST_BUFFER_BYTES = 65536  # what the host's serial buffer holds while nobody reads it
DEVICE_BUFFER_FRAMES = 64  # the device's output buffer: a frame beyond it is lost
_OVERFLOW_REPORT_NS = 1_000_000_000  # Error 0x29 at most once a second
_SPEEDS = {getattr(termios, f"B{b}"): b for b in xbus.BAUDRATES if hasattr(termios, f"B{b}")}


def _short_tmp() -> str:
    """/tmp where it is writable: a port path under a long $TMPDIR would not fit the 32
    bytes Xsens' tools keep for it."""
    if os.path.isdir("/tmp") and os.access("/tmp", os.W_OK | os.X_OK):
        return "/tmp"
    return tempfile.gettempdir()


class PtyLine:
    """A pty with a stable path, the device's UART pacing and its output buffer."""

    def __init__(self, baudrate: int) -> None:
        self.baudrate = baudrate  # the device's UART
        self._dir: str | None = None
        self.port: str | None = None
        self.master: int | None = None
        self._slave: int | None = None
        self.parser = xbus.XbusParser()  # what the host sends
        self.queue: collections.deque[tuple[int, bytes]] = collections.deque()  # (send at, bytes)
        self.out = bytearray()  # bytes due but not yet taken by the pty
        self.last_send = 0
        self._last_overflow_report = 0
        self.overflow_reports = 0  # Error 0x29 messages sent
        self.overflowed = 0  # messages lost because the baud rate cannot carry them
        self.dropped_on_wire = 0  # bytes lost because nobody read the pty

    # ---- the port -------------------------------------------------------------------------

    def create(self) -> str:
        """The stable path the host opens (the device is not plugged in yet)."""
        self._dir = tempfile.mkdtemp(prefix="walkcap-", dir=_short_tmp())
        self.port = os.path.join(self._dir, "ttyIMU")  # /tmp/walkcap-XXXXXXXX/ttyIMU
        if len(self.port) >= PORT_NAME_MAX:
            log.warning("IMU emulator port %s is too long for Xsens' tools", self.port)
        return self.port

    def remove(self) -> None:
        self.unplug()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None

    def plug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: a binary serial line
        _set_line_speed(slave, self.baudrate)
        flags = fcntl.fcntl(master, fcntl.F_GETFL)
        fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self.master, self._slave = master, slave
        tmp = self.port + ".new"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.port)  # atomic: the path always points at a whole device
        self.parser = xbus.XbusParser()
        log.info("IMU emulator plugged in at %s -> %s", self.port, os.ttyname(slave))

    def unplug(self) -> None:
        if self.port and os.path.lexists(self.port):
            os.unlink(self.port)
        for fd in (self.master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.master = self._slave = None
        self.queue.clear()
        self.out.clear()

    @property
    def plugged(self) -> bool:
        return self.master is not None

    def matches_host(self) -> bool:
        """Whether the host's end of the line runs at the device's baud rate."""
        if self._slave is None:
            return True
        try:
            speed = termios.tcgetattr(self._slave)[5]
        except termios.error:
            return True
        host = _SPEEDS.get(speed)
        return host is None or host == self.baudrate

    # ---- to the host ----------------------------------------------------------------------

    def reset(self, t: int) -> None:
        """Power up: nothing queued, the line free from t."""
        self.queue = collections.deque()
        self.out = bytearray()
        self.last_send = t

    def transmit(self, frame: bytes, ready_at: int) -> None:
        """Send a frame from ready_at, after the one before it: the host has it all one wire
        time later. More than the line carries piles up, then overflows the device."""
        # The device's buffer at ready_at: frames on the wire by then have left it (this
        # thread catching up after the host starved it is no overflow of the device).
        while self.queue and self.queue[0][0] <= ready_at:
            self.out += self.queue.popleft()[1]
        if len(self.queue) >= DEVICE_BUFFER_FRAMES:  # the device's buffer is full: lost
            self.overflowed += 1
            if ready_at - self._last_overflow_report >= _OVERFLOW_REPORT_NS:
                self._last_overflow_report = ready_at
                self.overflow_reports += 1
                error = xbus.build(MID.ERROR, bytes([xbus.DATA_OVERFLOW]))
                start = max(ready_at, self.last_send)
                self.last_send = start + xbus.wire_time_ns(len(error), self.baudrate)
                self.queue.append((self.last_send, error))
            return
        start = max(ready_at, self.last_send)
        self.last_send = start + xbus.wire_time_ns(len(frame), self.baudrate)
        self.queue.append((self.last_send, frame))

    def next_due(self) -> int | None:
        """When the next queued frame is on the host's side."""
        return self.queue[0][0] if self.queue else None

    def flush(self, t: int) -> None:
        """Hand the pty what is due by t."""
        while self.queue and self.queue[0][0] <= t:
            self.out += self.queue.popleft()[1]
        if not self.out or not self.plugged:
            return
        if not self.matches_host():  # another rate on the host's side: it reads noise
            self.out = bytearray(b ^ 0x5A for b in self.out)
        try:
            n = os.write(self.master, self.out)
            del self.out[:n]
        except OSError as e:
            if e.errno not in (errno.EAGAIN, errno.EIO):
                raise
        if len(self.out) > HOST_BUFFER_BYTES:
            # Nobody reads: as on a UART, the host's full buffer keeps the oldest bytes and
            # the ones arriving now are lost; the host reads what it kept once it runs.
            self.dropped_on_wire += len(self.out) - HOST_BUFFER_BYTES
            del self.out[HOST_BUFFER_BYTES:]

    def flush_at_old_rate(self) -> None:
        """Send what is queued now, before the line changes speed."""
        while self.queue:
            self.out += self.queue.popleft()[1]
        if self.out and self.plugged:
            try:
                n = os.write(self.master, self.out)
                del self.out[:n]
            except OSError:
                pass
        self.last_send = now_ns()

    # ---- from the host --------------------------------------------------------------------

    def wait_readable(self, timeout: float) -> bool:
        """Whether the host sent something within `timeout` s."""
        try:
            readable, _, _ = select.select([self.master], [], [], timeout)
        except (OSError, ValueError):
            return False
        return bool(readable)

    def read(self) -> bytes:
        """What the host sent (b"" when nothing is there)."""
        try:
            return os.read(self.master, 4096)
        except OSError as e:
            if e.errno not in (errno.EAGAIN, errno.EIO):
                raise
            return b""


def _set_line_speed(fd: int, baudrate: int) -> None:
    speed = next((k for k, v in _SPEEDS.items() if v == baudrate), None)
    if speed is None:
        return
    attrs = termios.tcgetattr(fd)
    attrs[4] = attrs[5] = speed
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
