"""Both devices at a glance: state, rates, drops, errors, clock drift and sync error; the
latest fault. Every figure has its label and unit."""

from __future__ import annotations

from rich.console import Group
from rich.table import Table
from rich.text import Text
from textual.widget import Widget

from devices.base import DeviceEvent, DeviceState, DeviceStatus
from devices.imu.clock import drift_text
from tui.widgets.modes import STATE_COLORS
from tui.widgets.pacing import Pacer

# Backends name their clock figures slightly differently; the first key present is shown.
_DRIFT_KEYS = ("clock_drift_ppm", "drift_ppm")
# What a device's error count is made of, in words (the parts add up to the count).
_ERROR_PARTS = (
    ("checksum_errors", "bad checksums"),
    ("missing_packets", "missing packets"),
    ("reconnects", "reconnects"),
    ("renderer_skipped", "frames not rendered"),
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
    drift = _first(status.details, _DRIFT_KEYS)
    if drift is not None:  # how fast the device clock runs against the host's, how surely
        if "drift_uncertainty_ppm" in status.details:
            text = drift_text(float(drift), status.details["drift_uncertainty_ppm"])
            rows.append(("drift", text.replace(" (under 2 s of samples)", ""), ""))
        else:
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


def label_width(rows: list[Row]) -> int:
    return max([7, *(len(label) for label, _, _ in rows)])


# What gives way when the panel is short, first to last: the pipeline, the sync error, the
# kinds of errors and other counts, the clock drift. States, reasons, rates, drops and
# errors, and the latest fault always stay.
_DETAIL = {"pipeline": 0, "frames": 0, "latency": 0, "sync": 1, "drift": 3}
_PART_PREFIXES = tuple(f"{what}:" for _, what in _ERROR_PARTS)


def _detail_rank(row: Row) -> int | None:
    label, value, _ = row
    if label in _DETAIL:
        return _DETAIL[label]
    if not label and value.startswith(_PART_PREFIXES):
        return 2
    return None


def fit_rows(rows: list[Row], width: int, height: int) -> tuple[list[Row], bool]:
    """The rows that fit `height` lines of `width` cells, and whether values may wrap.

    Everything, wrapped, when it fits; else one line each, detail rows dropped in
    _DETAIL order until the rest fits."""
    value_width = max(1, width - label_width(rows) - 1)
    lines = sum(
        max(1, -(-len(part) // value_width)) for _, value, _ in rows for part in value.split("\n")
    )
    if height <= 0 or lines <= height:
        return rows, True
    kept = list(rows)
    for rank in range(4):
        if len(kept) <= height:
            break
        kept = [r for r in kept if _detail_rank(r) != rank]
    return kept, False


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
        status = {"camera": camera, "imu": imu}.get(last_event.device) if last_event else None
        said = status is not None and last_event.kind == status.state
        if last_event is not None and not said:  # a lost device's state says it already
            rows.append(event_row(last_event))
        rows += pipeline or []
        if rows == self._rows:
            return
        # states, messages, drops, errors and faults at once; rates and clocks when paced
        urgent = _significant(rows) != _significant(self._rows)
        if self._pacer.due(urgent):
            self._rows = rows
            self.refresh()  # fixed height: no relayout (it would redraw the whole screen)

    def on_resize(self) -> None:
        self.refresh()  # what fits depends on the size

    def render(self) -> Table:
        rows, fold = fit_rows(self._rows, self.size.width, self.size.height)
        table = Table.grid(padding=(0, 1))
        table.add_column(style="dim", no_wrap=True, min_width=label_width(rows))
        table.add_column(overflow="fold")  # a long message wraps when there is room
        for label, value, style in rows:
            is_name = label in ("camera", "IMU", "pipeline")
            # else it ends in "…" (the notice line and tui.log have it whole)
            shown = Text(
                value, style=style, no_wrap=not fold, overflow=None if fold else "ellipsis"
            )
            table.add_row(Text(label, style="bold" if is_name else ""), shown)
        return Group(table)
