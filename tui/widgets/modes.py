"""Colours for the five modes and the device states, defined once for every widget."""

from __future__ import annotations

from rich.text import Text

from devices.base import DeviceState
from devices.frames import MODE_COLORS, MODES

# MODE_COLORS: devices.frames', the same on every panel and in every figure
NO_MODE_COLOR = "#555555"

STATE_COLORS = {
    DeviceState.OK: "#4caf50",
    DeviceState.DEGRADED: "#f0a020",
    DeviceState.LOST: "#e04040",
    DeviceState.STOPPED: "#888888",
}


def mode_name(mode: str | int | None) -> str | None:
    """A mode as its two letters, from a letter code or an index into MODES."""
    if mode is None or mode == "":
        return None
    if isinstance(mode, int):
        return MODES[mode] if 0 <= mode < len(MODES) else None
    return mode if mode in MODES else None


def mode_color(mode: str | int | None) -> str:
    name = mode_name(mode)
    return MODE_COLORS[name] if name else NO_MODE_COLOR


def mode_text(mode: str | int | None, *, bold: bool = True) -> Text:
    """The two letters on the mode's colour, or a dash when there is none."""
    name = mode_name(mode)
    if name is None:
        return Text("--", style="dim")
    return Text(name, style=f"{'bold ' if bold else ''}#000000 on {MODE_COLORS[name]}")
