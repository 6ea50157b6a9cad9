"""Both devices at a glance: state, rates, drops, errors, clock drift and sync error; the
latest fault. Every figure has its label and unit."""

from __future__ import annotations

from rich.console import Group
from rich.table import Table
from rich.text import Text
from textual.widget import Widget

from devices.base import DeviceEvent, DeviceState, DeviceStatus
from tui.widgets.modes import STATE_COLORS
from tui.widgets.pacing import Pacer

# Backends name their clock figures slightly differently; the first key present is shown.
_DRIFT_KEYS = ("clock_drift_ppm", "drift_ppm")
# What a device's error count is made of, in words.
_ERROR_PARTS = (
    ("checksum_errors", "bad checksums"),
    ("missing_packets", "missing packets"),
)
# Counts of their own, outside the error count: each on its own labelled row.
_OTHER_COUNTS = (
    ("reconnects", "reconnects", ""),
    ("renderer_skipped", "skipped", "frames not rendered"),
)
_NAMES = {"imu": "IMU", "camera": "camera"}
_UNITS = {"camera": ("fps", "frames"), "imu": ("Hz", "samples")}
_RED, _AMBER = STATE_COLORS[DeviceState.LOST], STATE_COLORS[DeviceState.DEGRADED]

Row = tuple[str, str, str]  # label, value, style of the value


def _first(details: dict, keys: tuple[str, ...]):
    for k in keys:
        if details.get(k) is not None:
            return details[k]
    return None


def device_rows(name: str, status: DeviceStatus | None, sync: dict | None = None) -> list[Row]:
    """The lines shown for one device, already formatted (so an unchanged view costs nothing)."""
    title = "IMU" if name == "imu" else name
    if status is None:
        return [(title, "not open", "dim")]
    unit, things = _UNITS.get(name, ("Hz", "items"))
    rows = [
        (title, f"{status.state}  {status.backend}", f"bold {STATE_COLORS.get(status.state, '')}")
    ]
    if (
        status.message and status.state != DeviceState.OK
    ):  # "streaming" says nothing the state does not
        rows.append(("", status.message, STATE_COLORS.get(status.state, "")))
    slow = status.configured_rate_hz and status.measured_rate_hz < 0.9 * status.configured_rate_hz
    rows.append(
        (
            "rate",
            f"{status.measured_rate_hz:.1f} of {status.configured_rate_hz:g} {unit}",
            _AMBER if slow and status.state == DeviceState.OK else "",
        )
    )
    # drops: lost on this side (walkcap fell behind); errors: faults of the device or link
    style = f"bold {_RED}" if status.dropped else (_AMBER if status.errors else "")
    rows.append(("drops", f"{status.dropped} {things}, errors {status.errors}", style))
    parts = [f"{what}: {status.details[k]}" for k, what in _ERROR_PARTS if status.details.get(k)]
    rows += [("", part, _AMBER) for part in parts]
    for key, label, unit in _OTHER_COUNTS:
        if status.details.get(key):
            rows.append((label, f"{status.details[key]} {unit}".strip(), _AMBER))
    drift = _first(status.details, _DRIFT_KEYS)
    if drift is not None:  # how fast the device clock runs against the host's
        rows.append(("drift", f"{float(drift):+.0f} ppm (clock)", ""))
    if sync:  # how far a sample's host time is from when it was taken
        rows.append(("sync", f"error p99 {sync.get('p99_ms', 0):.1f} ms", ""))
    return rows


def event_sentence(event: DeviceEvent) -> str:
    """A device event as one plain sentence: the device named once, the message's words."""
    name = _NAMES.get(event.device, event.device)
    text = " ".join(event.message.split())
    if text.lower().startswith(name.lower()):
        return text  # "IMU lost (...); retrying ...": it names the device and what happened
    return f"{name} {event.kind.replace('_', ' ')}: {text}"


def event_row(event: DeviceEvent) -> Row:
    style = f"bold {_RED}" if event.kind in ("lost", "error", "stall") else _AMBER
    return ("", event_sentence(event), style)


_PACED = ("rate", "drift", "sync", "frames", "latency")


def _significant(rows: list[Row]) -> list[Row]:
    return [r for r in rows if r[0] not in _PACED]


class DevicePanel(Widget):
    """Camera and IMU status; redrawn only when what it shows changes."""

    DEFAULT_CSS = """
    DevicePanel { height: 1fr; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._rows: list[Row] = []
        self._pacer = Pacer()

    def present(
        self,
        camera: DeviceStatus | None,
        imu: DeviceStatus | None,
        sync: dict,
        last_event: DeviceEvent | None,
        pipeline: list[Row] | None = None,
    ) -> None:
        rows = device_rows("camera", camera) + device_rows("imu", imu, sync)
        if last_event is not None:  # before the pipeline line: a small terminal cuts the end
            rows.append(event_row(last_event))
        rows += pipeline or []
        if rows == self._rows:
            return
        # states, messages, drops, errors and faults at once; rates and clocks when paced
        urgent = _significant(rows) != _significant(self._rows)
        if self._pacer.due(urgent):
            self._rows = rows
            self.refresh()  # fixed height: no relayout (it would redraw the whole screen)

    def render(self) -> Table:
        table = Table.grid(padding=(0, 1))
        table.add_column(style="dim", no_wrap=True, min_width=7)
        table.add_column(overflow="fold")  # a long message wraps, never cut mid-word
        for label, value, style in self._rows:
            is_name = label in ("camera", "IMU", "pipeline")
            table.add_row(Text(label, style="bold" if is_name else ""), Text(value, style=style))
        return Group(table)
