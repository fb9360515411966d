"""Stacked frames in sun: a prototype measured on a tuning world (issue 17; not the product).

In direct sun the laser's excess over sunlit skin is a few DN against a shot noise of
1.5-5 DN (docs/lle.md, "What remains lost in sun"), and the misses the tuning worlds still
have in sun are targets whose lit rows the LLE does not find. Two ways to give each
decision more light, neither of them built into the sensor:

- several frames of each stop averaged (a stop-and-go scan in sun: more frame slots a stop);
- the sensor at a lower analogue gain, the exposure lengthened to keep the same DN (more
  electrons a frame for no more frames, while the full well allows).

`alacs-eval diagnose --loc --stack N [--stack-gain-db G]` takes a tuning world's occluded
scans in sun (the set's `lighting`), renders every frame of each again from its scene
(`alacs-twin render --average N [--gain-db G]`), once with one frame and once with N frames
averaged and rounded to 8 bits, and runs `alacs-twin process` on the stored scans and on
both sets. The two sets share their seeds (frame i takes noise seeds SEED_BASE +
SEED_STRIDE·i onwards and the first one's speckle), so the one-frame set is the control:
the N-frame set is it plus N - 1 more frames. The control differs from the stored scans in
its draw of noise and speckle (and in the gain, when given). The manifests are kept: the
replay serves the same frames at the same exposures, and the localizer sees the DN it saw.
The second pass's stops are those the stored scans were rendered with; where a set's first
pass asks for others, the replay serves the nearest recorded frame, and the text counts
those stops (per set and per scan). The second world is refused, as by the rest of
`diagnose`.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from alacs_eval import diagnose, evaluate, twin
from alacs_eval.scans import Scan, target_truth

# Noise seeds of the renders: frame i of a scan takes SEED_BASE + 100 * i onwards, far from
# the generator's own (its frame indices), so that no render repeats a stored frame's noise.
SEED_BASE = 5000
SEED_STRIDE = 100
MAX_FRAMES = 64  # `alacs-twin render --average`'s limit
# What the renders depend on besides the source set and the arguments: this file's own
# rules (seeds, the exposure's scaling), so that a change to them renders the sets again.
VERSION = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]


def sunlit_occluded(cases: list[dict]) -> list[dict]:
    """The occluded cases whose scene is in direct sun (the set's `lighting`, else the
    scan's note, which names the light first)."""
    def sun(c: dict) -> bool:
        return c["lighting"] == "sun" if "lighting" in c else Scan.load(c["dir"]).note.startswith("sun ")
    return [c for c in cases if c["occluded"] and sun(c)]


def render_jobs(src: Path, dst: Path, frames: int, gain_db: float | None) -> list[list[str]]:
    """The `alacs-twin render` arguments (after the binary) for every frame of scan `src`,
    written over the copies in `dst`."""
    manifest = json.loads((src / "manifest.json").read_text())
    scene_file = src / manifest["scan"].get("truth", "truth/scene.json")
    scene_gain = float(json.loads(scene_file.read_text())["sensor"]["gain_db"])
    # A lower gain wants a longer exposure for the same DN (the manifest keeps the recorded one).
    scale = 10.0 ** ((scene_gain - gain_db) / 20.0) if gain_db is not None else 1.0
    jobs = []
    for i, f in enumerate(manifest["frames"]):
        start = float(f.get("slide_start_mm", f["slide_mm"]))
        end = float(f.get("slide_end_mm", f["slide_mm"]))
        if start != end:
            # Frames of a moving slide are not a stop's: nothing to stack.
            raise ValueError(f"{src.name}: frame {i} was exposed while the slide moved")
        args = ["render", "--scene", str(scene_file), "--slide", repr(start), "--slide-end", repr(end),
                "--exposure-us", str(max(1, round(int(f["exposure_us"]) * scale))),
                "--laser", "1" if f["laser_on"] else "0",
                "--frame", str(SEED_BASE + SEED_STRIDE * int(f.get("index", i))), "--average", str(frames),
                "--out", str(dst / f["file"])]
        if "crop_px" in f:
            args += ["--roi", ",".join(str(int(v)) for v in f["crop_px"])]
        if gain_db is not None:
            args += ["--gain-db", repr(gain_db)]
        jobs.append(args)
    return jobs


def render_set(tw: Path, cases: list[dict], out: Path, frames: int, gain_db: float | None, jobs: int,
               quiet: bool) -> list[str]:
    """The scans of `cases` rendered again into `out` (reused when rendered with the same
    arguments from the same source set); their directories, in the cases' order."""
    signature = {"frames": frames, "gain_db": gain_db, "version": VERSION,
                 "cases": [c["dir"] for c in cases],
                 "source": json.loads((Path(cases[0]["dir"]).parent / "args.json").read_text()) if cases else {}}
    dirs = [str(out / Path(c["dir"]).name) for c in cases]
    if twin.reuse_or_clear(out, signature, "stack.json"):
        return dirs
    work = []
    for c, d in zip(cases, dirs):
        shutil.copytree(c["dir"], d)
        work += render_jobs(Path(c["dir"]), Path(d), frames, gain_db)

    def run(args: list[str]) -> None:
        subprocess.run([str(tw), *args], check=True, capture_output=True, text=True)

    with ThreadPoolExecutor(max(1, jobs)) as ex, \
            tqdm(total=len(work), desc=f"rendering, {frames} frame(s) averaged", unit="frame", disable=quiet,
                 leave=False) as bar:
        for _ in ex.map(run, work):
            bar.update(1)
    twin.sign(out, signature, "stack.json")
    return dirs


def _errors(raw: dict[str, dict], dirs: list[str], cases: list[dict]) -> list[dict]:
    rows = []
    for c, d in zip(cases, dirs):
        _, _, approach = target_truth(Scan.load(d))
        r = raw.get(d, {})
        e = r.get("multi", {})
        ok = bool(e.get("ok"))
        rows.append({"case": Path(d).name, "distance": int(c["distance_mm"]), "ok": ok,
                     "approach": float(np.linalg.norm(np.asarray(e["approach_mm"]) - approach)) if ok else math.nan,
                     "sigma": float(e["sigma_mm"]) if ok else math.nan,
                     "confidence": float(e["confidence_pct"]) if ok else 0.0,
                     "lines": int(e.get("lines_used", 0)) if ok else 0,
                     "stops_missing": int(r.get("follow_up_missing", 0))})
    return rows


def summary(rows: list[dict]) -> dict[str, Any]:
    """Mean approach error per distance, the share within 20 mm (no result counts as
    beyond), within 2σ, the misses at confidence >= 80 %, and second-pass stops lacking."""
    res = [x for x in rows if x["ok"]]
    cells = {}
    for dist in evaluate.DISTANCES:
        sel = [x["approach"] for x in res if x["distance"] == dist]
        cells[dist] = float(np.mean(sel)) if sel else math.nan
    return {"scans": len(rows), "results": len(res), "cells": cells,
            "mean": float(np.mean([x["approach"] for x in res])) if res else math.nan,
            "within20": sum(1 for x in res if x["approach"] <= diagnose.LOC_MISS_MM),
            "within2sigma": sum(1 for x in res if x["approach"] <= 2.0 * x["sigma"]),
            "confident_misses": sum(1 for x in res
                                    if x["approach"] > diagnose.LOC_MISS_MM and x["confidence"] >= 80.0),
            "stops_missing": sum(x["stops_missing"] for x in rows)}


def run(cfg: diagnose.Config, per_cell: int, frames: int, gain_db: float | None = None) -> dict[str, Any]:
    """The tuning world's occluded sunlit scans: stored, rendered again with one frame, and
    with `frames` frames averaged (at `gain_db` when given)."""
    if not 2 <= frames <= MAX_FRAMES:
        raise ValueError(f"--stack wants 2..{MAX_FRAMES} frames")
    if gain_db is not None and not 0.0 <= gain_db <= 48.0:
        raise ValueError("--stack-gain-db wants 0..48 dB")
    cases, both, loc_dir = diagnose.loc_cases(cfg, per_cell)
    sel = sunlit_occluded(cases)
    if not sel:
        raise ValueError("no occluded scan in sun in this set")
    gain = "" if gain_db is None else f"-gain{gain_db:g}"
    base = cfg.work / f"{cfg.world}-{cfg.seed}" / "stack"
    sets = {"stored": [c["dir"] for c in sel]}
    for n in (1, frames):
        sets[f"{n} frame{'s' if n > 1 else ''}"] = render_set(cfg.twin, sel, base / f"{n}{gain}", n, gain_db,
                                                              cfg.jobs, cfg.quiet)
    rows = {}
    for label, dirs in sets.items():
        raw = twin.process(cfg.twin, dirs, cfg.jobs, f"{cfg.world}: {label}", quiet=cfg.quiet,
                           extra=both + cfg.process_args)
        rows[label] = _errors(raw, dirs, sel)
    return {"world": cfg.world, "seed": cfg.seed, "frames": frames, "gain_db": gain_db, "work": str(base),
            "source": str(loc_dir), "process_args": list(both + cfg.process_args),
            "sets": {label: summary(r) for label, r in rows.items()}, "rows": rows}


def text(res: dict[str, Any]) -> str:
    gain = "the scenes' gain" if res["gain_db"] is None else f"the sensor at {res['gain_db']:g} dB"
    L = [f"{res['world']}, seed {res['seed']}: the occluded scans in sun, rendered again ({gain}; the stored "
         f"scans as generated), approach error mean (mm) per distance, within 20 mm, within 2σ, beyond 20 mm at "
         f"confidence >= 80 %, second-pass stops the scans lack (served by the nearest frame):"]
    dists = " / ".join(f"{d / 1000:.1f}" for d in evaluate.DISTANCES)
    for label, s in res["sets"].items():
        cells = " / ".join(f"{v:.1f}" for v in s["cells"].values())
        L.append(f"  {label:>10}: {dists} m: {cells}; all {s['mean']:.2f}; within 20 mm {s['within20']} of "
                 f"{s['scans']}; within 2σ {s['within2sigma']} of {s['results']}; confident misses "
                 f"{s['confident_misses']}; stops lacking {s['stops_missing']}")
    labels = list(res["rows"])
    cases = res["rows"][labels[0]]
    worse = [i for i in range(len(cases))
             if any(not res["rows"][l][i]["ok"] or res["rows"][l][i]["approach"] > 10.0 for l in labels)]
    if worse:
        L += ["", "scans beyond 10 mm in any set (approach mm, lines, confidence %, second-pass stops lacking):"]
        for i in worse:
            cols = "; ".join(f"{l} {res['rows'][l][i]['approach']:.1f} mm, {res['rows'][l][i]['lines']} lines, "
                             f"{res['rows'][l][i]['confidence']:.0f} %, {res['rows'][l][i]['stops_missing']}"
                             for l in labels)
            L.append(f"  {cases[i]['case']}: {cols}")
    return "\n".join(L)
