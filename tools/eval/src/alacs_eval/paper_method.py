"""The paper's localization (§2): among the candidate lines, the most reliable one by
P = ω1·N - ω2·Δd (N its pixel count, Δd the distance in pixels of its middle from the
expected centre); the 2D middle of that line, triangulated, is the apple's position (the
marker on its face). For a centre, we push that point one nominal radius along the ray.
ω1 = 1 and ω2 = 2 as in the localizer's fallback: the paper gives no values."""

from __future__ import annotations

import dataclasses

import numpy as np

from alacs_eval.camera import Calibration
from alacs_eval.paper_line import PaperLine

W1, W2 = 1.0, 2.0
NOMINAL_RADIUS_MM = 40.0


@dataclasses.dataclass
class Candidate:
    slide_mm: float
    n: int
    middle_px: tuple[float, float]  # (column, row), full frame
    score: float


def candidate(line: PaperLine, roi: tuple[int, int, int, int], slide_mm: float,
              expected_px: tuple[float, float]) -> Candidate | None:
    if not line.has_curve or len(line.rows) == 0:
        return None
    mid = float(line.rows[len(line.rows) // 2])
    u = float(line.column_at(np.array([mid]))[0]) + roi[0]
    v = mid + roi[1]
    dd = float(np.hypot(u - expected_px[0], v - expected_px[1]))
    n = len(line.rows)
    return Candidate(slide_mm, n, (u, v), W1 * n - W2 * dd)


def localize(cands: list[Candidate | None], cal: Calibration) -> tuple[np.ndarray, np.ndarray] | None:
    """(surface point = approach estimate, centre estimate) from the best candidate."""
    ok = [c for c in cands if c is not None]
    if not ok:
        return None
    best = max(ok, key=lambda c: c.score)
    p = cal.triangulate(np.array([best.middle_px]), best.slide_mm)[0]
    if not np.all(np.isfinite(p)) or p[2] <= 0:
        return None
    return p, p + NOMINAL_RADIUS_MM * p / np.linalg.norm(p)
