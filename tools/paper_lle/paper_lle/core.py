"""The paper's four LLE steps (Algorithms 1 and 2, line focusing, curve fitting).

Algorithm 1 as printed computes G1 = R[:, :-2s] - R[:, s:-s], the neighbour minus the
centre; on uint8 data that subtraction wraps (10 - 100 = 166). ``literal=False`` (the
default) implements what the paper means, a pixel brighter than both neighbours `step`
columns away by more than `th`; ``literal=True`` keeps the printed form on uint8 (the
subtraction wraps; the element-wise product is taken without overflow). Both match the
C++ implementation (edge/image, BrceForm::kMeaning / kLiteral) bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import Polynomial


@dataclass
class PaperLine:
    """The result of :func:`paper_lle` (pixel centres at integers, rows and columns of the image)."""

    rows: np.ndarray      # int, rows with at least one candidate left after noise removal
    columns: np.ndarray   # float, the mean of those candidates' columns (line focusing)
    counts: np.ndarray    # int, the number of candidates of each of those rows
    curve: Polynomial | None  # column = curve(row), least squares; None below order + 1 rows
    mask: np.ndarray      # bool H x W, the candidates after noise removal

    def column_at(self, rows: np.ndarray | list[int] | int) -> np.ndarray:
        """The fitted curve at `rows` (NaN when there is no curve)."""
        r = np.asarray(rows, dtype=float)
        if self.curve is None:
            return np.full(r.shape, np.nan)
        return np.asarray(self.curve(r), dtype=float)


def brce(rgb: np.ndarray, step: int = 4, th: int = 40, literal: bool = False) -> np.ndarray:
    """Algorithm 1 (bRCE) on the red channel: the H x W candidate mask."""
    red = rgb[..., 0]
    h, w = red.shape
    g = np.zeros((h, w), dtype=bool)
    if w <= 2 * step:
        return g
    if literal:
        r8 = red.astype(np.uint8)
        g1 = (r8[:, : -2 * step] - r8[:, step:-step]).astype(np.int32)  # uint8: wraps
        g2 = (r8[:, 2 * step :] - r8[:, step:-step]).astype(np.int32)
        g1[g1 <= th] = 0
        g2[g2 <= th] = 0
        g[:, step:-step] = (g1 * g2) > 0
    else:
        r = red.astype(np.int16)
        c = r[:, step:-step]
        g[:, step:-step] = ((c - r[:, : -2 * step]) > th) & ((c - r[:, 2 * step :]) > th)
    return g


def remove_noise(g: np.ndarray, theta: int = 8, gamma: int = 3) -> np.ndarray:
    """Algorithm 2: windows of w_G/4 x h_G/2 slid by gamma over bands of h rows; a window
    holding at most theta candidates (of G) is cleared in C."""
    h_g, w_g = g.shape
    w, h = w_g // 4, h_g // 2
    c = g.copy()
    if w < 1 or h < 1:
        return c
    u = (w_g - w) // gamma
    v = h_g // h
    for j in range(v):
        y = j * h
        # The count of every window of the band from a prefix sum of its column counts.
        prefix = np.concatenate(([0], np.cumsum(g[y : y + h].sum(axis=0))))
        for i in range(u):
            x = i * gamma
            if prefix[x + w] - prefix[x] <= theta:
                c[y : y + h, x : x + w] = False
    return c


def focus_rows(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Line focusing: per row, the mean of the candidate columns (rows with none are left out)."""
    counts = c.sum(axis=1)
    rows = np.nonzero(counts)[0]
    cols = np.arange(c.shape[1], dtype=np.int64)
    sums = (c[rows] * cols).sum(axis=1)
    return rows, sums / counts[rows], counts[rows]


def paper_lle(rgb: np.ndarray, step: int = 4, th: int = 40, theta: int = 8, gamma: int = 3, *,
              order: int = 4, literal: bool = False) -> PaperLine:
    """The paper's LLE on an RGB image (H x W x 3, uint8, R first): bRCE, noise removal,
    line focusing, and a least-squares polynomial of `order` (4 in the paper) column = p(row)."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] < 3 or rgb.dtype != np.uint8:
        raise ValueError(f"paper_lle wants an H x W x 3 uint8 image, got {rgb.dtype} {rgb.shape}")
    if not 1 <= step or not 0 <= th <= 254 or theta < 0 or gamma < 1:
        raise ValueError("step >= 1, 0 <= th <= 254, theta >= 0, gamma >= 1")
    g = brce(rgb, step, th, literal)
    c = remove_noise(g, theta, gamma)
    rows, cols, counts = focus_rows(c)
    curve = Polynomial.fit(rows, cols, order) if rows.size > order else None
    return PaperLine(rows=rows, columns=cols, counts=counts, curve=curve, mask=c)
