"""Terrain features of the current profile (slope, riser height, tread depth, ...)."""
from __future__ import annotations

from rich.table import Table
from rich.text import Text
from textual.widget import Widget

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
    if kind:
        head = f"{kind} {features.get('direction') or ''}".strip()
        if features.get("steps"):
            head += f", {features['steps']} steps"
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
    FeaturesPanel { height: auto; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._rows: list[tuple[str, str]] = []

    def present(self, features: dict | None) -> None:
        rows = feature_rows(features or {})
        if rows != self._rows:
            self._rows = rows
            self.refresh(layout=True)

    def render(self) -> Table | Text:
        if not self._rows:
            return Text("no terrain features", style="dim")
        table = Table.grid(padding=(0, 1))
        table.add_column(style="dim", no_wrap=True)
        table.add_column(no_wrap=True)
        for name, value in self._rows:
            table.add_row(name, value)
        return table
