"""Terrain features of the current profile (slope, riser height, tread depth, ...)."""

from __future__ import annotations

from rich.text import Text
from textual.widget import Widget

from tui.widgets.pacing import IMAGE_HZ, Pacer

# How each known feature reads; unknown ones are shown by name with their raw value.
_FORMATS = {
    "slope_deg": ("slope", "{:+.1f}°"),
    "riser_m": ("riser", "{:.3f} m"),
    "tread_m": ("tread", "{:.3f} m"),
    "inlier_fraction": ("fit", "{:.0%}"),
    "residual_m": ("rms", "{:.3f} m"),
}
_HEADLINE = ("kind", "direction", "steps")


def feature_rows(features: dict) -> list[tuple[str, str]]:
    """(name, value) lines: what the terrain is first ("stairs up, 3 steps"), then numbers."""
    rows = []
    kind = features.get("kind")
    if kind:  # what the profile's geometry looks like, not the decision (that is the HMM's)
        head = f"fits {kind} {features.get('direction') or ''}".strip()
        steps = features.get("steps")
        if steps:
            head += f", {steps} step{'s' if steps != 1 else ''}"
        rows.append(("", head))
    for key, value in features.items():
        if value is None or key in _HEADLINE:
            continue
        name, fmt = _FORMATS.get(key, (key.replace("_", " "), "{}"))
        if isinstance(value, float) and fmt == "{}":
            fmt = "{:.3g}"
        try:
            rows.append((name, fmt.format(value)))
        except (ValueError, TypeError):
            rows.append((name, str(value)))
    return rows


class FeaturesPanel(Widget):
    DEFAULT_CSS = """
    FeaturesPanel { height: 1fr; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._rows: list[tuple[str, str]] = []
        self._pacer = Pacer(IMAGE_HZ)

    def present(self, features: dict | None) -> None:
        rows = feature_rows(features or {})
        if rows == self._rows:
            return
        kind_changed = rows[:1] != self._rows[:1]  # what the terrain is: at once
        if self._pacer.due(kind_changed):
            self._rows = rows
            self.refresh()  # fixed height: no relayout (it would redraw the whole screen)

    def render(self) -> Text:
        if not self._rows:
            return Text("no terrain features", style="dim")
        width = max(len(name) for name, _ in self._rows)
        text = Text(no_wrap=True, overflow="ellipsis")
        for i, (name, value) in enumerate(self._rows):
            if name:  # the headline ("fits stairs up, 3 steps") starts at the edge
                text.append(f"{name:<{width}} ", style="dim")
            text.append(value + ("\n" if i < len(self._rows) - 1 else ""))
        return text
