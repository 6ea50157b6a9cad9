"""What the IMU outputs: the request fitted to the family, the device's reply compared with
it, the link budget's refusal, and MTData2 values turned into `ImuSample`s.

Pure functions. Every output is asked for at an explicit rate the family has (0xFFFF only
for the packet counter and SampleTimeFine, which ride in every message); outputs the model
lacks are left out with a reason (an IMU-only model sends no orientation, so its samples
carry no quaternion and leveling needs a VRU or AHRS model); every rate the device granted
instead of the one asked is said; a stream that does not fit the baud rate is refused in
one line naming a rate or baud rate that fits. Quaternions are always sensor -> ENU world
(z up), whatever coordinate system the device reports in.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from devices import xbus
from devices.frames import ImuSample
from devices.imu.family import NEEDS_ORIENTATION, Family, describe_rates, divisor_rates
from devices.rotations import matrix_to_quat, quat_from_euler, quat_multiply, quat_normalize

# sensor -> ENU = (frame -> ENU) * (sensor -> frame)
_FRAME_TO_ENU = {
    name: matrix_to_quat(np.array(m, dtype=np.float64).T) for name, m in xbus.FRAME_FROM_ENU.items()
}
_VECTOR_OUTPUTS = ("acceleration", "rate_of_turn")
# Outputs that are no measurement: a message of only these carries no sample.
NOT_MEASUREMENTS = frozenset(
    {"packet_counter", "sample_time_fine", "sample_time_coarse", "utc_time", "status_word"}
)


# ---- the request and the reply ------------------------------------------------------------


def fit_to_family(
    settings: list[xbus.OutputSetting], family: Family, product_code: str
) -> tuple[list[xbus.OutputSetting], list[str]]:
    """(the request fitted to the family, what was changed): outputs it lacks left out,
    each rate one it has."""
    fitted, adjusted = [], []
    for s in settings:
        if not family.has(s.name):
            why = (
                "an IMU-only model has no orientation (leveling needs a VRU or AHRS)"
                if s.name in NEEDS_ORIENTATION and not family.has_orientation
                else f"the {family.name} has no such output"
            )
            adjusted.append(f"{s.name} left out: {why}")
            continue
        rate = family.fit(s.xdi, s.rate_hz)
        if rate != s.rate_hz:
            adjusted.append(
                f"{s.name} at {rate} Hz, not {s.rate_hz} Hz "
                f"({product_code}: {describe_rates(family, s.xdi)} Hz)"
            )
        fitted.append(xbus.OutputSetting(s.xdi, rate))
    return fitted, adjusted


def granted_differences(
    request: list[xbus.OutputSetting], reply: list[xbus.OutputSetting]
) -> list[str]:
    """Every difference between the request and what the device uses."""
    asked = {s.xdi: s.rate_hz for s in request}
    got = {s.xdi: s.rate_hz for s in reply}
    granted = []
    for xdi, rate in asked.items():
        name = xbus.OutputSetting(xdi, rate).name
        if xdi not in got:
            granted.append(f"{name}: asked for at {_rate_text(rate)}, not granted")
        elif got[xdi] != rate:
            granted.append(
                f"{name}: asked for {_rate_text(rate)}, the device uses {_rate_text(got[xdi])}"
            )
    for xdi, rate in got.items():
        if xdi not in asked:
            name = xbus.OutputSetting(xdi, rate).name
            granted.append(f"{name}: not asked for, the device adds it")
    return granted


def budget_refusal(
    settings: list[xbus.OutputSetting],
    budget: xbus.LinkBudget,
    baudrate: int,
    family: Family | None,
    port: str,
    product_code: str,
) -> str:
    """One line: what the stream needs, and a rate or baud rate that carries it."""
    fits = xbus.baud_that_fits(settings)
    hints = []
    if fits is not None:
        hints.append(
            f"set [imu] baudrate = {fits} (the device too: walkcap imu set-baud {port} {fits})"
        )
    rate = rate_that_fits(settings, baudrate, family)
    if rate:
        hints.append(f"or rate_hz = {rate}")
    return (
        f"IMU {product_code} on {port}: the output needs {budget.describe()}: "
        f"more than {baudrate} baud carries; " + " ".join(hints)
    )


def sampling_rate(settings: list[xbus.OutputSetting]) -> float:
    """The rate of the measurements (the status word and timestamps left aside)."""
    rates = [
        s.rate_hz
        for s in settings
        if s.rate_hz not in (0, xbus.EVERY_PACKET) and s.name not in NOT_MEASUREMENTS
    ]
    return float(max(rates)) if rates else 0.0


def rate_that_fits(
    settings: list[xbus.OutputSetting], baudrate: int, family: Family | None
) -> int | None:
    """The highest rate (one the family has) at which these outputs fit the baud rate."""
    top = int(sampling_rate(settings) or 0)
    if not top:
        return None
    candidates = family.rates(xbus.XDI["acceleration"]) if family else divisor_rates(top)
    for rate in candidates:
        if rate >= top:
            continue
        scaled = [
            xbus.OutputSetting(
                s.xdi, s.rate_hz if s.rate_hz == xbus.EVERY_PACKET else min(s.rate_hz, rate)
            )
            for s in settings
        ]
        if xbus.link_budget(scaled, baudrate).fits:
            return rate
    return None


def _rate_text(rate: int) -> str:
    return "every packet" if rate == xbus.EVERY_PACKET else f"{rate} Hz"


# ---- samples ------------------------------------------------------------------------------


def is_measurement(values: dict[str, Any]) -> bool:
    """False for a status-only message (the status word faster than the data)."""
    return not values.keys() <= NOT_MEASUREMENTS


def imu_sample(
    values: dict[str, Any], systems: dict[str, str], host_ns: int, time_ns: int
) -> ImuSample:
    """The sample of one MTData2 message's values, received at host_ns, taken at time_ns."""
    extra = {
        k: _plain(v)
        for k, v in values.items()
        if k
        not in ("packet_counter", "sample_time_fine", "quaternion", "status_word", *_VECTOR_OUTPUTS)
    }
    return ImuSample(
        host_time_ns=host_ns,
        time_ns=int(time_ns),
        packet_counter=values.get("packet_counter"),
        sample_time_fine=values.get("sample_time_fine"),
        quaternion=orientation(values, systems),
        acceleration=np.array(values["acceleration"]) if "acceleration" in values else None,
        rate_of_turn=np.array(values["rate_of_turn"]) if "rate_of_turn" in values else None,
        status_word=values.get("status_word"),
        extra=extra,
    )


def orientation(values: dict[str, Any], systems: dict[str, str]) -> np.ndarray | None:
    """Sensor -> ENU quaternion from whichever orientation output the device sent."""
    if "quaternion" in values:
        q, name = np.array(values["quaternion"], dtype=np.float64), "quaternion"
    elif "rotation_matrix" in values:
        q, name = matrix_to_quat(np.array(values["rotation_matrix"])), "rotation_matrix"
    elif "euler" in values:
        q, name = quat_from_euler(*np.radians(values["euler"])), "euler"
    else:
        return None
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm < 1e-6:
        return None
    system = systems.get(name, "ENU")
    if system != "ENU":
        q = quat_multiply(_FRAME_TO_ENU[system], q)
    return quat_normalize(q)


def _plain(value: Any) -> Any:
    """JSON-friendly: tuples to lists, recursively."""
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value
