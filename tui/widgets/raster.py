"""Binary rasters as terminal text: half-blocks (2 pixels a cell) or braille (8 a cell).

Pure functions on numpy arrays, so the image and the profile widgets share them and the
tests check them without a terminal.
"""

from __future__ import annotations

import math

import numpy as np

_BRAILLE_BASE = 0x2800
# Dot bit for (row, column) inside a 4 x 2 braille cell.
_BRAILLE_BITS = np.array([[0x01, 0x08], [0x02, 0x10], [0x04, 0x20], [0x40, 0x80]], dtype=np.int64)
_HALF = {(0, 0): " ", (1, 0): "▀", (0, 1): "▄", (1, 1): "█"}


def pool_any(image: np.ndarray, factor: int) -> np.ndarray:
    """Shrink by an integer factor; a cell is set when any pixel under it is.

    Thin lines survive the shrink.
    """
    if factor <= 1:
        return image.astype(bool)
    h, w = image.shape
    hh, ww = math.ceil(h / factor), math.ceil(w / factor)
    padded = np.zeros((hh * factor, ww * factor), dtype=bool)
    padded[:h, :w] = image.astype(bool)
    return padded.reshape(hh, factor, ww, factor).any(axis=(1, 3))


def _pad_to(image: np.ndarray, rows_multiple: int, cols_multiple: int) -> np.ndarray:
    h, w = image.shape
    hh = math.ceil(h / rows_multiple) * rows_multiple
    ww = math.ceil(w / cols_multiple) * cols_multiple
    out = np.zeros((hh, ww), dtype=bool)
    out[:h, :w] = image
    return out


def halfblock_lines(image: np.ndarray) -> list[str]:
    """Two pixel rows per text row: ▀ top, ▄ bottom, █ both."""
    img = _pad_to(image.astype(bool), 2, 1)
    top, bottom = img[0::2], img[1::2]
    return ["".join(_HALF[(int(a), int(b))] for a, b in zip(t, u)) for t, u in zip(top, bottom)]


def braille_lines(image: np.ndarray) -> list[str]:
    """Four pixel rows and two columns per text cell, as Unicode braille."""
    img = _pad_to(image.astype(bool), 4, 2)
    h, w = img.shape
    cells = img.reshape(h // 4, 4, w // 2, 2).transpose(0, 2, 1, 3)  # rows, cols, 4, 2
    codes = (cells * _BRAILLE_BITS).sum(axis=(2, 3)) + _BRAILLE_BASE
    return ["".join(map(chr, row)) for row in codes]


def fit_binary_image(image: np.ndarray, cols: int, rows: int) -> tuple[list[str], int, str]:
    """Render `image` as large as it fits in cols x rows text cells.

    Returns the lines, the pooling factor used and the style ("half" or "braille").
    Half-blocks are chosen when they show the image at the same factor (they read better),
    braille otherwise (four times the pixels in the same space).
    """
    h, w = image.shape
    if cols <= 0 or rows <= 0:
        return [], 0, ""

    def smallest_factor(px_per_col: int, px_per_row: int) -> int:
        return max(1, math.ceil(w / (cols * px_per_col)), math.ceil(h / (rows * px_per_row)))

    half, braille = smallest_factor(1, 2), smallest_factor(2, 4)
    if half <= braille:
        return halfblock_lines(pool_any(image, half)), half, "half"
    return braille_lines(pool_any(image, braille)), braille, "braille"


def plot_points(
    points: np.ndarray,
    cols: int,
    rows: int,
    x_range: tuple[float, float],
    y_range: tuple[float, float],
) -> list[str]:
    """Scatter (x, y) points on a braille canvas; y up. Braille dots are about square."""
    if cols <= 0 or rows <= 0:
        return []
    grid = np.zeros((rows * 4, cols * 2), dtype=bool)
    if len(points):
        pts = np.asarray(points, dtype=np.float64)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        (x0, x1), (y0, y1) = x_range, y_range
        pts = pts[(pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)]
        # the far edges belong to the last dot, not to one past it
        cx = np.minimum(np.floor((pts[:, 0] - x0) / (x1 - x0) * cols * 2).astype(int), cols * 2 - 1)
        cy = np.minimum(np.floor((y1 - pts[:, 1]) / (y1 - y0) * rows * 4).astype(int), rows * 4 - 1)
        grid[cy, cx] = True
    return braille_lines(grid)
