"""The Xsens Xbus protocol: message frames, a streaming parser, MTData2 decode and encode.

Pure functions and one small stateful parser, no I/O: the driver, the emulator, the
`walkcap imu decode` command and the tests all use this module. Facts from
../shared/notes/xbus.md; error and baud-rate codes as in Xsens' public drivers.

    frame:   FA  BID  MID  LEN [EXTLEN_HI EXTLEN_LO]  DATA...  CS
    MTData2: a sequence of  XDI (u16) | size (u8) | data (size bytes)

Decoded MTData2 values use walkcap's names (`quaternion` [w, x, y, z], `euler` [roll,
pitch, yaw] degrees, `rotation_matrix` as three rows, ...). Vectors are tuples of floats,
counters and bit fields ints.
"""

from __future__ import annotations

import enum
import operator
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any
from zlib import adler32

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


# --------------------------------------------------------------------------- frames


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
class MTData2:
    """One decoded MTData2 payload."""

    values: dict[str, Any]  # output name -> value (see OUTPUTS)
    # Output name -> "ENU" | "NED" | "NWU" for orientation and free acceleration outputs.
    # Shared between messages of the same layout: read it, do not modify it.
    coordinate_systems: dict[str, str] = field(default_factory=dict)
    skipped: tuple[int, ...] = ()  # XDIs skipped: unknown, unexpected size or a repeat
    truncated: bool = False  # a packet ran past the end of the payload


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


# --------------------------------------------------------------------------- MTData2

FLOAT32, FP1220, FP1632, FLOAT64 = 0, 1, 2, 3
PRECISION_NAMES = {FLOAT32: "float32", FP1220: "fp1220", FP1632: "fp1632", FLOAT64: "float64"}
ENU, NED, NWU = 0x0, 0x4, 0x8
COORDINATE_SYSTEMS = {ENU: "ENU", NED: "NED", NWU: "NWU"}
_COORDINATE_CODES = {v: k for k, v in COORDINATE_SYSTEMS.items()}
# Rows: the axes of each world frame in ENU coordinates (v_frame = M @ v_enu).
FRAME_FROM_ENU = {
    "ENU": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "NED": ((0, 1, 0), (1, 0, 0), (0, 0, -1)),
    "NWU": ((0, 1, 0), (-1, 0, 0), (0, 0, 1)),
}
_REAL_FORMATS = {FLOAT32: ("f", 4), FP1220: ("i", 4), FP1632: ("Ih", 6), FLOAT64: ("d", 8)}

# xdi & 0xFFF0 -> (name, kind, count). kind "real" honours the precision bits.
OUTPUTS: dict[int, tuple[str, str, int]] = {
    0x0810: ("temperature", "real", 1),
    0x1010: ("utc_time", "utc", 1),
    0x1020: ("packet_counter", "u16", 1),
    0x1060: ("sample_time_fine", "u32", 1),
    0x1070: ("sample_time_coarse", "u32", 1),
    0x2010: ("quaternion", "real", 4),
    0x2020: ("rotation_matrix", "real", 9),
    0x2030: ("euler", "real", 3),
    0x3010: ("baro_pressure", "u32", 1),
    0x4010: ("delta_v", "real", 3),
    0x4020: ("acceleration", "real", 3),
    0x4030: ("free_acceleration", "real", 3),
    0x8020: ("rate_of_turn", "real", 3),
    0x8030: ("delta_q", "real", 4),
    0xC020: ("magnetic_field", "real", 3),
    0xE020: ("status_word", "u32", 1),
}
XDI = {name: xdi for xdi, (name, _, _) in OUTPUTS.items()}
# Outputs expressed in a world frame, where the coordinate-system bits mean something.
WORLD_FRAME_OUTPUTS = frozenset({"quaternion", "rotation_matrix", "euler", "free_acceleration"})
# Integer kinds. UtcTime (XsUtcTime): nanoseconds u32, year u16, month, day, hour, minute,
# second, flags u8 (flags 0x04: UTC valid, as a GNSS receiver sets it).
_INT_FORMATS = {"u16": ("H", 2), "u32": ("I", 4), "utc": ("IHBBBBBB", 12)}


def value_size(xdi: int) -> int | None:
    """The data size of a known identifier, None for an unknown one."""
    known = OUTPUTS.get(xdi & 0xFFF0)
    if known is None:
        return None
    _, kind, count = known
    if kind == "real":
        return _REAL_FORMATS[xdi & 0x3][1] * count
    return _INT_FORMATS[kind][1]


_FP1220_SCALE = 2.0**-20
_FP1632_SCALE = 2.0**-32


def _from_fp1220(raw: tuple, count: int) -> Any:
    v = tuple(x * _FP1220_SCALE for x in raw)
    return v[0] if count == 1 else v


def _from_fp1632(raw: tuple, count: int) -> Any:
    # Each value unpacks as (fraction u32, integer part i16).
    v = tuple(raw[2 * k + 1] + raw[2 * k] * _FP1632_SCALE for k in range(count))
    return v[0] if count == 1 else v


def _columns_to_rows(c: tuple) -> tuple[tuple[float, ...], ...]:
    return ((c[0], c[3], c[6]), (c[1], c[4], c[7]), (c[2], c[5], c[8]))


def _getter(items: list) -> Any:
    """itemgetter that always returns a tuple (even for zero or one item)."""
    if not items:
        return lambda vals: ()
    if len(items) == 1:
        item = items[0]
        return lambda vals: (vals[item],)
    return operator.itemgetter(*items)


class _Layout:
    """A compiled MTData2 layout: one struct for the whole payload, headers included.

    Devices send the same layout in every message, so decoding is one unpack, a check
    that the headers are the expected ones, and one itemgetter picking each output's
    values (an index or a slice) out of the unpacked tuple.
    """

    def __init__(self, headers: tuple[tuple[int, int], ...]) -> None:
        fmt = [">"]
        header_idx: list[int] = []
        expected: list[int] = []
        names: list[str] = []
        items: list[int | slice] = []
        convert: list[tuple[str, Any, int]] = []  # fixed point and matrices
        skipped: list[int] = []
        systems: dict[str, str] = {}
        idx = 0
        for xdi, size in headers:
            fmt.append("HB")
            header_idx += [idx, idx + 1]
            expected += [xdi, size]
            idx += 2
            known = OUTPUTS.get(xdi & 0xFFF0)
            # A repeated output is skipped: decoding it twice would convert one value twice.
            if known is None or value_size(xdi) != size or known[0] in names:
                fmt.append(f"{size}x")
                skipped.append(xdi)
                continue
            name, kind, count = known
            names.append(name)
            if kind != "real":
                code = _INT_FORMATS[kind][0]
                fmt.append(code)
                items.append(idx if len(code) == 1 else slice(idx, idx + len(code)))
                idx += len(code)
                continue
            precision = xdi & 0x3
            code = _REAL_FORMATS[precision][0]
            fmt.append(code * count)
            n = len(code) * count
            # A lone float is picked as a value; fixed point as a slice for its converter.
            items.append(idx if n == 1 and precision != FP1220 else slice(idx, idx + n))
            idx += n
            if precision == FP1220:
                convert.append((name, _from_fp1220, count))
            elif precision == FP1632:
                convert.append((name, _from_fp1632, count))
            if name == "rotation_matrix":  # column-major on the wire, rows in walkcap
                convert.append((name, lambda c, _n: _columns_to_rows(c), count))
            if name in WORLD_FRAME_OUTPUTS:
                systems[name] = COORDINATE_SYSTEMS.get(xdi & 0xC, "ENU")
        self.struct = struct.Struct("".join(fmt))
        self.headers = tuple(expected)
        self._get_headers = _getter(header_idx)
        self._names = tuple(names)
        self._pick = _getter(items)
        self._convert = convert
        self.skipped = tuple(skipped)
        self.systems = systems

    def matches(self, vals: tuple) -> bool:
        return self._get_headers(vals) == self.headers

    def values(self, vals: tuple) -> dict[str, Any]:
        out = dict(zip(self._names, self._pick(vals)))
        for name, convert, count in self._convert:
            out[name] = convert(out[name], count)
        return out


_LAYOUTS: dict[int, list[_Layout]] = {}  # payload length -> layouts seen with it
_MAX_LAYOUTS = 64


def _headers_of(payload: bytes) -> tuple[tuple[tuple[int, int], ...], int]:
    """Walk the packet headers: (headers, bytes covered by whole packets)."""
    headers = []
    i, n = 0, len(payload)
    while n - i >= 3:
        size = payload[i + 2]
        if i + 3 + size > n:
            break
        headers.append((payload[i] << 8 | payload[i + 1], size))
        i += 3 + size
    return tuple(headers), i


def decode_mtdata2(payload: bytes) -> MTData2:
    """Decode an MTData2 payload; unknown identifiers are skipped by their size."""
    candidates = _LAYOUTS.get(len(payload))
    if candidates:
        for layout in candidates:
            vals = layout.struct.unpack(payload)
            if layout.matches(vals):
                return MTData2(layout.values(vals), layout.systems, layout.skipped)
    headers, covered = _headers_of(payload)
    layout = _Layout(headers)
    vals = layout.struct.unpack_from(payload)
    if covered == len(payload):
        if sum(len(v) for v in _LAYOUTS.values()) >= _MAX_LAYOUTS:
            _LAYOUTS.clear()  # a stream of changing layouts must not grow memory
        _LAYOUTS.setdefault(len(payload), []).append(layout)
    return MTData2(
        layout.values(vals), layout.systems, layout.skipped, truncated=covered != len(payload)
    )


def _pack_real(value: float, precision: int) -> bytes:
    if precision == FLOAT32:
        return struct.pack(">f", value)
    if precision == FLOAT64:
        return struct.pack(">d", value)
    if precision == FP1220:
        raw = max(-(2**31), min(2**31 - 1, round(value * 2**20)))
        return struct.pack(">i", raw)
    raw = max(-(2**47), min(2**47 - 1, round(value * 2**32)))  # 16.32 fixed point
    return struct.pack(">Ih", raw & 0xFFFFFFFF, raw >> 32)


def encode_packet(
    name: str, value: Any, precision: int = FLOAT32, coordinate_system: str = "ENU"
) -> bytes:
    """One MTData2 packet (XDI, size, data) for a named output."""
    base = XDI[name]
    _, kind, count = OUTPUTS[base]
    if kind != "real":
        code, _ = _INT_FORMATS[kind]
        data = struct.pack(">" + code, *(value if len(code) > 1 else (int(value),)))
        xdi = base
    else:
        if name == "rotation_matrix":  # rows in, column-major on the wire
            rows = [list(r) for r in value]
            values = [rows[r][c] for c in range(3) for r in range(3)]
        elif count == 1:
            values = [value]
        else:
            values = list(value)
        if len(values) != count:
            raise ValueError(f"{name}: expected {count} values, got {len(values)}")
        data = b"".join(_pack_real(float(v), precision) for v in values)
        xdi = base | precision
        if name in WORLD_FRAME_OUTPUTS:
            xdi |= _COORDINATE_CODES[coordinate_system]
    return struct.pack(">HB", xdi, len(data)) + data


def encode_mtdata2(
    values: dict[str, Any],
    precision: int = FLOAT32,
    coordinate_system: str = "ENU",
    precisions: dict[str, int] | None = None,
) -> bytes:
    """An MTData2 payload with the given outputs, in the given order."""
    precisions = precisions or {}
    return b"".join(
        encode_packet(name, v, precisions.get(name, precision), coordinate_system)
        for name, v in values.items()
    )


# --------------------------------------------------------------------------- configuration

# Frequency 0xFFFF in SetOutputConfiguration: for the timestamp group (0x10xx: UtcTime,
# packet counter, SampleTimeFine, ...) "no maximum frequency, sent along with appropriate
# packets", whatever rate is asked (0 too, as Xsens' example and ROS driver ask); the
# status word asked at 0 or 0xFFFF rides along the same way; any other output at 0xFFFF
# runs at "the highest rate the device has for it" (xsoutputconfiguration.h). walkcap
# sends 0xFFFF only for the timestamp group and an explicit rate for everything else.
EVERY_PACKET = 0xFFFF
TIMESTAMP_GROUP = 0x1000
STATUS_WORD = 0xE020


def rides_every_packet(xdi: int) -> bool:
    """Whether this identifier goes in every message at any rate (the timestamp group)."""
    return xdi & 0xFF00 == TIMESTAMP_GROUP


def rides_along(xdi: int, requested: int) -> bool:
    """Whether a device sends this output with every message when asked at `requested`:
    the timestamp group always, the status word at 0 or 0xFFFF."""
    if rides_every_packet(xdi):
        return True
    return xdi & 0xFFF0 == STATUS_WORD and requested in (0, EVERY_PACKET)


@dataclass(frozen=True)
class OutputSetting:
    xdi: int  # with precision and coordinate-system bits
    rate_hz: int  # EVERY_PACKET: asked, the maximum (timestamps: every message); reported,
    # "no maximum frequency, sent along with appropriate packets" (xsoutputconfiguration.h)

    @property
    def name(self) -> str:
        known = OUTPUTS.get(self.xdi & 0xFFF0)
        return known[0] if known else f"0x{self.xdi:04X}"

    def describe(self) -> dict[str, Any]:
        """As a device reports it (OutputConfiguration)."""
        if self.rate_hz == EVERY_PACKET:
            rate: Any = "every packet"
        else:
            rate = self.rate_hz
        d: dict[str, Any] = {"output": self.name, "xdi": f"0x{self.xdi:04X}", "rate_hz": rate}
        known = OUTPUTS.get(self.xdi & 0xFFF0)
        if known and known[1] == "real":
            d["precision"] = PRECISION_NAMES[self.xdi & 0x3]
            if known[0] in WORLD_FRAME_OUTPUTS:
                d["coordinate_system"] = COORDINATE_SYSTEMS.get(self.xdi & 0xC, "?")
        return d


def encode_output_configuration(settings: Iterable[OutputSetting]) -> bytes:
    return b"".join(struct.pack(">HH", s.xdi, s.rate_hz) for s in settings)


def decode_output_configuration(data: bytes) -> list[OutputSetting]:
    if len(data) % 4:
        raise ValueError(f"output configuration of {len(data)} bytes is not pairs of u16")
    return [OutputSetting(*struct.unpack_from(">HH", data, i)) for i in range(0, len(data), 4)]


DEFAULT_OUTPUTS = (
    "packet_counter",
    "sample_time_fine",
    "quaternion",
    "acceleration",
    "rate_of_turn",
    "status_word",
)


def xdi_of(name: str, precision: int = FLOAT32, coordinate_system: str = "ENU") -> int:
    """The identifier of a named output with its precision and coordinate-system bits."""
    if name not in XDI:
        raise ValueError(f"unknown IMU output {name!r} (known: {', '.join(sorted(XDI))})")
    xdi = XDI[name]
    if OUTPUTS[xdi][1] == "real":
        xdi |= precision
        if name in WORLD_FRAME_OUTPUTS:
            xdi |= _COORDINATE_CODES[coordinate_system]
    return xdi


def output_settings(
    names: Iterable[str], rate_hz: int, precision: int = FLOAT32, coordinate_system: str = "ENU"
) -> list[OutputSetting]:
    """SetOutputConfiguration entries: the timestamp group in every message, every other
    output (the status word too) at `rate_hz`. devices.imu_family fits them to a model."""
    settings = []
    for name in names:
        xdi = xdi_of(name, precision, coordinate_system)
        settings.append(OutputSetting(xdi, EVERY_PACKET if rides_every_packet(xdi) else rate_hz))
    return settings


def wire_time_ns(nbytes: int, baudrate: int) -> int:
    """Time to send nbytes over a UART at 8N1 (10 bits a byte)."""
    return nbytes * 10 * 1_000_000_000 // baudrate if baudrate > 0 else 0


# --------------------------------------------------------------------------- link budget

BITS_PER_BYTE = 10  # 8N1: a start bit, 8 data bits, a stop bit
LINK_MARGIN = 0.8  # use at most this share of the line: bursts and replies need room


@dataclass(frozen=True)
class LinkBudget:
    """What an output configuration costs on the serial line."""

    message_rate_hz: float  # MTData2 messages a second
    bytes_per_message: float  # on average, frame included
    bytes_per_s: float
    baudrate: int

    @property
    def bits_per_s(self) -> float:
        return self.bytes_per_s * BITS_PER_BYTE

    @property
    def load(self) -> float:
        """The share of the line's capacity used (1.0: full)."""
        return self.bits_per_s / self.baudrate if self.baudrate > 0 else float("inf")

    @property
    def fits(self) -> bool:
        return self.load <= LINK_MARGIN

    def describe(self) -> str:
        return (
            f"{self.message_rate_hz:g} messages/s x {self.bytes_per_message:.0f} bytes = "
            f"{self.bits_per_s / 1000:.1f} kbit/s of {self.baudrate / 1000:g} kbit/s "
            f"({self.load:.0%}, at most {LINK_MARGIN:.0%})"
        )


def link_budget(settings: Iterable[OutputSetting], baudrate: int) -> LinkBudget:
    """Bytes a second of an MTData2 stream: each output (3 header bytes + its data) at its
    rate, timestamp-group outputs in every message, 5 frame bytes (7 when extended) a
    message. Messages go out at the highest output rate (the rates divide it)."""
    settings = list(settings)
    rates = [s.rate_hz for s in settings if s.rate_hz != EVERY_PACKET and s.rate_hz > 0]
    message_rate = float(max(rates)) if rates else 0.0
    data_per_s = 0.0
    payload_max = 0
    for s in settings:
        size = value_size(s.xdi)
        if size is None or s.rate_hz == 0:
            continue
        rate = message_rate if s.rate_hz == EVERY_PACKET else float(s.rate_hz)
        data_per_s += (3 + size) * rate
        payload_max += 3 + size
    frame = 5 if payload_max < EXTENDED_LENGTH else 7
    per_s = data_per_s + frame * message_rate
    per_message = per_s / message_rate if message_rate else 0.0
    return LinkBudget(message_rate, per_message, per_s, int(baudrate))


def baud_that_fits(settings: Iterable[OutputSetting]) -> int | None:
    """The lowest standard baud rate that carries these outputs (None: none does)."""
    settings = list(settings)
    for baud in BAUDRATES:
        if baud >= 115200 and link_budget(settings, baud).fits:
            return baud
    return None
