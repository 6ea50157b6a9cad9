"""The leveled sagittal profile: height against distance ahead, equal scales, in braille."""

from __future__ import annotations

import numpy as np
from rich.style import Style

from tui.widgets.lines import FrameLines, Line
from tui.widgets.raster import plot_points

_DIM = Style(dim=True)

FORWARD_M = (0.0, 1.5)  # what the corridor keeps by default (preprocess.max_forward_m)


def profile_ranges(
    points: np.ndarray, cols: int, rows: int, forward_m: tuple[float, float] = FORWARD_M
) -> tuple[tuple[float, float], tuple[float, float]]:
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


class ProfilePlot(FrameLines):
    DEFAULT_CSS = """
    ProfilePlot { color: $accent; }
    """

    def __init__(self, forward_m: tuple[float, float] = FORWARD_M, **kwargs) -> None:
        super().__init__(**kwargs)
        self.forward_m = forward_m
        self._points: np.ndarray | None = None

    def present(self, profile: np.ndarray | None, key: object = None) -> None:
        """`key` identifies the frame (FrameLines)."""
        if self._admit(key):
            self._points = (
                None if profile is None else np.asarray(profile, dtype=np.float64).reshape(-1, 2)
            )
            self.invalidate()

    def build_lines(self, width: int, height: int) -> list[Line]:
        if self._points is None:
            return [[("no profile yet", _DIM)]]
        rows = height - 1
        if width < 4 or rows < 2:
            return []
        xr, yr = profile_ranges(self._points, width, rows, self.forward_m)
        out: list[Line] = [
            [(line, None)] for line in plot_points(self._points, width, rows, xr, yr)
        ]
        right = f"{xr[1]:.1f} m ahead"
        out.append([(f"0 m{' ' * max(1, width - 3 - len(right))}{right}"[:width], _DIM)])
        return out
