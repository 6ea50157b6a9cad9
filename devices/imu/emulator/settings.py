"""What an emulated MTi keeps and tells about itself: identity, stored settings, outputs.

`DeviceSettings` answers the read-outs and settings writes a device of the family answers
on open and configuration, so that Xsens' own host library (xspublic) opens it: DeviceID,
a 20-character ProductCode, HardwareVersion, FirmwareRev, ReqConfiguration in the vendor's
layout, option flags, location id, filter profiles, alignment rotation, string output
type, and the output configuration, granted by the family's rules (devices/imu/family.py):
each output at a rate the family has (the ack carries the rates it uses, as a device's
does; timestamps, UtcTime among them, and the status word asked at 0 or 0xFFFF go with
every message, reported as 0xFFFF), Error 0x21 (invalid parameter) for an output the model
lacks (an IMU-only model has no orientation). How a firmware rounds an unsupported rate is
not documented publicly: the emulator grants the highest supported rate not above the
request. The values are typical ones, not any unit's.
"""

from __future__ import annotations

import dataclasses
import struct

from devices import xbus
from devices.imu.family import Family
from devices.xbus import MID

INVALID_FILTER_PROFILE = 0x31


@dataclasses.dataclass(frozen=True)
class Answer:
    """A reply to send: `slow` after a settings write (to flash), which takes its time."""

    mid: int
    data: bytes = b""
    slow: bool = False


def error(code: int) -> Answer:
    return Answer(MID.ERROR, bytes([code]))


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


def _numbered(first: int, labels: tuple[str, ...]) -> tuple[FilterProfile, ...]:
    """A family's filter profiles, numbered on from `first` in the order it lists them."""
    return tuple(FilterProfile(first + i, 1, label) for i, label in enumerate(labels))


_ONE_SERIES_PROFILES = _numbered(
    50, ("general", "high_mag_dep", "dynamic", "north_reference", "vru_general")
)
_MK4_PROFILES = _numbered(39, ("general", "high_mag_dep", "dynamic", "low_mag_dep", "vru_general"))
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


class DeviceSettings:
    """The identity and the stored settings of one emulated device, and its answers."""

    # Read-outs and settings beyond the outputs (see `answer`).
    REQUESTS = frozenset(
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

    def __init__(
        self,
        family: Family,
        rate_hz: int,
        device_id: int,
        device_id_size: int,
        product_code: str,
        firmware: tuple[int, int, int],
    ) -> None:
        self.family = family
        self.rate_hz = rate_hz  # the stored power-up rate
        self.device_id = device_id
        self.device_id_size = device_id_size  # 8: the id as a 64-bit value (xspublic reads both)
        self.product_code = product_code
        self.firmware = firmware
        facts = _DEVICE_FACTS.get(family.name, _DEVICE_FACTS["MTi-1 series"])
        self.hardware_version = facts.hardware_version
        self.filter_profiles = _profiles_of(facts, family.function)
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
        # Stored settings at power-up: the default outputs this model has, at rate_hz.
        self.outputs = [
            s for s in xbus.output_settings(xbus.DEFAULT_OUTPUTS, rate_hz) if family.has(s.name)
        ]
        self.last_output_request: list[xbus.OutputSetting] = []  # as the host sent it

    def device_id_bytes(self) -> bytes:
        return self.device_id.to_bytes(self.device_id_size, "big")

    def product_code_bytes(self) -> bytes:
        """20 characters padded with spaces, as a device sends it (the library copies 20)."""
        return self.product_code.encode("ascii")[:20].ljust(20, b" ")

    def firmware_bytes(self) -> bytes:
        major, minor, rev = self.firmware
        return struct.pack(">BBBII", major, minor, rev, 42, 7031)

    def configuration(self) -> bytes:
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
            master[32:52] = self.product_code_bytes()
        device = bytearray(20)
        if legacy:
            struct.pack_into(">I", device, 0, self.device_id)
        else:
            struct.pack_into(">II", device, 0, self.device_id & 0xFFFFFFFF, self.device_id >> 32)
        profile = self.filter_profile if isinstance(self.filter_profile, int) else 0
        struct.pack_into(">HBBBcBB", device, 12, profile, major, minor, rev, b"\x00", 0, 0)
        return bytes(master) + struct.pack(">H", 1) + bytes(device)

    def answer(self, mid: int, data: bytes) -> Answer:
        """Read-outs and settings a device of the family answers on open and configuration."""
        if mid == MID.REQ_CONFIGURATION and not data:
            return Answer(MID.CONFIGURATION, self.configuration())
        if mid == MID.REQ_HARDWARE_VERSION and not data:
            return Answer(MID.HARDWARE_VERSION, struct.pack(">H", self.hardware_version))
        if mid == MID.REQ_OPTION_FLAGS and not data:
            return Answer(MID.REQ_OPTION_FLAGS_ACK, struct.pack(">I", self.option_flags))
        if mid == MID.REQ_OPTION_FLAGS and len(data) == 8:  # flags to set, flags to clear
            set_, clear = struct.unpack(">II", data)
            self.option_flags = (self.option_flags | set_) & ~clear & 0xFFFFFFFF
            return Answer(MID.REQ_OPTION_FLAGS_ACK, slow=True)
        if mid == MID.REQ_LOCATION_ID and not data:
            return Answer(MID.REQ_LOCATION_ID_ACK, struct.pack(">H", self.location_id))
        if mid == MID.REQ_LOCATION_ID and len(data) == 2:
            self.location_id = struct.unpack(">H", data)[0]
            return Answer(MID.REQ_LOCATION_ID_ACK, slow=True)
        if mid == MID.REQ_AVAILABLE_FILTER_PROFILES and not data:
            listing = b"".join(
                bytes((p.kind, p.version)) + p.label.encode("ascii").ljust(20, b" ")
                for p in self.filter_profiles
            )
            return Answer(MID.AVAILABLE_FILTER_PROFILES, listing)
        if mid == MID.REQ_FILTER_PROFILE and not data:
            current = self.filter_profile
            return Answer(
                MID.REQ_FILTER_PROFILE_ACK,
                current.encode("ascii") if isinstance(current, str) else struct.pack(">H", current),
            )
        if mid == MID.REQ_FILTER_PROFILE:
            return self._set_filter_profile(data)
        if mid == MID.REQ_ALIGNMENT_ROTATION and len(data) == 1 and data[0] in self.alignment:
            q = self.alignment[data[0]]
            return Answer(MID.REQ_ALIGNMENT_ROTATION_ACK, data + struct.pack(">4f", *q))
        if mid == MID.REQ_ALIGNMENT_ROTATION and len(data) == 17 and data[0] in self.alignment:
            self.alignment[data[0]] = struct.unpack(">4f", data[1:])
            return Answer(MID.REQ_ALIGNMENT_ROTATION_ACK, slow=True)
        if mid == MID.REQ_ALIGNMENT_ROTATION and len(data) in (1, 17):
            return error(xbus.INVALID_PARAMETER)  # no such frame
        if mid == MID.REQ_STRING_OUTPUT_TYPE and not data:
            return Answer(
                MID.REQ_STRING_OUTPUT_TYPE_ACK, struct.pack(">H", self.string_output_type)
            )
        if mid == MID.REQ_STRING_OUTPUT_TYPE and len(data) == 2:
            self.string_output_type = struct.unpack(">H", data)[0]
            return Answer(MID.REQ_STRING_OUTPUT_TYPE_ACK, slow=True)
        return error(xbus.INVALID_MESSAGE)

    def _set_filter_profile(self, data: bytes) -> Answer:
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
            return error(INVALID_FILTER_PROFILE)
        self.filter_profile = value
        return Answer(MID.REQ_FILTER_PROFILE_ACK, slow=True)

    def output_configuration(self, data: bytes) -> Answer:
        """ReqOutputConfiguration (no data), or SetOutputConfiguration granted by the
        family's rules."""
        if not data:
            return Answer(MID.OUTPUT_CONFIGURATION, xbus.encode_output_configuration(self.outputs))
        try:
            settings = xbus.decode_output_configuration(data)
        except ValueError:
            return error(xbus.INVALID_MESSAGE)
        self.last_output_request = settings  # as the host sent it (tests look at it)
        granted = []
        for s in settings:
            known = xbus.OUTPUTS.get(s.xdi & 0xFFF0)
            if known is None or (s.xdi & 0xC) not in xbus.COORDINATE_SYSTEMS:
                return error(xbus.INVALID_PARAMETER)
            if not self.family.has(known[0]):  # e.g. a quaternion from an IMU-only model
                return error(xbus.INVALID_PARAMETER)
            # The timestamp group (any rate) and the status word at 0 or 0xFFFF: with every
            # message (0xFFFF); another output at 0xFFFF: its maximum; at 0: not output.
            rate = self.family.fit(s.xdi, s.rate_hz)
            granted.append(xbus.OutputSetting(s.xdi, rate))
        self.outputs = granted
        return Answer(
            MID.OUTPUT_CONFIGURATION, xbus.encode_output_configuration(granted), slow=True
        )
