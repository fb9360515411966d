"""The ALACS paper's Laser Line Extraction, in numpy, as published (docs/lle.md): the
baseline the C++ LLE (edge/image) is compared with.

    from paper_lle import paper_lle
    line = paper_lle(rgb)            # rgb: H x W x 3 uint8, RGB order
    line.rows, line.columns          # the focused centre of every row with candidates
    line.column_at(rows)             # the fitted 4th-order curve
    np.asarray(line)                 # (n, 2): row, column (what tools/eval reads)

Importable without installing (``sys.path.insert(0, "tools/paper_lle")``), or by file
path (tools/eval does). ``python tools/paper_lle/paper_lle.py --help`` for the command.

Algorithm 1 as printed computes G1 = R[:, :-2s] - R[:, s:-s], the neighbour minus the
centre; on uint8 data that subtraction wraps (10 - 100 = 166). ``literal=False`` (the
default) implements what the paper means, a pixel brighter than both neighbours `step`
columns away by more than `th`; ``literal=True`` keeps the printed form on uint8 (the
subtraction wraps; the element-wise product is taken without overflow). Both match the
C++ implementation (edge/image, BrceForm::kMeaning / kLiteral) bit for bit.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import numpy as np
from numpy.polynomial import Polynomial


class PaperLine:
    """The result of :func:`paper_lle` (pixel centres at integers, rows and columns of the image).

    A plain class, not a dataclass: tools/eval loads this file by path without registering
    it in sys.modules, which dataclasses need.
    """

    def __init__(self, rows: np.ndarray, columns: np.ndarray, counts: np.ndarray, curve: Polynomial | None,
                 mask: np.ndarray) -> None:
        self.rows = rows        # int, rows with at least one candidate left after noise removal
        self.columns = columns  # float, the mean of those candidates' columns (line focusing)
        self.counts = counts    # int, the number of candidates of each of those rows
        self.curve = curve      # column = curve(row), least squares; None below order + 1 rows
        self.mask = mask        # bool H x W, the candidates after noise removal

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        """(n, 2): row, focused column; the form tools/eval's adapter reads."""
        out = np.column_stack([self.rows.astype(float), self.columns.astype(float)])
        return out.astype(dtype) if dtype is not None else out

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


# --- the command -------------------------------------------------------------------------
# paper_lle.py IMAGE [--roi X,Y,W,H] [--json OUT] [--step 4 --th 40 --theta 8 --gamma 3] [--literal]
# paper_lle.py --time FRAME.npy [--repeat N] [--roi X,Y,W,H]   (prints the median ms; tools/bench)


def _roi(text: str) -> tuple[int, int, int, int]:
    parts = [int(p) for p in text.split(",")]
    if len(parts) != 4:
        raise argparse.ArgumentTypeError("X,Y,W,H")
    return parts[0], parts[1], parts[2], parts[3]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="paper-lle", description="The paper's LLE on one image, or its median time on a .npy frame (tools/bench).")
    ap.add_argument("image", nargs="?", help="PNG/JPEG (read as RGB)")
    ap.add_argument("--roi", type=_roi, help="X,Y,W,H in image pixels")
    ap.add_argument("--json", help="write rows, columns and the curve here")
    ap.add_argument("--step", type=int, default=4)
    ap.add_argument("--th", type=int, default=40)
    ap.add_argument("--theta", type=int, default=8)
    ap.add_argument("--gamma", type=int, default=3)
    ap.add_argument("--literal", action="store_true", help="Algorithm 1 as printed (uint8 wrap)")
    ap.add_argument("--time", metavar="NPY", help="time paper_lle on this H x W x 3 uint8 .npy (BGR or RGB)")
    ap.add_argument("--repeat", type=int, default=20)
    a = ap.parse_args(argv)
    if a.time:
        frame = np.load(a.time)
        if frame.ndim != 3 or frame.dtype != np.uint8:
            print(f"paper-lle: {a.time} is not H x W x 3 uint8", file=sys.stderr)
            return 1
        rgb = np.ascontiguousarray(frame[..., ::-1])  # the benchmark writes BGR
        if a.roi:
            x, y, w, h = a.roi
            rgb = rgb[y : y + h, x : x + w]
        paper_lle(rgb, a.step, a.th, a.theta, a.gamma, literal=a.literal)  # warm-up
        times = []
        for _ in range(max(1, a.repeat)):
            t0 = time.perf_counter()
            paper_lle(rgb, a.step, a.th, a.theta, a.gamma, literal=a.literal)
            times.append((time.perf_counter() - t0) * 1e3)
        print(f"{statistics.median(times):.3f}")
        return 0
    if not a.image:
        ap.error("give IMAGE or --time NPY")
    from PIL import Image

    try:
        rgb = np.asarray(Image.open(a.image).convert("RGB"))
    except OSError as e:
        print(f"paper-lle: {e}", file=sys.stderr)
        return 1
    x0 = y0 = 0
    if a.roi:
        x0, y0, w, h = a.roi
        if w <= 0 or h <= 0 or x0 < 0 or y0 < 0 or x0 + w > rgb.shape[1] or y0 + h > rgb.shape[0]:
            print(f"paper-lle: ROI {a.roi} leaves the {rgb.shape[1]}x{rgb.shape[0]} image", file=sys.stderr)
            return 1
        rgb = rgb[y0 : y0 + h, x0 : x0 + w]
    line = paper_lle(rgb, a.step, a.th, a.theta, a.gamma, literal=a.literal)
    out = {
        "rows": [int(r) + y0 for r in line.rows],
        "columns": [float(c) + x0 for c in line.columns],
        "curve_at_rows": [float(c) + x0 for c in line.column_at(line.rows)] if line.curve else None,
    }
    text = json.dumps(out)
    if a.json:
        with open(a.json, "w") as f:
            f.write(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
