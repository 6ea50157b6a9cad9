"""MTData2: the measurement payload, decoded and encoded.

    MTData2: a sequence of  XDI (u16) | size (u8) | data (size bytes)

Decoded values use walkcap's names (`quaternion` [w, x, y, z], `euler` [roll, pitch, yaw]
degrees, `rotation_matrix` as three rows, ...). Vectors are tuples of floats, counters and
bit fields ints. Devices send the same layout in every message: each layout is compiled
once into one struct.
"""

from __future__ import annotations

import operator
import struct
from dataclasses import dataclass, field
from typing import Any

FLOAT32, FP1220, FP1632, FLOAT64 = 0, 1, 2, 3
PRECISION_NAMES = {FLOAT32: "float32", FP1220: "fp1220", FP1632: "fp1632", FLOAT64: "float64"}
ENU, NED, NWU = 0x0, 0x4, 0x8
COORDINATE_SYSTEMS = {ENU: "ENU", NED: "NED", NWU: "NWU"}
COORDINATE_CODES = {v: k for k, v in COORDINATE_SYSTEMS.items()}
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


@dataclass(slots=True)
class MTData2:
    """One decoded MTData2 payload."""

    values: dict[str, Any]  # output name -> value (see OUTPUTS)
    # Output name -> "ENU" | "NED" | "NWU" for orientation and free acceleration outputs.
    # Shared between messages of the same layout: read it, do not modify it.
    coordinate_systems: dict[str, str] = field(default_factory=dict)
    skipped: tuple[int, ...] = ()  # XDIs skipped: unknown, unexpected size or a repeat
    truncated: bool = False  # a packet ran past the end of the payload


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
            xdi |= COORDINATE_CODES[coordinate_system]
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
