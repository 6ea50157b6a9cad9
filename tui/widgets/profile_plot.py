"""The leveled sagittal profile: height against distance ahead, equal scales, in braille."""
from __future__ import annotations

import numpy as np
from rich.text import Text
from textual.widget import Widget

from tui.widgets.raster import plot_points

FORWARD_M = (0.0, 1.5)  # what the corridor keeps by default (preprocess.max_forward_m)


def profile_ranges(points: np.ndarray, cols: int, rows: int,
                   forward_m: tuple[float, float] = FORWARD_M) -> tuple[tuple[float, float], tuple[float, float]]:
    """Axis ranges with equal metres per dot on both axes, the profile centred in height."""
    x0, x1 = forward_m
    m_per_dot = (x1 - x0) / max(1, cols * 2)
    span = m_per_dot * rows * 4
    finite = points[np.all(np.isfinite(points), axis=1)] if len(points) else points
    mid = float(np.median(finite[:, 1])) if len(finite) else 0.0
    if len(finite):  # keep the highest and lowest points in view when they fit
        lo, hi = float(finite[:, 1].min()), float(finite[:, 1].max())
        if hi - lo <= span:
            mid = (lo + hi) / 2
    return (x0, x1), (mid - span / 2, mid + span / 2)


class ProfilePlot(Widget):
    DEFAULT_CSS = """
    ProfilePlot { color: $accent; }
    """

    def __init__(self, forward_m: tuple[float, float] = FORWARD_M, **kwargs) -> None:
        super().__init__(**kwargs)
        self.forward_m = forward_m
        self._points: np.ndarray | None = None
        self._key: object = None

    def present(self, profile: np.ndarray | None, key: object = None) -> None:
        if key is not None and key == self._key:
            return
        self._key = key
        self._points = None if profile is None else np.asarray(profile, dtype=np.float64).reshape(-1, 2)
        self.refresh()

    def render(self) -> Text:
        if self._points is None:
            return Text("no profile yet", style="dim")
        cols, rows = self.size.width, self.size.height - 1
        if cols < 4 or rows < 2:
            return Text("")
        xr, yr = profile_ranges(self._points, cols, rows, self.forward_m)
        text = Text("\n".join(plot_points(self._points, cols, rows, xr, yr)))
        right = f"{xr[1]:.1f} m ahead"
        text.append("\n" + f"0 m{' ' * max(1, cols - 3 - len(right))}{right}"[:cols], style="dim")
        return text
