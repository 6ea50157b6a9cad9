"""Xsens MTi families: which outputs a model has, at which rates, and how slowly it writes.

Pure data and functions, shared by the driver (devices/imu/driver.py) and the emulator
(devices/imu/emulator/). Facts from Xsens' public device SDK (the `xspublic` sources):
a family is known from the product code ("MTi-3-8A7G6", "MTi-630-...", "MTi-G-710-...",
xsdeviceid.c); each data group has a base rate, and a device outputs a group at the base
rate divided by a whole number (mtibasedevice.cpp, supportedUpdateRates; the base rates
per family are each device class's getBaseFrequencyInternal). The timestamp group
(UtcTime, packet counter, SampleTimeFine) rides along with every message instead, and so
does the status word asked at 0 or 0xFFFF (as Xsens' example and ROS driver ask for it).
Families as xspublic's device classes: MtiXDevice (1-series), Mti3X0Device (MTi-310/320/
330), MtiX0Device, MtiX00Device, MtigDevice, Mti6X0Device.

The function digit of the product code: 1 = IMU (inertial data only, no orientation),
2 = VRU, 3 = AHRS; 7 (and MTi-G, 670, 680, 8) = GNSS/INS. walkcap levels point clouds with
the device's own orientation: an IMU-only model streams acceleration and rate of turn,
the samples carry no quaternion, and leveling needs a VRU or AHRS model (walkcap does not
run an attitude filter of its own on the host).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from devices import xbus

# Data groups by the identifier's high byte (xdi & 0xFF00).
TEMPERATURE, TIMESTAMP, ORIENTATION, PRESSURE = 0x0800, 0x1000, 0x2000, 0x3000
ACCELERATION, ANGULAR_VELOCITY, MAGNETIC, STATUS = 0x4000, 0x8000, 0xC000, 0xE000
GROUP_NAMES = {
    TEMPERATURE: "temperature",
    TIMESTAMP: "timestamp",
    ORIENTATION: "orientation",
    PRESSURE: "pressure",
    ACCELERATION: "acceleration",
    ANGULAR_VELOCITY: "angular velocity",
    MAGNETIC: "magnetic",
    STATUS: "status",
}
# Outputs that need the device's attitude filter (none on an IMU-only model).
NEEDS_ORIENTATION = frozenset({"quaternion", "rotation_matrix", "euler", "free_acceleration"})


def divisor_rates(base: int) -> tuple[int, ...]:
    """The rates a group with this base runs at: base / n where n divides base, highest
    first (the 2024 SDK keeps 500/250/125 Hz on a 2000 Hz base; the 2019 one drops them)."""
    return tuple(base // n for n in range(1, base + 1) if base % n == 0)


@dataclass(frozen=True)
class Family:
    name: str  # "MTi-1 series", "MTi-600 series", ...
    bases: dict[int, int]  # group -> base rate in Hz; a group missing: not on this model
    # A settings write (SetOutputConfiguration, SetBaudrate) can take this long: the SDK
    # allows about 900 ms on the 1-series ("a settings write can occasionally take ~900ms").
    settings_write_s: float = 0.1
    function: str = "AHRS"  # IMU | VRU | AHRS | GNSS/INS
    # The emulator's usual time for a settings write (a real one varies, up to the above).
    typical_write_s: float = 0.02
    models: tuple[str, ...] = field(default=())

    @property
    def has_orientation(self) -> bool:
        return self.function != "IMU"

    def base(self, xdi: int) -> int:
        """The group's base rate; 0: this model does not have the output."""
        name = xbus.OUTPUTS.get(xdi & 0xFFF0, ("",))[0]
        if not self.has_orientation and (xdi & 0xFF00 == ORIENTATION or name in NEEDS_ORIENTATION):
            return 0
        return self.bases.get(xdi & 0xFF00, 0)

    def has(self, name: str) -> bool:
        if name in NEEDS_ORIENTATION and not self.has_orientation:
            return False
        return self.base(xbus.XDI[name]) > 0

    def rates(self, xdi: int) -> tuple[int, ...]:
        base = self.base(xdi)
        return divisor_rates(base) if base else ()

    def fit(self, xdi: int, requested: int) -> int:
        """The rate this family outputs when asked for `requested`: the highest supported
        rate not above it (the slowest one below that); 0xFFFF: the group's maximum; 0:
        not output. The timestamp group at any rate, and the status word at 0 or 0xFFFF,
        go with every message (0xFFFF)."""
        if xbus.rides_along(xdi, requested):
            return xbus.EVERY_PACKET if self.base(xdi) else 0
        rates = self.rates(xdi)
        if not rates or requested == 0:
            return 0
        if requested == xbus.EVERY_PACKET:
            return rates[0]
        return next((r for r in rates if r <= requested), rates[-1])

    def max_rate(self) -> int:
        """The highest rate of the main outputs (acceleration, rate of turn)."""
        return max(self.bases.get(g, 0) for g in (ACCELERATION, ANGULAR_VELOCITY))


_ONE_SERIES = {g: 100 for g in (TEMPERATURE, ORIENTATION, ACCELERATION, ANGULAR_VELOCITY)}
_ONE_SERIES.update({MAGNETIC: 100, STATUS: 100, TIMESTAMP: xbus.EVERY_PACKET})
_MTI_10 = {g: 400 for g in (TEMPERATURE, ORIENTATION, ACCELERATION, ANGULAR_VELOCITY)}
_MTI_10.update({MAGNETIC: 100, STATUS: 2000, TIMESTAMP: xbus.EVERY_PACKET})
_MTI_600 = {g: 400 for g in (TEMPERATURE, ORIENTATION, ACCELERATION, ANGULAR_VELOCITY)}
_MTI_600.update({MAGNETIC: 100, PRESSURE: 100, STATUS: 400, TIMESTAMP: xbus.EVERY_PACKET})

ONE_SERIES = Family("MTi-1 series", _ONE_SERIES, 0.9, typical_write_s=0.15)
# MTi-310/320/330 (xspublic's Mti3X0Device, mti3x0device.cpp): the 1-series' 100 Hz bases
# (pressure only on GNSS models) and its slow settings writes (a 2 s default timeout).
MTI_3X0 = Family("MTi-3X0 series", dict(_ONE_SERIES), 0.9, typical_write_s=0.15)
ONE_SERIES_GNSS = Family(
    "MTi-1 series", {**_ONE_SERIES, PRESSURE: 50}, 0.9, "GNSS/INS", typical_write_s=0.15
)
MTI_10 = Family("MTi-10 series", _MTI_10)
MTI_100 = Family("MTi-100 series", {**_MTI_10, PRESSURE: 50})
MTI_G = Family("MTi-G-700 series", {**_MTI_10, PRESSURE: 50}, function="GNSS/INS")
MTI_600 = Family("MTi-600 series", _MTI_600)

_FUNCTIONS = {"1": "IMU", "2": "VRU", "3": "AHRS", "7": "GNSS/INS", "8": "GNSS/INS"}


def family_of(product_code: str) -> Family | None:
    """The family and function of a product code ("MTi-3-8A7G6" -> MTi-1 series, AHRS);
    None for a code this driver does not know."""
    code = product_code.strip("\x00 ").split(" ")[0].upper()
    m = re.match(r"MTI-(G-)?(\d+)", code)
    if not m:
        return None
    n = int(m.group(2))
    digits = m.group(2)
    if m.group(1):  # MTi-G-700 / 710
        return MTI_G if n >= 100 else None
    if 1 <= n <= 9:
        family = ONE_SERIES_GNSS if n in (7, 8) else ONE_SERIES
        function = _FUNCTIONS.get(digits[0], "AHRS")
    elif 10 <= n <= 99:
        family, function = MTI_10, _FUNCTIONS.get(digits[0], "AHRS")
    elif 100 <= n <= 300:  # xsdeviceid.c, XsDeviceId_isMtiX00: 100..300
        family, function = MTI_100, _FUNCTIONS.get(digits[0], "AHRS")
    elif 300 < n < 400:  # the function is the second digit: 310 IMU, 320 VRU, 330 AHRS
        family, function = MTI_3X0, _FUNCTIONS.get(digits[1], "AHRS")
    elif 600 <= n < 700:  # the function is the second digit: 610 IMU, 620 VRU, 630 AHRS
        family, function = MTI_600, _FUNCTIONS.get(digits[1], "AHRS")
        if n >= 670:
            function = "GNSS/INS"
    else:
        return None
    if function == family.function:
        return family
    return Family(
        family.name, family.bases, family.settings_write_s, function, family.typical_write_s
    )


# The models `[imu] emulate` plays: name -> (product code, legacy device id or a new-style
# id). A legacy id carries the type (xsdid.h: 0x0080_0000 1-series, 0x0060_0000 10-series,
# 0x0070_0000 100-series, 0x00D0_0000 3X0) and the function (0x0100_0000 IMU, 0x0200_0000
# VRU, 0x0300_0000 AHRS); new-style ids (the 600 series) set bit 31 (XS_DID64_BIT) and the
# library reads the type from the product code.
EMULATED_MODELS = {
    "MTi-1": ("MTi-1-8A7G6", 0x01881234),
    "MTi-2": ("MTi-2-8A7G6", 0x02881234),
    "MTi-3": ("MTi-3-8A7G6", 0x03881234),
    "MTi-7": ("MTi-7-8A7G6", 0x07881234),
    "MTi-10": ("MTi-10-2A8G4", 0x01601234),
    "MTi-20": ("MTi-20-2A8G4", 0x02601234),
    "MTi-30": ("MTi-30-2A8G4", 0x03601234),
    "MTi-100": ("MTi-100-2A8G4", 0x01701234),
    "MTi-200": ("MTi-200-2A8G4", 0x02701234),
    "MTi-300": ("MTi-300-2A8G4", 0x03701234),
    "MTi-310": ("MTi-310", 0x01D01234),
    "MTi-320": ("MTi-320", 0x02D01234),
    "MTi-330": ("MTi-330", 0x03D01234),
    "MTi-610": ("MTi-610", 0x80001234),
    "MTi-620": ("MTi-620", 0x80001235),
    "MTi-630": ("MTi-630", 0x80001236),
}


def emulated_model(name: str) -> tuple[str, int, Family]:
    """(product code, device id, family) of a model `[imu] emulate` names."""
    if name not in EMULATED_MODELS:
        raise ValueError(
            f"[imu] emulate = {name!r} is not a model the emulator plays "
            f"(known: {', '.join(EMULATED_MODELS)})"
        )
    code, device_id = EMULATED_MODELS[name]
    family = family_of(code)
    assert family is not None
    return code, device_id, family


def describe_rates(family: Family, xdi: int) -> str:
    rates = family.rates(xdi)
    return ", ".join(str(r) for r in rates) if rates else "none"
