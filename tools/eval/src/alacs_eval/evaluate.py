"""The evaluation itself: generate (or reuse) the benchmark sets with the twin, run our
pipeline (C++, through the replay source) and the paper's method (numpy) on the same
scans, and compute the paper's figures for both."""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from alacs_eval import metrics, paper_method, twin
from alacs_eval.camera import Calibration
from alacs_eval.paper_lle import load as load_paper_lle
from alacs_eval.scans import Scan, target_truth

DEFAULT_COMBO = (4, 40)
# The paper's Figure 8: step 2..14 at th 60 and at th 30; th 20..70 at step 4.
SWEEP = ([(s, 60) for s in range(2, 15, 2)] + [(s, 30) for s in range(2, 15, 2)] +
         [(4, t) for t in range(20, 71, 10)])
DISTANCES = (1000, 1200, 1400, 1600)
LLE_DISTANCES = (800, 1000, 1200, 1400, 1600)


@dataclasses.dataclass
class Config:
    work: Path
    twin: Path
    jobs: int = 2
    small: bool = False
    seed: int = 1
    calibration: str | None = None
    quiet: bool = False
    estimate_calibration: bool = False  # also run localization with a calibration estimated from twin scans

    @property
    def lle_count(self) -> int:
        return 20 if self.small else 320

    @property
    def loc_per_cell(self) -> int:
        return 3 if self.small else 120


def combos() -> list[tuple[int, int]]:
    out = [DEFAULT_COMBO]
    for c in SWEEP:
        if c not in out:
            out.append(c)
    return out


# ---- workers (top level, for multiprocessing) -----------------------------------------

_PAPER = None


def _paper():
    global _PAPER
    if _PAPER is None:
        _PAPER = load_paper_lle()[0]
    return _PAPER


def _paper_lle_case(task: tuple[str, list[tuple[int, int]]]) -> dict[str, Any]:
    directory, combo_list = task
    scan = Scan.load(directory)
    frame = next(f for f in scan.frames if f.laser_on)
    roi = scan.roi
    rgb = scan.region(frame, roi)
    truth = scan.truth_rows(frame, scan.target_id)
    out: dict[str, Any] = {"scan": directory, "combos": {}}
    for step, th in combo_list:
        line = _paper()(rgb, step=step, th=th)
        predict = None
        if line.has_curve and len(line.rows):
            lo, hi = float(np.min(line.rows)) + roi[1], float(np.max(line.rows)) + roi[1]

            def predict(rows: np.ndarray, l=line, lo=lo, hi=hi) -> np.ndarray:
                return np.where((rows >= lo) & (rows <= hi), l.column_at(rows - roi[1]) + roi[0], np.nan)

        seg = metrics.segment_metrics(truth, predict)
        out["combos"][f"{step},{th}"] = {
            "disp": {k: v[0] for k, v in seg.items()},
            "cover": {k: v[1] for k, v in seg.items()},
            "rows": int(len(line.rows)),
            "pixels": int(line.pixels),
        }
    return out


def _paper_loc_case(task: tuple[str, str | None]) -> dict[str, Any]:
    directory, cal_path = task
    scan = Scan.load(directory)
    cal = Calibration.load(Path(cal_path)) if cal_path else scan.calibration()
    roi = scan.roi
    expected = tuple(cal.project(scan.rough_mm[None, :])[0])
    stops, aimed = [], []
    for f in scan.frames:
        if not f.laser_on or f.tag == "second":  # the paper takes one exposure per stop
            continue
        line = _paper()(scan.region(f, roi))
        cand = paper_method.candidate(line, roi, f.slide_mm, expected)
        (aimed if f.tag == "aimed" else stops).append(cand)
    centre, radius, approach = target_truth(scan)
    res: dict[str, Any] = {"scan": directory}
    for name, cands in (("multi", stops), ("single", aimed if aimed else [])):
        est = paper_method.localize(cands, cal)
        if est is None:
            res[name] = {"approach_err": math.nan, "centre_err": math.nan}
        else:
            res[name] = {"approach_err": float(np.linalg.norm(est[0] - approach)),
                         "centre_err": float(np.linalg.norm(est[1] - centre))}
    return res


# ---- the run -------------------------------------------------------------------------

# How a row the localizer keeps several samples of is read (kept_rows): the LLE's line's
# sample (RowStatus kLine), or the sample nearest the rough position in 3D (the target's
# prior, the only one the localizer has before its fit). Both use the product's output
# alone, never the truth; the worlds' report gives both.
BY_LINE = "line"
BY_ROUGH = "rough"


def has_distances(frame: dict) -> bool:
    """Whether a processed frame gives each kept sample's distance from the rough position
    (`process --rows` since issue 17's second LLE reading); without them, reading by the
    rough position falls back to the line's."""
    d = frame.get("kept_from_rough_mm")
    return d is not None and len(d) == len(frame.get("kept", []))


def kept_rows(frame: dict, by: str = BY_LINE) -> dict[int, tuple[float, bool]]:
    """Our line per row: the samples the localizer keeps of the frame (its LLE, gated in 3D
    around the rough position); where a row has several, the LLE's line's (by BY_LINE, when
    `process --rows` gave the statuses) or the one nearest the rough position (by BY_ROUGH,
    when it gave `kept_from_rough_mm`), else the first. Each with whether it is the line's
    (else another segment's)."""
    on_line = {(int(round(s[0])), round(float(s[1]), 3)) for s in frame.get("rows", []) if len(s) > 3 and s[3] == 0}
    samples = frame.get("kept", [])
    from_rough = [0.0] * len(samples)
    if by == BY_ROUGH and has_distances(frame):
        # A distance the JSON could not carry (null: not finite) is no nearer than any other.
        from_rough = [math.inf if d is None or not math.isfinite(float(d)) else float(d)
                      for d in frame["kept_from_rough_mm"]]
    kept: dict[int, tuple[float, bool]] = {}
    nearest: dict[int, float] = {}
    for (row, col), dist in zip(samples, from_rough):
        key = int(round(row))
        line = (key, round(float(col), 3)) in on_line
        if by == BY_ROUGH:
            better = key not in kept or dist < nearest[key] or (dist == nearest[key] and line)
        else:
            better = key not in kept or line
        if better:
            kept[key] = (float(col), line)
            nearest[key] = float(dist)
    return kept


def _ours_lle(results: dict[str, dict], truths: dict[str, np.ndarray], by: str = BY_LINE) -> dict[str, dict]:
    """Our line per row (kept_rows, read `by`), against the truth per central segment."""
    out = {}
    for d, r in results.items():
        frames = r.get("frames", [])
        kept = {row: col for row, (col, _) in kept_rows(frames[0] if frames else {}, by).items()}
        predict = None
        if kept:
            def predict(rows: np.ndarray, kept=kept) -> np.ndarray:
                return np.array([kept.get(int(round(x)), np.nan) for x in rows], float)

        seg = metrics.segment_metrics(truths[d], predict)
        out[d] = {"disp": {k: v[0] for k, v in seg.items()}, "cover": {k: v[1] for k, v in seg.items()},
                  "rows": len(kept)}
    return out


def run(cfg: Config) -> dict[str, Any]:
    times: dict[str, float] = {}
    t = time.monotonic()
    gen_args = {"seed": cfg.seed, "jobs": cfg.jobs}
    lle_cases = twin.generate(cfg.twin, cfg.work / "lle", "lle", {"count": cfg.lle_count, **gen_args},
                              cfg.lle_count, "generating LLE scans", cfg.quiet)
    n_loc = cfg.loc_per_cell * len(DISTANCES) * 2
    loc_cases = twin.generate(cfg.twin, cfg.work / "loc", "loc", {"count": cfg.loc_per_cell, **gen_args}, n_loc,
                              "generating localization scans", cfg.quiet)
    times["generate"] = time.monotonic() - t

    lle_dirs = [c["dir"] for c in lle_cases]
    loc_dirs = [c["dir"] for c in loc_cases]
    truths = {}
    for d in lle_dirs:
        s = Scan.load(d)
        truths[d] = s.truth_rows(next(f for f in s.frames if f.laser_on), s.target_id)

    # Ours, on the LLE set, for every bRCE setting.
    t = time.monotonic()
    ours_lle: dict[tuple[int, int], dict[str, dict]] = {}
    raw_default: dict[str, dict] = {}
    for step, th in tqdm(combos(), desc="our LLE (bRCE settings)", disable=cfg.quiet, leave=False):
        res = twin.process(cfg.twin, lle_dirs, cfg.jobs, f"step {step} th {th}", rows=True, step=step, threshold=th,
                           calibration=cfg.calibration, quiet=True)
        ours_lle[(step, th)] = _ours_lle(res, truths)
        if (step, th) == DEFAULT_COMBO:
            raw_default = res
    times["ours_lle"] = time.monotonic() - t

    # The paper's LLE on the same frames and ROIs.
    t = time.monotonic()
    paper_lle_res: dict[str, dict] = {}
    with multiprocessing.get_context("fork").Pool(cfg.jobs) as pool:
        for r in tqdm(pool.imap_unordered(_paper_lle_case, [(d, combos()) for d in lle_dirs]), total=len(lle_dirs),
                      desc="paper's LLE (numpy)", disable=cfg.quiet, leave=False):
            paper_lle_res[r["scan"]] = r
    times["paper_lle"] = time.monotonic() - t

    # Localization: ours (C++) and the paper's method.
    t = time.monotonic()
    ours_loc = twin.process(cfg.twin, loc_dirs, cfg.jobs, "our localization", calibration=cfg.calibration,
                            quiet=cfg.quiet)
    times["ours_loc"] = time.monotonic() - t
    t = time.monotonic()
    paper_loc: dict[str, dict] = {}
    with multiprocessing.get_context("fork").Pool(cfg.jobs) as pool:
        for r in tqdm(pool.imap_unordered(_paper_loc_case, [(d, cfg.calibration) for d in loc_dirs]),
                      total=len(loc_dirs), desc="paper's localization", disable=cfg.quiet, leave=False):
            paper_loc[r["scan"]] = r
    times["paper_loc"] = time.monotonic() - t

    res = assemble(cfg, lle_cases, loc_cases, ours_lle, paper_lle_res, ours_loc, paper_loc, times)
    res["_examples"] = _examples(lle_cases, raw_default)
    if cfg.estimate_calibration:
        res["estimated_calibration"] = _with_estimated_calibration(cfg, loc_cases, times)
    return res


def _examples(lle_cases: list[dict], raw: dict[str, dict]) -> list[dict[str, Any]]:
    """One LLE case per condition, with the truth and both methods' curves, for a figure."""
    seen, distances, out = set(), set(), []
    for c in lle_cases:
        key = (c["lighting"], bool(c["occluded"]))
        if key in seen or c["distance_mm"] in distances:
            continue
        seen.add(key)
        distances.add(c["distance_mm"])
        scan = Scan.load(c["dir"])
        frame = next(f for f in scan.frames if f.laser_on)
        roi = scan.roi
        rgb = scan.region(frame, roi)
        truth = metrics.visible_rows(scan.truth_rows(frame, scan.target_id))
        f = raw.get(c["dir"], {}).get("frames", [{}])[0]
        ours = np.asarray(f.get("kept", []), float).reshape(-1, 2)
        line = _paper()(rgb)
        curve_rows = np.arange(truth["row"].min(), truth["row"].max() + 1) - roi[1] if len(truth) else np.array([])
        out.append({"title": f"{c['lighting']} {c['lux']:.0f} lux, {'occluded' if c['occluded'] else 'clear'}, "
                             f"{c['distance_mm'] / 1000:.1f} m", "rgb": rgb, "roi": roi, "truth": truth, "ours": ours,
                    "paper_rows": line.rows, "paper_cols": line.columns,
                    "paper_curve": (curve_rows, line.column_at(curve_rows)) if line.has_curve else None})
    return out


def _calibration_errors(est: Calibration, true: Calibration) -> dict[str, float]:
    angle = math.degrees(math.acos(min(1.0, abs(float(est.normal @ true.normal)))))
    return {"fx_px": est.fx - true.fx, "fy_px": est.fy - true.fy, "cx_px": est.cx - true.cx, "cy_px": est.cy - true.cy,
            "k1": est.dist[0] - true.dist[0], "normal_mrad": 1000.0 * math.radians(angle),
            "offset_mm": est.offset_mm - true.offset_mm, "scale": est.slide_scale - true.slide_scale}


def _with_estimated_calibration(cfg: Config, loc_cases: list[dict], times: dict[str, float]) -> dict[str, Any]:
    """Calibration scans from the twin, issue 5's alacs_calibrate on them, and both
    methods' localization again with what it estimated instead of the truth."""
    tool = twin.find_calibrate(cfg.twin)
    if tool is None:
        return {"ran": False, "why": "alacs_calibrate is not built next to alacs-twin"}
    t = time.monotonic()
    scans = cfg.work / "calib"
    twin.calibration_scans(cfg.twin, scans, cfg.seed + 100, cfg.jobs, cfg.quiet)
    est_path = cfg.work / "estimated_calibration.json"
    ok, log = twin.calibrate(tool, scans, est_path)
    times["calibration"] = time.monotonic() - t
    if not ok:
        return {"ran": False, "why": "alacs_calibrate refused or failed", "log": log[-2000:]}
    loc_dirs = [c["dir"] for c in loc_cases]
    ours = twin.process(cfg.twin, loc_dirs, cfg.jobs, "our localization (estimated calibration)",
                        calibration=str(est_path), quiet=cfg.quiet)
    paper: dict[str, dict] = {}
    with multiprocessing.get_context("fork").Pool(cfg.jobs) as pool:
        for r in tqdm(pool.imap_unordered(_paper_loc_case, [(d, str(est_path)) for d in loc_dirs]), total=len(loc_dirs),
                      desc="paper's localization (estimated calibration)", disable=cfg.quiet, leave=False):
            paper[r["scan"]] = r
    true_cal = Scan.load(loc_dirs[0]).calibration()
    out: dict[str, Any] = {"ran": True, "file": str(est_path),
                           "errors": _calibration_errors(Calibration.load(est_path), true_cal), "loc": {}}
    for method, results in (("ours", ours), ("paper", paper)):
        for lines in ("single", "multi"):
            for occ in (False, True):
                for dist in DISTANCES:
                    errs = []
                    for c in loc_cases:
                        if int(c["distance_mm"]) != dist or bool(c["occluded"]) != occ:
                            continue
                        centre, radius, approach = target_truth(Scan.load(c["dir"]))
                        if method == "ours":
                            e = results.get(c["dir"], {}).get(lines, {})
                            errs.append(float(np.linalg.norm(np.asarray(e["approach_mm"]) - approach)) if e.get("ok")
                                        else math.nan)
                        else:
                            errs.append(results[c["dir"]][lines]["approach_err"])
                    out["loc"].setdefault(method, {}).setdefault(lines, {}).setdefault(
                        "occluded" if occ else "clear", {})[str(dist)] = dataclasses.asdict(metrics.loc_stats(errs))
    return out


def _seg_table(per_case: list[dict[int, float]]) -> dict[str, Any]:
    return {str(s): dataclasses.asdict(metrics.summarize(c[s] for c in per_case)) for s in metrics.SEGMENTS}


def assemble(cfg: Config, lle_cases: list[dict], loc_cases: list[dict], ours_lle: dict, paper_lle_res: dict,
             ours_loc: dict, paper_loc: dict, times: dict[str, float]) -> dict[str, Any]:
    key = f"{DEFAULT_COMBO[0]},{DEFAULT_COMBO[1]}"
    lle_dirs = [c["dir"] for c in lle_cases]
    ours_default = ours_lle[DEFAULT_COMBO]

    def paper_disp(d: str, combo: str = key) -> dict[int, float]:
        return {int(k): v for k, v in paper_lle_res[d]["combos"][combo]["disp"].items()}

    def cover_table(per_case: list[dict[int, float]]) -> dict[str, float]:
        return {str(sg): metrics.mean_found(c[sg] for c in per_case) for sg in metrics.SEGMENTS}

    res: dict[str, Any] = {
        "meta": {
            "small": cfg.small, "seed": cfg.seed, "lle_cases": len(lle_cases), "loc_cases": len(loc_cases),
            "loc_per_cell": cfg.loc_per_cell, "paper_lle": load_paper_lle()[1], "times_s": times,
            "calibration": cfg.calibration or "the scans' (true) calibration",
        },
        "lle": {
            "ours": _seg_table([ours_default[d]["disp"] for d in lle_dirs]),
            "paper": _seg_table([paper_disp(d) for d in lle_dirs]),
            "ours_cover": cover_table([ours_default[d]["cover"] for d in lle_dirs]),
            "paper_cover": cover_table([{int(k): v for k, v in paper_lle_res[d]["combos"][key]["cover"].items()}
                                        for d in lle_dirs]),
        },
    }
    # LLE by condition (50 % segment), to see where each method struggles.
    cond: dict[str, Any] = {}
    for c in lle_cases:
        k = f"{c['lighting']}, {'occluded' if c['occluded'] else 'clear'}"
        cond.setdefault(k, {"ours": [], "paper": [], "lux": []})
        cond[k]["ours"].append(ours_default[c["dir"]]["disp"][50])
        cond[k]["paper"].append(paper_disp(c["dir"])[50])
        cond[k]["lux"].append(c["lux"])
    res["lle"]["by_condition"] = {
        k: {"ours": dataclasses.asdict(metrics.summarize(v["ours"])),
            "paper": dataclasses.asdict(metrics.summarize(v["paper"])),
            "lux": [float(min(v["lux"])), float(max(v["lux"]))]}
        for k, v in sorted(cond.items())}
    by_dist: dict[str, Any] = {}
    for c in lle_cases:
        k = str(int(c["distance_mm"]))
        by_dist.setdefault(k, {"ours": [], "paper": []})
        by_dist[k]["ours"].append(ours_default[c["dir"]]["disp"][50])
        by_dist[k]["paper"].append(paper_disp(c["dir"])[50])
    res["lle"]["by_distance"] = {k: {m: dataclasses.asdict(metrics.summarize(v[m])) for m in ("ours", "paper")}
                                 for k, v in sorted(by_dist.items(), key=lambda kv: int(kv[0]))}

    # bRCE sweep.
    sweep = []
    for step, th in combos():
        combo = f"{step},{th}"
        entry: dict[str, Any] = {"step": step, "th": th}
        for name, disp, rows in (
            ("ours", [ours_lle[(step, th)][d]["disp"][80] for d in lle_dirs],
             [ours_lle[(step, th)][d]["rows"] for d in lle_dirs]),
            ("paper", [paper_disp(d, combo)[80] for d in lle_dirs],
             [paper_lle_res[d]["combos"][combo]["rows"] for d in lle_dirs]),
        ):
            arr = np.asarray(disp, float)
            entry[name] = {
                "disp80": float(np.nanmean(arr)) if np.any(np.isfinite(arr)) else math.nan,
                "median80": float(np.nanmedian(arr)) if np.any(np.isfinite(arr)) else math.nan,
                "within2px": float(np.mean(np.where(np.isfinite(arr), arr, np.inf) < 2.0)),
                "rows": float(np.mean(rows)),
            }
        entry["paper"]["pixels"] = float(np.mean([paper_lle_res[d]["combos"][combo]["pixels"] for d in lle_dirs]))
        sweep.append(entry)
    res["sweep"] = sweep

    # Localization.
    loc: dict[str, Any] = {"ours": {}, "paper": {}}
    per_case = []
    for c in loc_cases:
        d = c["dir"]
        centre, radius, approach = target_truth(Scan.load(d))
        row = {"case": c["case"], "distance": int(c["distance_mm"]), "occluded": bool(c["occluded"]),
               "occlusion_share": c["occlusion_share"]}
        o = ours_loc.get(d, {})
        for lines in ("single", "multi"):
            e = o.get(lines, {})
            if e.get("ok"):
                row[f"ours_{lines}_approach"] = float(np.linalg.norm(np.asarray(e["approach_mm"]) - approach))
                row[f"ours_{lines}_centre"] = float(np.linalg.norm(np.asarray(e["center_mm"]) - centre))
                row[f"ours_{lines}_sphere"] = bool(e["sphere_fit"])
            else:
                row[f"ours_{lines}_approach"] = row[f"ours_{lines}_centre"] = math.nan
            p = paper_loc[d][lines]
            row[f"paper_{lines}_approach"] = p["approach_err"]
            row[f"paper_{lines}_centre"] = p["centre_err"]
        per_case.append(row)
    for method in ("ours", "paper"):
        for lines in ("single", "multi"):
            for what in ("approach", "centre"):
                for occ in (False, True):
                    for dist in DISTANCES:
                        errs = [r[f"{method}_{lines}_{what}"] for r in per_case
                                if r["distance"] == dist and r["occluded"] == occ]
                        loc[method].setdefault(lines, {}).setdefault(what, {}).setdefault(
                            "occluded" if occ else "clear", {})[str(dist)] = dataclasses.asdict(metrics.loc_stats(errs))
    loc["occlusion_share"] = {
        "mean": float(np.mean([r["occlusion_share"] for r in per_case if r["occluded"]] or [math.nan])),
        "min": float(np.min([r["occlusion_share"] for r in per_case if r["occluded"]] or [math.nan])),
        "max": float(np.max([r["occlusion_share"] for r in per_case if r["occluded"]] or [math.nan])),
    }
    loc["sphere_fit_share"] = {
        lines: float(np.mean([r.get(f"ours_{lines}_sphere", False) for r in per_case])) for lines in ("single", "multi")}
    loc["observe_ms_per_frame"] = float(np.mean([r["observe_ms"] / max(1, len(r["frames"]))
                                                 for r in ours_loc.values() if "observe_ms" in r]))
    res["loc"] = loc
    res["loc_cases"] = per_case
    return res
