"""The evaluation's view of one line found by the paper's LLE (tools/paper_lle/paper_lle.py):
its rows, their centroids and the fitted curve, whichever implementation produced it."""

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
