"""Xbus messages: ids, error and baud-rate codes, frames, a streaming parser.

    frame:   FA  BID  MID  LEN [EXTLEN_HI EXTLEN_LO]  DATA...  CS

Pure functions and one small stateful parser, no I/O. Error and baud-rate codes as in
Xsens' public drivers.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from zlib import adler32

from devices.xbus.mtdata2 import MTData2, decode_mtdata2

PREAMBLE = 0xFA
MASTER_BID = 0xFF
EXTENDED_LENGTH = 0xFF
MAX_DATA = 2048  # the largest data length accepted; a longer header is garbage
TICKS_PER_SECOND = 10_000  # SampleTimeFine


class MID(enum.IntEnum):
    REQ_DID = 0x00
    DEVICE_ID = 0x01
    INIT_MT = 0x02
    INIT_MT_RESULTS = 0x03
    REQ_PERIOD = 0x04  # also SetPeriod (legacy string output)
    REQ_PERIOD_ACK = 0x05
    REQ_CONFIGURATION = 0x0C
    CONFIGURATION = 0x0D
    GOTO_MEASUREMENT = 0x10
    GOTO_MEASUREMENT_ACK = 0x11
    REQ_FW_REV = 0x12
    FIRMWARE_REV = 0x13
    REQ_BAUDRATE = 0x18  # also SetBaudrate, with one code byte
    REQ_BAUDRATE_ACK = 0x19
    REQ_PRODUCT_CODE = 0x1C
    PRODUCT_CODE = 0x1D
    REQ_HARDWARE_VERSION = 0x1E
    HARDWARE_VERSION = 0x1F
    GOTO_CONFIG = 0x30
    GOTO_CONFIG_ACK = 0x31
    MTDATA2 = 0x36
    WAKEUP = 0x3E
    WAKEUP_ACK = 0x3F
    RESET = 0x40
    RESET_ACK = 0x41
    ERROR = 0x42
    WARNING = 0x43
    REQ_OPTION_FLAGS = 0x48  # also SetOptionFlags, with set and clear masks
    REQ_OPTION_FLAGS_ACK = 0x49
    REQ_AVAILABLE_FILTER_PROFILES = 0x62
    AVAILABLE_FILTER_PROFILES = 0x63
    REQ_FILTER_PROFILE = 0x64  # also SetFilterProfile
    REQ_FILTER_PROFILE_ACK = 0x65
    REQ_LOCATION_ID = 0x84  # also SetLocationId
    REQ_LOCATION_ID_ACK = 0x85
    REQ_STRING_OUTPUT_TYPE = 0x8E  # also SetStringOutputType
    REQ_STRING_OUTPUT_TYPE_ACK = 0x8F
    SET_OUTPUT_CONFIGURATION = 0xC0  # without data: request the current one
    OUTPUT_CONFIGURATION = 0xC1
    REQ_OUTPUT_SKIP_FACTOR = 0xD4  # also SetOutputSkipFactor (legacy string output)
    REQ_OUTPUT_SKIP_FACTOR_ACK = 0xD5
    REQ_ALIGNMENT_ROTATION = 0xEC  # also SetAlignmentRotation
    REQ_ALIGNMENT_ROTATION_ACK = 0xED


def mid_name(mid: int) -> str:
    try:
        return MID(mid).name
    except ValueError:
        return f"0x{mid:02X}"


# Error codes a device sends in an Error message (MID 0x42): XsResultValue below 256
# (xsresultvalue.h in Xsens' public SDK; values from 256 up are host-side results).
ERROR_CODES = {
    0x00: "ok",
    0x01: "no bus communication",
    0x02: "bus not ready: InitBus or SetBID not issued",
    0x03: "invalid period",
    0x04: "invalid message: not valid or not implemented",
    0x10: "bus initialisation failed (1)",
    0x11: "bus initialisation failed (2)",
    0x12: "bus initialisation failed (3)",
    0x14: "setting the bus id failed (1)",
    0x15: "setting the bus id failed (2)",
    0x18: "measurement failed: timer overflow, the period is too short",
    0x19: "measurement failed (2)",
    0x1A: "measurement failed: more than 255 bytes of data",
    0x1B: "measurement failed: timer overflow (4)",
    0x1C: "measurement failed: timer overflow (5)",
    0x1D: "measurement failed: no correct response",
    0x1E: "timer overflow during measurement",
    0x20: "invalid baud rate",
    0x21: "invalid parameter",
    0x23: "measurement failed: transmit buffer full",
    0x24: "measurement failed: transmit buffer overflow",
    0x25: "wireless failure",
    0x28: "device error (try updating the firmware)",
    0x29: "data overflow: more output than the baud rate carries",
    0x2A: "buffer overflow: the sample buffer filled during a communication outage",
    0x2B: "external trigger error",
    0x2C: "sample stream error",
    0x2D: "power dip",
    0x2E: "power overcurrent",
    0x2F: "overheating",
    0x30: "battery low",
    0x31: "invalid filter profile",
    0x32: "invalid stored settings",
    0x33: "access denied",
    0x34: "file error",
    0x35: "output configuration error: cannot go to measurement",
}
INVALID_PERIOD, INVALID_MESSAGE, INVALID_BAUDRATE, INVALID_PARAMETER = 0x03, 0x04, 0x20, 0x21
DEVICE_ERROR, DATA_OVERFLOW, BUFFER_OVERFLOW, OUTPUT_CONFIG_ERROR = 0x28, 0x29, 0x2A, 0x35
# Error 0x28 carries a u32 XsDeviceErrorType after the code.
DEVICE_ERROR_TYPES = {
    0: "unknown",
    1: "IMCU timeout",
    2: "IMCU settings invalid",
    3: "IMCU settings failure",
    4: "IMCU EMTS write failure",
    5: "IMCU EMTS read failure",
    6: "DSP crashed",
    7: "DSP booting timeout",
    8: "DSP settings invalid",
}

BAUD_CODES = {  # SetBaudrate code -> baud (xsbaudcode.h)
    0x00: 460800,
    0x01: 230400,
    0x02: 115200,
    0x04: 57600,
    0x05: 38400,
    0x07: 19200,
    0x09: 9600,
    0x0B: 4800,
    0x0A: 921600,  # "only usable from MTi/x FW 2.4.6" (xsbaudcode.h)
    0x80: 921600,  # the code Xsens' library sends for 921600 (xsbaud.c, rateToCode)
    0x0C: 2000000,
    0x0E: 3500000,
    0x0D: 4000000,
}
# The code a host sends for each baud rate: 0x80 for 921600, as Xsens' own library does
# (0x0A works only from MTi firmware 2.4.6 on).
BAUD_CODE = {baud: code for code, baud in BAUD_CODES.items() if code != 0x0A}
BAUDRATES = tuple(sorted(BAUD_CODE))


def error_text(code: int, data: bytes = b"") -> str:
    """'Error 0x29 (data overflow: ...)'; with the Error message's data, 0x28's type too."""
    text = f"Error 0x{code:02X} ({ERROR_CODES.get(code, 'a code this driver does not know')})"
    if code == DEVICE_ERROR and len(data) >= 5:
        kind = int.from_bytes(data[1:5], "big")
        text = text[:-1] + f": {DEVICE_ERROR_TYPES.get(kind, f'type {kind}')})"
    return text


def checksum(body: bytes | bytearray) -> int:
    """The checksum byte for BID..DATA: makes the sum from BID to CS 0 modulo 256."""
    return -sum(body) & 0xFF


def build(mid: int, data: bytes = b"", bid: int = MASTER_BID) -> bytes:
    """One Xbus frame; data longer than 254 bytes uses the extended length."""
    n = len(data)
    if n > 0xFFFF:
        raise ValueError(f"Xbus data too long: {n} bytes")
    if n < EXTENDED_LENGTH:
        body = bytes((bid, mid, n)) + data
    else:
        body = bytes((bid, mid, EXTENDED_LENGTH, n >> 8, n & 0xFF)) + data
    return b"\xfa" + body + bytes((checksum(body),))


@dataclass(slots=True)
class Message:
    mid: int
    data: bytes
    bid: int = MASTER_BID
    mtdata2: MTData2 | None = None  # decoded by the parser for MID 0x36

    def frame(self) -> bytes:
        return build(self.mid, self.data, self.bid)


class XbusParser:
    """Turns arbitrary byte chunks into messages; never raises on bad bytes.

    Garbage, a bad header or a bad checksum costs one byte: the parser resynchronises on
    the next preamble. The buffer holds at most one incomplete frame (<= MAX_DATA + 7
    bytes) beyond the chunk being parsed. MTData2 payloads are decoded on the way.
    """

    def __init__(
        self, bus_id: int | None = MASTER_BID, max_data: int = MAX_DATA, decode: bool = True
    ) -> None:
        self.bus_id = bus_id  # None accepts any bus id
        self.max_data = max_data
        self.decode = decode
        self._buf = bytearray()
        # Bytes before the first good message are a start mid-stream, not a loss of sync.
        self._in_sync = False
        self.messages = 0
        self.checksum_errors = 0
        self.resyncs = 0  # times sync was lost after a good message (garbage, bad checksum)
        self.discarded_bytes = 0
        self.unknown_ids = 0  # MTData2 packets skipped (unknown XDI or unexpected size)
        self.malformed = 0  # MTData2 payloads whose packets ran past their end

    def counters(self) -> dict[str, int]:
        return {
            "messages": self.messages,
            "checksum_errors": self.checksum_errors,
            "resyncs": self.resyncs,
            "unknown_ids": self.unknown_ids,
            "malformed": self.malformed,
            "discarded_bytes": self.discarded_bytes,
        }

    def _lose_sync(self, nbytes: int) -> None:
        self.discarded_bytes += nbytes
        if self._in_sync:
            self.resyncs += 1
            self._in_sync = False

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Message]:
        buf = self._buf
        buf += chunk
        out: list[Message] = []
        n = len(buf)
        i = 0
        bus_id = self.bus_id
        decode = self.decode
        while n - i >= 5:
            if buf[i] != PREAMBLE:
                j = buf.find(PREAMBLE, i)
                if j < 0:
                    j = n
                self._lose_sync(j - i)
                i = j
                continue
            bid = buf[i + 1]
            length = buf[i + 3]
            start = i + 4
            if length == EXTENDED_LENGTH:
                if n - i < 7:
                    break
                length = buf[i + 4] << 8 | buf[i + 5]
                start = i + 6
            if (bus_id is not None and bid != bus_id) or length > self.max_data:
                self._lose_sync(1)
                i += 1
                continue
            end = start + length  # index of the checksum byte
            if end >= n:
                break  # incomplete: wait for more bytes
            # Adler-32's low half is the byte sum modulo 65521: exact (and much faster than
            # sum()) while the sum stays below 65521, i.e. for frames up to 257 bytes.
            if (
                adler32(buf[i + 1 : end + 1], 0) if end - i <= 256 else sum(buf[i + 1 : end + 1])
            ) & 0xFF:
                self.checksum_errors += 1
                self._lose_sync(1)
                i += 1
                continue
            mid = buf[i + 2]
            data = bytes(buf[start:end])
            if mid == 0x36 and decode:
                try:
                    decoded = decode_mtdata2(data)
                except (struct.error, IndexError, TypeError, ValueError, KeyError):
                    # A payload no layout explains: counted, its values not given.
                    decoded = None
                    self.malformed += 1
                out.append(Message(mid, data, bid, decoded))
                if decoded is not None and decoded.skipped:
                    self.unknown_ids += len(decoded.skipped)
                if decoded is not None and decoded.truncated:
                    self.malformed += 1
            else:
                out.append(Message(mid, data, bid))
            self._in_sync = True
            i = end + 1
        if i:
            del buf[:i]
        self.messages += len(out)
        return out

    def finish(self) -> list[Message]:
        """End of stream: give up on an incomplete frame and parse what follows it."""
        out: list[Message] = []
        while self._buf:
            del self._buf[:1]
            self._lose_sync(1)
            out += self.feed(b"")
        return out

    def clear(self) -> None:
        """Drop buffered bytes without counting them (a port reopened)."""
        self._buf.clear()
        self._in_sync = False

    @property
    def buffered(self) -> int:
        return len(self._buf)


def parse(data: bytes) -> list[Message]:
    """Every message in a complete byte string (a capture, a test fixture)."""
    parser = XbusParser()
    return parser.feed(data) + parser.finish()
