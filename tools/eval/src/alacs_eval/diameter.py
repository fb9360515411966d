"""Where an occluded round fruit's diameter error comes from (issue 17; tuning worlds only).

`alacs-eval diagnose --loc --diameter` takes a tuning world's occluded five-stop scans whose
target is a plain sphere (the generator's shape "sphere": no lumps, aspect within a few
percent of 1), runs `alacs-twin process --rows` on them, and compares, per scan, the
diameter error of three estimates:

- **the sensor**: the localizer's result, as it goes out;
- **its samples**: a sphere fitted (Huber, as the localizer's refinement) to the samples the
  localizer kept that lie on the target by the truth (within BAND_PX of the target's true
  column in the same image row), triangulated as the sensor does: the sensor's own data
  with a perfect choice of which samples are the fruit's;
- **exact points**: a sphere fitted (least squares: they have no outliers) to the truth's 3D
  points at those rows: what that part of the fruit gives with error-free samples (the
  shape of the visible part).

The gap between the first two is the localizer's (which samples join the fit, its priors
and the spheroid); between the last two, the LLE's sub-pixel errors through the
triangulation. The stops of both passes count, not the aimed frame (the five-line result
does not use it). Only scans whose result used three lines or more and which have
MIN_SAMPLES such samples enter (with fewer lines the diameter is mostly the prior's).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from alacs_eval import twin, worlds
from alacs_eval.scans import Scan, target_truth

if TYPE_CHECKING:
    from alacs_eval.diagnose import Config

BAND_PX = 2.0      # a kept sample within this of the target's true column is the target's
MIN_SAMPLES = 30   # fewer of the target's samples: the scan is left out
MIN_LINES = 3      # fewer lines in the sensor's fit: its diameter is the prior's, left out
HUBER_MM = 1.0     # as geometry::SphereFitParams::huberMm


def fit_sphere(points: np.ndarray, centre: np.ndarray, radius: float, huber_mm: float = HUBER_MM,
               iterations: int = 60) -> tuple[np.ndarray, float]:
    """Geometric sphere fit (iteratively reweighted Gauss–Newton, Huber weights; huber_mm <= 0:
    least squares) from a start; returns (centre, radius)."""
    x = np.r_[np.asarray(centre, float), float(radius)]
    for _ in range(iterations):
        v = points - x[:3]
        n = np.linalg.norm(v, axis=1)
        r = n - x[3]
        jac = np.c_[-v / n[:, None], -np.ones(len(points))]
        w = np.minimum(1.0, huber_mm / np.maximum(np.abs(r), 1e-12)) if huber_mm > 0 else np.ones(len(points))
        jw = jac * w[:, None]
        step = np.linalg.lstsq(jw.T @ jac, jw.T @ r, rcond=None)[0]
        x = x - step
        if np.linalg.norm(step) < 1e-9:
            break
    return x[:3], float(x[3])


def target_samples(scan: Scan, detail: dict) -> tuple[np.ndarray, np.ndarray]:
    """The kept samples of the scan's stops (both passes; not the aimed frame, which the
    five-line result does not use; a frame served twice counts once) that lie on the target by
    the truth: (measured 3D points, triangulated at the frame's slide position with the scan's
    calibration; the truth's 3D points at those rows)."""
    cal = scan.calibration()
    measured, exact = [], []
    for i, fr in worlds.stop_frames(scan, detail):
        kept = fr.get("kept", [])
        if not kept:
            continue
        truth = scan.truth_rows(scan.frames[i], scan.target_id)
        by_row: dict[int, list] = {}
        for t in truth[truth["flags"] == 0]:
            by_row.setdefault(int(t["row"]), []).append(t)
        px = np.asarray([[col, row] for row, col in kept], float)
        for (col, row), p in zip(px, cal.triangulate(px, float(fr["slide_mm"]))):
            near = [t for t in by_row.get(int(round(row)), []) if abs(t["column"] - col) <= BAND_PX]
            if near:
                t = min(near, key=lambda t: abs(t["column"] - col))
                measured.append(p)
                exact.append((t["x"], t["y"], t["z"]))
    return np.asarray(measured, float).reshape(-1, 3), np.asarray(exact, float).reshape(-1, 3)


def scan_sources(scan: Scan, detail: dict) -> dict[str, Any] | None:
    """The three diameter errors (mm, signed) of one scan, or None when it is left out."""
    e = detail.get("multi", {})
    if not e.get("ok") or int(e.get("lines_used", 0)) < MIN_LINES:
        return None
    measured, exact = target_samples(scan, detail)
    if len(measured) < MIN_SAMPLES:
        return None
    centre, radius, _ = target_truth(scan)
    _, r_measured = fit_sphere(measured, centre, radius)
    _, r_exact = fit_sphere(exact, centre, radius, huber_mm=0.0)
    return {"sensor": float(e["diameter_mm"]) - 2.0 * radius, "samples": 2.0 * (r_measured - radius),
            "exact": 2.0 * (r_exact - radius), "samples_n": len(measured), "lines": int(e["lines_used"]),
            "diameter_true": 2.0 * radius}


def run(cfg: Config, cases: list[dict], extra: tuple[str, ...]) -> dict[str, Any]:
    """The occluded plain spheres among `cases` (a tuning world's, from diagnose.loc_cases);
    `extra`: the options `process` takes (as the scans were generated, then the user's)."""
    chosen = [c for c in cases if c["occluded"] and c.get("shape") == "sphere"]
    if not chosen:
        raise ValueError(f"{cfg.world}: no occluded scan of a plain sphere (the benchmark's fruit are all oblate; "
                         "use --world benchmark-hard)")
    dirs = [c["dir"] for c in chosen]
    detail = twin.process(cfg.twin, dirs, cfg.jobs, f"{cfg.world}: the round fruit's samples", rows=True,
                          quiet=cfg.quiet, extra=extra)
    rows = []
    for c in chosen:
        r = scan_sources(Scan.load(c["dir"]), detail.get(c["dir"], {}))
        if r is not None:
            rows.append({"case": c["case"], "distance": int(c["distance_mm"]), **r})
    summary = {}
    for key in ("sensor", "samples", "exact"):
        v = np.asarray([r[key] for r in rows], float)
        summary[key] = {"bias": float(v.mean()), "abs": float(np.abs(v).mean()),
                        "median_abs": float(np.median(np.abs(v)))} if len(v) else \
            {"bias": math.nan, "abs": math.nan, "median_abs": math.nan}
    return {"world": cfg.world, "seed": cfg.seed, "scans": len(chosen), "used": len(rows), "summary": summary,
            "process_args": list(extra), "rows": sorted(rows, key=lambda r: -abs(r["sensor"]))}


NAMES = {"sensor": "the sensor's result",
         "samples": "a sphere on its samples that lie on the target (by the truth)",
         "exact": "a sphere on the truth's points at those rows"}


def text(res: dict[str, Any], worst: int = 10) -> str:
    args = " ".join(res["process_args"]) or "defaults"
    L = [f"{res['world']}, seed {res['seed']} ({args}): occluded plain spheres {res['scans']}, of which "
         f"{res['used']} with {MIN_LINES} lines or more in the fit and {MIN_SAMPLES} or more samples on the target",
         "diameter error (mm): mean signed, mean absolute, median absolute:"]
    L += [f"  {NAMES[k]:<62} {v['bias']:+.2f}  {v['abs']:.2f}  {v['median_abs']:.2f}"
          for k, v in res["summary"].items()]
    L += ["", "largest sensor errors (sensor / samples / exact, mm):"]
    L += [f"  {r['case']} true {r['diameter_true']:.1f}: {r['sensor']:+.1f} / {r['samples']:+.1f} / "
          f"{r['exact']:+.1f} ({r['lines']} lines, {r['samples_n']} samples)" for r in res["rows"][:worst]]
    return "\n".join(L)
