"""A second exposure in sun: a prototype measured on a tuning world (issue 17; not the product).

The metering brings the 99th percentile of the ROI's red to 220 DN (docs/lle.md, "Metering
and laser-off subtraction"). In a sunlit cluster that percentile is often another fruit's
skin or a leaf in full sun, and the target's own lit rows, in part shade, get a shorter
exposure than they could bear: its line is then a few DN over the noise. A longer exposure
alone clips the brightest skin, where the line is lost; a second laser frame at a longer
exposure, beside the metered one, would keep both.

`alacs-eval diagnose --loc --exposures 1,2,4` takes a tuning world's occluded scans in sun
(stack.sunlit_occluded) and, at each first-pass stop, renders the laser frame and a
laser-off frame again from the scene (`alacs-twin render`, the stop's ROI and gain) at each
factor of the stop's metered exposure, runs `alacs_lle --laser-off` on each pair, and counts
the target's visible, laser-lit rows (the truth's flags 0) on which the LLE has a valid
sample within ON_TARGET_PX of the truth. It prints the share found at each factor and for
the metered frame together with each other one (a row found in either), over all the scans
and over those the stored scans' own localization puts beyond 20 mm. Every factor of a stop
takes the same noise seeds, so the factors differ by the exposure alone. The second world is
refused, as by the rest of `diagnose`.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from tqdm import tqdm

from alacs_eval import diagnose, twin, worlds
from alacs_eval.scans import Scan
from alacs_eval.stack import sunlit_occluded

ON_TARGET_PX = worlds.ON_TARGET_PX
# Noise seeds of the renders (laser frame, laser-off frame): far from the generator's own.
SEED_ON, SEED_OFF = 7001, 7002


def parse_factors(text: str) -> tuple[float, ...]:
    """'1,2,4' -> (1.0, 2.0, 4.0); the metered exposure (1) first, each within 0.1..16."""
    try:
        factors = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--exposures wants factors such as 1,2,4, got {text!r}") from None
    if not factors or factors[0] != 1.0 or len(set(factors)) != len(factors) \
            or not all(0.1 <= f <= 16.0 for f in factors) or len(factors) < 2:
        raise ValueError(f"--exposures wants 1 first, then other factors within 0.1..16, got {text!r}")
    return factors


def target_rows(truth_csv: Path, target_id: int, roi_x: int, roi_y: int) -> dict[int, float]:
    """The target's visible, laser-lit rows of a render's truth: row -> column, in the ROI's pixels."""
    rows = {}
    with truth_csv.open() as f:
        for r in csv.DictReader(f):
            if int(r["apple_id"]) == target_id and int(r["flags"]) == 0:
                rows[int(r["row"]) - roi_y] = float(r["column_px"]) - roi_x
    return rows


def found_rows(lle_json: dict, truth: dict[int, float]) -> set[int]:
    """The truth's rows on which `alacs_lle` has a valid sample within ON_TARGET_PX."""
    return {r["row"] for r in lle_json["rows"]
            if r["valid"] and r["column"] is not None and r["row"] in truth
            and abs(truth[r["row"]] - r["column"]) <= ON_TARGET_PX}


def _stops(scan_dir: Path) -> list[dict]:
    """The first pass's laser frames of a scan (tag 'stop')."""
    manifest = json.loads((scan_dir / "manifest.json").read_text())
    return [f for f in manifest["frames"] if f.get("laser_on") and f.get("tag") == "stop"]


def _one_stop(tw: Path, lle: Path, scan_dir: Path, frame: dict, factors: tuple[float, ...],
              target_id: int, tmp: Path) -> dict[float, Any]:
    scene = scan_dir / "truth" / "scene.json"
    x, y, w, h = (int(v) for v in frame["crop_px"])
    gain = float(frame.get("analogue_gain", 1.0))
    gain_db = 20.0 * math.log10(gain) if gain > 0 else 0.0
    out: dict[float, Any] = {}
    truth: dict[int, float] | None = None
    # The truth does not change with the exposure (the slide stands still): the first render
    # writes it, and it is read once.
    for k in factors:
        stem = tmp / f"{scan_dir.name}_{frame['index']}_{k:g}"
        common = [str(tw), "render", "--scene", str(scene), "--slide", repr(float(frame["slide_mm"])),
                  "--exposure-us", str(max(1, round(int(frame["exposure_us"]) * k))), "--gain-db", repr(gain_db),
                  "--roi", f"{x},{y},{w},{h}"]
        subprocess.run(common + ["--frame", str(SEED_ON), "--out", f"{stem}_on.png"]
                       + (["--truth", f"{stem}.csv"] if truth is None else []), check=True, capture_output=True)
        subprocess.run(common + ["--laser", "0", "--frame", str(SEED_OFF), "--out", f"{stem}_off.png"],
                       check=True, capture_output=True)
        subprocess.run([str(lle), f"{stem}_on.png", "--laser-off", f"{stem}_off.png", "--json", f"{stem}.json",
                        "--overlay", "none"], check=True, capture_output=True)
        if truth is None:
            truth = target_rows(Path(f"{stem}.csv"), target_id, x, y)
        out[k] = found_rows(json.loads(Path(f"{stem}.json").read_text()), truth)
    out["lit"] = len(truth or {})
    return out


def run(cfg: diagnose.Config, per_cell: int, factors: tuple[float, ...]) -> dict[str, Any]:
    diagnose.refuse_second_world(cfg.world)
    lle = cfg.twin.parent.parent / "lle" / "alacs_lle"
    if not lle.exists():
        raise ValueError(f"--exposures needs alacs_lle beside alacs-twin ({lle})")
    cases, both, _ = diagnose.loc_cases(cfg, per_cell)
    sel = sunlit_occluded(cases)
    if not sel:
        raise ValueError("no occluded scan in sun in this set")
    stored = twin.process(cfg.twin, [c["dir"] for c in sel], cfg.jobs, f"{cfg.world}: the stored scans",
                          quiet=cfg.quiet, extra=both + cfg.process_args)
    missed = set()
    for c in sel:
        e = stored.get(c["dir"], {}).get("multi", {})
        errs = diagnose.estimate_errors(Scan.load(c["dir"]), e)
        if errs is None or errs["approach"] > diagnose.LOC_MISS_MM:
            missed.add(c["dir"])
    work = [(Path(c["dir"]), f, int(Scan.load(c["dir"]).target_id)) for c in sel for f in _stops(Path(c["dir"]))]
    per_scan: dict[str, dict[str, int]] = {}
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(max(1, cfg.jobs)) as ex, \
            tqdm(total=len(work), desc=f"{cfg.world}: stops rendered at {len(factors)} exposures", unit="stop",
                 disable=cfg.quiet, leave=False) as bar:
        futures = [(d, ex.submit(_one_stop, cfg.twin, lle, d, f, factors, t, Path(tmp))) for d, f, t in work]
        for d, fut in futures:
            res = fut.result()
            acc = per_scan.setdefault(str(d), {"lit": 0})
            acc["lit"] += res["lit"]
            for k in factors:
                acc[f"x{k:g}"] = acc.get(f"x{k:g}", 0) + len(res[k])
                if k != 1.0:
                    acc[f"x1+x{k:g}"] = acc.get(f"x1+x{k:g}", 0) + len(res[1.0] | res[k])
            bar.update(1)

    def total(dirs: list[str]) -> dict[str, int]:
        out: dict[str, int] = {}
        for d in dirs:
            for key, v in per_scan.get(d, {}).items():
                out[key] = out.get(key, 0) + v
        return out

    dirs = [c["dir"] for c in sel]
    return {"world": cfg.world, "seed": cfg.seed, "factors": list(factors), "scans": len(sel), "stops": len(work),
            "all": total(dirs), "missed_scans": sorted(Path(d).name for d in missed),
            "missed": total([d for d in dirs if d in missed]),
            "per_scan": {Path(d).name: v for d, v in per_scan.items()}}


def text(res: dict[str, Any]) -> str:
    keys = [f"x{k:g}" for k in res["factors"]] + [f"x1+x{k:g}" for k in res["factors"][1:]]

    def line(label: str, t: dict[str, int]) -> str:
        lit = t.get("lit", 0)
        shares = ", ".join(f"{k} {100.0 * t.get(k, 0) / lit:.1f} %" if lit else f"{k} –" for k in keys)
        return f"  {label}: {lit} lit rows; found {shares}"

    L = [f"{res['world']}, seed {res['seed']}: the occluded scans in sun ({res['scans']} scans, {res['stops']} "
         f"first-pass stops), each stop rendered again at the factors {', '.join(f'{k:g}' for k in res['factors'])} "
         f"of its metered exposure; the target's visible, laser-lit rows on which alacs_lle (laser-off "
         f"subtracted) has a valid sample within {ON_TARGET_PX:g} px (x1+xK: in either frame):",
         line("all scans", res["all"]),
         line(f"the stored scans beyond 20 mm ({len(res['missed_scans'])}: {' '.join(res['missed_scans'])})",
              res["missed"])]
    return "\n".join(L)
