"""The paper's Laser Line Extraction (Algorithms 1 and 2, line focusing, curve fitting),
in numpy, as published. Used by the evaluation until tools/paper_lle/paper_lle.py (issue
4) lands; `paper_lle.load()` picks that one when it exists.

Two readings had to be made, both documented in docs/evaluation.md:
  * Algorithm 1 prints G1 = R[:, :-2s] - R[:, s:-s] (neighbour minus centre). Taken
    literally that marks pixels darker than their neighbours, not the line; on uint8 it
    also wraps. `form="meaning"` (the default) subtracts the neighbour from the centre,
    as the text describes; `form="literal"` is the printed form on uint8, wrap included.
  * Algorithm 2 sums each window over G, the detector's output, and clears it in C.
Line focusing averages the column indices of a row's remaining pixels; the curve is a
4th-order polynomial column = p(row) by least squares (np.polyfit), no outlier rejection.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np


@dataclasses.dataclass
class PaperLine:
    rows: np.ndarray          # rows with at least one line pixel (crop coordinates)
    columns: np.ndarray       # their centroids (mean column index)
    coeffs: np.ndarray | None  # np.polyval coefficients of column = p(row), None if < 5 rows
    pixels: int               # line pixels after noise removal
    curve: Callable[[np.ndarray], np.ndarray] | None = None  # another implementation's curve

    @property
    def has_curve(self) -> bool:
        return self.coeffs is not None or self.curve is not None

    def column_at(self, rows: np.ndarray) -> np.ndarray:
        if self.curve is not None:
            return np.asarray(self.curve(np.asarray(rows, float)), float)
        if self.coeffs is None:
            return np.full(np.shape(rows), np.nan)
        return np.polyval(self.coeffs, np.asarray(rows, float))


def brce(red: np.ndarray, step: int = 4, th: int = 40, form: str = "meaning") -> np.ndarray:
    """Algorithm 1 (bRCE): n×m 0/1 mask aligned with the image's columns."""
    n, m = red.shape
    mask = np.zeros((n, m), np.uint8)
    if m <= 2 * step:
        return mask
    if form == "literal":
        r = red.astype(np.uint8)
        g1 = r[:, : -2 * step] - r[:, step:-step]  # uint8: wraps, as the printed code would
        g2 = r[:, 2 * step:] - r[:, step:-step]
        g1 = np.where(g1 <= th, 0, g1).astype(np.uint8)
        g2 = np.where(g2 <= th, 0, g2).astype(np.uint8)
        g = g1 * g2  # uint8 product, wraps too
    elif form == "meaning":
        r = red.astype(np.int32)
        g1 = r[:, step:-step] - r[:, : -2 * step]
        g2 = r[:, step:-step] - r[:, 2 * step:]
        g1 = np.where(g1 <= th, 0, g1)
        g2 = np.where(g2 <= th, 0, g2)
        g = g1.astype(np.int64) * g2
    else:
        raise ValueError(f"form must be 'meaning' or 'literal', got {form!r}")
    mask[:, step: m - step] = (g > 0).astype(np.uint8)
    return mask


def remove_noise(g: np.ndarray, theta: int = 8, gamma: int = 3) -> np.ndarray:
    """Algorithm 2: windows of W/4 × H/2 slid by γ; a window with ≤ θ pixels is cleared."""
    h_g, w_g = g.shape
    w, h = w_g // 4, h_g // 2
    c = g.copy()
    if w < 1 or h < 1:
        return c
    u = (w_g - w) // gamma
    v = h_g // h
    for j in range(v):
        y = j * h
        band = g[y: y + h].sum(axis=0, dtype=np.int64)
        csum = np.concatenate([[0], np.cumsum(band)])
        for i in range(u):
            x = i * gamma
            if csum[x + w] - csum[x] <= theta:
                c[y: y + h, x: x + w] = 0
    return c


def focus(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Line focusing: per row, the mean column index of the remaining pixels."""
    counts = c.sum(axis=1)
    rows = np.nonzero(counts)[0]
    cols = np.arange(c.shape[1], dtype=float)
    centroids = (c[rows].astype(float) @ cols) / counts[rows]
    return rows.astype(float), centroids


def paper_lle(rgb: np.ndarray, step: int = 4, th: int = 40, theta: int = 8, gamma: int = 3,
              form: str = "meaning", order: int = 4) -> PaperLine:
    """The four steps on an RGB image (the apple's box). Coordinates are the image's."""
    red = rgb[..., 0]
    c = remove_noise(brce(red, step, th, form), theta, gamma)
    rows, cols = focus(c)
    coeffs = np.polyfit(rows, cols, order) if len(rows) > order else None
    return PaperLine(rows, cols, coeffs, int(c.sum()))
