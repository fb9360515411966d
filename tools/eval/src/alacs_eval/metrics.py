"""The paper's metrics: laser line displacement on central segments (Table 1), and
localization error and success within the end-effector's tolerance."""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Iterable

import numpy as np

SEGMENTS = (10, 20, 30, 40, 50, 60, 70, 80)
TOLERANCE_MM = 20.0  # the vacuum end-effector's tolerance (paper §5.2)

# The paper's Table 1 (300 cases, manual labels) and its localization figures.
PAPER_LLE = {
    "avg": (1.0, 1.2, 1.3, 1.4, 1.5, 1.7, 1.7, 1.9),
    "min": (0.0, 0.2, 0.3, 0.4, 0.4, 0.5, 0.5, 0.6),
    "max": (2.9, 3.2, 3.3, 3.5, 3.8, 3.9, 4.0, 4.2),
}
PAPER_DISTANCES = (1000, 1200, 1400, 1600)
PAPER_LOC = {
    # (lines, occluded) -> mean error (mm) per distance; None where the paper gives only a range
    ("single", False): None,  # "2.5 mm to 5.8 mm at 1.0-1.6 m"
    ("single", True): (6.9, 7.2, 9.0, 11.2),
    ("multi", False): None,  # "5.5 mm to 9.1 mm"
    ("multi", True): (9.2, 11.6, 13.9, 17.5),
}
PAPER_LOC_RANGE = {("single", False): (2.5, 5.8), ("multi", False): (5.5, 9.1)}


# Fewer visible, laser-lit rows of the target than this: no central segments, nothing to
# find (the frame is left out of the rows-found share, and counted beside it).
MIN_VISIBLE_ROWS = 3


def mean_found(shares: Iterable[float]) -> float:
    """The mean share of rows found over the frames that had rows to find (NaN: none had)."""
    v = np.asarray(list(shares), float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if len(v) else math.nan


def has_rows_to_find(truth: np.ndarray) -> bool:
    """Whether the laser lights at least MIN_VISIBLE_ROWS visible rows of the target."""
    return len(visible_rows(truth)) >= MIN_VISIBLE_ROWS


def visible_rows(truth: np.ndarray) -> np.ndarray:
    """The visible, laser-lit truth rows, one per image row (the first where the arc turns back)."""
    vis = truth[truth["flags"] == 0]
    if len(vis) == 0:
        return vis
    vis = np.sort(vis, order="row")
    _, first = np.unique(vis["row"], return_index=True)
    return vis[first]


def segment_metrics(truth: np.ndarray, predict: Callable[[np.ndarray], np.ndarray] | None,
                    segments: Iterable[int] = SEGMENTS) -> dict[int, tuple[float, float]]:
    """Per central segment (percent of the visible line's row span): the mean |predicted -
    true column| (px) over the visible truth rows the prediction covers, and the share of
    those rows it covers. A method's line exists only over the rows where it found it
    (`predict` returns NaN elsewhere): the paper compares "the points on each row" of both
    lines. (NaN, 0) when there is no prediction in the segment; (NaN, NaN) when the target
    has fewer than MIN_VISIBLE_ROWS visible, laser-lit rows (or none in the segment): there
    is nothing to find, and 0 of 0 rows is not a miss (leaves hid where the line crossed)."""
    vis = visible_rows(truth)
    out: dict[int, tuple[float, float]] = {}
    if len(vis) < MIN_VISIBLE_ROWS:
        return {s: (math.nan, math.nan) for s in segments}
    if predict is None:
        return {s: (math.nan, 0.0) for s in segments}
    r0, r1 = float(vis["row"][0]), float(vis["row"][-1])
    centre, half = 0.5 * (r0 + r1), 0.5 * (r1 - r0)
    for s in segments:
        sel = np.abs(vis["row"] - centre) <= s / 100.0 * half + 1e-9
        rows = vis[sel]
        if len(rows) == 0:
            out[s] = (math.nan, math.nan)
            continue
        pred = np.asarray(predict(rows["row"].astype(float)), float)
        ok = np.isfinite(pred)
        out[s] = (float(np.mean(np.abs(pred[ok] - rows["column"][ok]))) if ok.any() else math.nan,
                  float(ok.mean()))
    return out


def segment_displacements(truth: np.ndarray, predict: Callable[[np.ndarray], np.ndarray] | None,
                          segments: Iterable[int] = SEGMENTS) -> dict[int, float]:
    """The displacement part of segment_metrics."""
    return {s: d for s, (d, _) in segment_metrics(truth, predict, segments).items()}


@dataclasses.dataclass
class Summary:
    avg: float
    min: float
    max: float
    median: float
    n: int
    missing: int


def summarize(values: Iterable[float]) -> Summary:
    v = np.asarray(list(values), float)
    ok = v[np.isfinite(v)]
    if len(ok) == 0:
        return Summary(math.nan, math.nan, math.nan, math.nan, 0, len(v))
    return Summary(float(ok.mean()), float(ok.min()), float(ok.max()), float(np.median(ok)), len(ok), len(v) - len(ok))


@dataclasses.dataclass
class LocStats:
    mean: float
    std: float
    median: float
    p90: float
    success: float  # share of ALL cases within the tolerance (no result counts as a failure)
    n: int
    no_result: int


def loc_stats(errors: Iterable[float]) -> LocStats:
    e = np.asarray(list(errors), float)
    ok = e[np.isfinite(e)]
    n = len(e)
    if len(ok) == 0:
        return LocStats(math.nan, math.nan, math.nan, math.nan, 0.0, n, n)
    return LocStats(float(ok.mean()), float(ok.std()), float(np.median(ok)), float(np.percentile(ok, 90)),
                    float(np.sum(ok <= TOLERANCE_MM)) / n if n else math.nan, n, n - len(ok))
