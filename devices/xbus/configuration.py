"""Output configuration: which outputs at which rates, and what they cost on the line.

SetOutputConfiguration entries, the identifiers' precision and coordinate-system bits,
the outputs that ride along with every message, and the link budget: the bytes a second
of a stream against what a baud rate carries.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from devices.xbus.frames import BAUDRATES, EXTENDED_LENGTH
from devices.xbus.mtdata2 import (
    COORDINATE_CODES,
    COORDINATE_SYSTEMS,
    FLOAT32,
    OUTPUTS,
    PRECISION_NAMES,
    WORLD_FRAME_OUTPUTS,
    XDI,
    value_size,
)

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
            xdi |= COORDINATE_CODES[coordinate_system]
    return xdi


def output_settings(
    names: Iterable[str], rate_hz: int, precision: int = FLOAT32, coordinate_system: str = "ENU"
) -> list[OutputSetting]:
    """SetOutputConfiguration entries: the timestamp group in every message, every other
    output (the status word too) at `rate_hz`. devices.imu.family fits them to a model."""
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
