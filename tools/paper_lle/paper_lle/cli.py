"""paper-lle: the paper's LLE on one image, or the time it takes (for tools/bench).

    python -m paper_lle IMAGE [--roi X,Y,W,H] [--json OUT] [--step 4 --th 40 --theta 8 --gamma 3] [--literal]
    python -m paper_lle --time FRAME.npy [--repeat N] [--roi X,Y,W,H]   (prints the median ms)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import numpy as np

from paper_lle.core import paper_lle


def _roi(text: str) -> tuple[int, int, int, int]:
    parts = [int(p) for p in text.split(",")]
    if len(parts) != 4:
        raise argparse.ArgumentTypeError("X,Y,W,H")
    return parts[0], parts[1], parts[2], parts[3]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="paper-lle", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
