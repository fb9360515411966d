"""Two builds of the sensor on the same tuning scans, side by side (issue 17).

`alacs-eval diagnose --loc --against OTHER_TWIN` runs a tuning world's five-stop scans
through this build's `alacs-twin process` and through another build's (one made from the
commit before a change, say), and prints what a change to the localizer did: within 20 mm,
within 2σ, misses at a confidence of 80 % or more, the approach error per distance and
occlusion, and every scan whose result moved.

The scans hold the second-pass stops that the localizer of their generation asked for. A
build whose second pass asks for other stops would see frames the scan lacks
(`follow_up_missing`), so each build renders those scans again itself (`alacs-twin generate
--only`, into a directory of its own beside the set) and is measured on its own renders.
The first pass's frames are the same for both: the scene, the light and the noise come from
the case's seed.

Like the rest of `diagnose`, it refuses the second world (docs/evaluation.md, "The second
world").
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from alacs_eval import diagnose, evaluate, twin
from alacs_eval.scans import Scan

BUILDS = ("against", "this build")
CHANGED_MM = 2.0  # an approach error that moved by more than this is listed


def _process_all(tw: Path, dirs: list[str], cfg: diagnose.Config, desc: str, extra: tuple[str, ...]) -> dict[str, dict]:
    """`process` by `tw` on `dirs`, every one of which must come back (else it is no alacs-twin)."""
    raw = twin.process(tw, dirs, cfg.jobs, desc, quiet=cfg.quiet, extra=extra)
    lost = [d for d in dirs if d not in raw]
    if lost:
        raise ValueError(f"{tw} process gave no result line for {len(lost)} of {len(dirs)} scans (is it alacs-twin?)")
    return raw


def _processed(cfg: diagnose.Config, tw: Path, tag: str, cases: list[dict], per_cell: int,
               both: tuple[str, ...]) -> tuple[dict[str, dict | None], int, int]:
    """Each case's errors by the build `tw` (None: no result); the cases whose second pass it
    moved are rendered again by that build first. Also: how many were, and the second-pass
    stops its results still lack (0 unless the renders went wrong)."""
    desc = f"{cfg.world}: {tag}"
    extra = both + cfg.process_args
    raw = _process_all(tw, [c["dir"] for c in cases], cfg, desc, extra)
    where = {c["case"]: c["dir"] for c in cases}
    moved = [c["case"] for c in cases if int(raw[c["dir"]].get("follow_up_missing", 0)) > 0]
    if moved:
        again = cfg.work / f"{cfg.world}-{cfg.seed}" / ("loc-" + tag.replace(" ", "-"))
        if again.exists():
            shutil.rmtree(again)
        again.mkdir(parents=True)
        cmd = [str(tw), "generate", "--set", "loc", "--out", str(again), "--world", cfg.world, "--count",
               str(per_cell), "--seed", str(cfg.seed), "--jobs", str(cfg.jobs), "--only", ",".join(moved), *both]
        twin.run_lines(cmd, len(moved), f"{desc}: second passes rendered again", cfg.quiet)
        where.update({m: str(again / m) for m in moved})
        raw.update(_process_all(tw, [where[m] for m in moved], cfg, desc, extra))
    out = {name: diagnose.estimate_errors(Scan.load(d), raw[d].get("multi", {})) for name, d in where.items()}
    lacking = sum(int(raw[d].get("follow_up_missing", 0)) for d in where.values())
    return out, len(moved), lacking


def summary(rows: dict[str, dict | None]) -> dict[str, Any]:
    """Within 20 mm (of all scans: no result is a miss), within 2σ (of the results), misses at
    80 % confidence or more, no result, and the mean approach error per cell ("d1000_occ1": the
    case names' prefix)."""
    res = {k: r for k, r in rows.items() if r is not None}
    cells = {}
    for occ in (0, 1):
        for dist in evaluate.DISTANCES:
            sel = [r["approach"] for k, r in res.items() if k.startswith(f"d{dist}_occ{occ}_")]
            cells[f"{'occluded' if occ else 'clear'} {dist}"] = float(np.mean(sel)) if sel else math.nan
    return {"scans": len(rows), "no_result": len(rows) - len(res),
            "within20": sum(1 for r in res.values() if r["approach"] <= diagnose.LOC_MISS_MM),
            "within2sigma": sum(1 for r in res.values() if r["approach"] <= 2.0 * r["sigma"]),
            "confident_misses": sum(1 for r in res.values()
                                    if r["approach"] > diagnose.LOC_MISS_MM and r["confidence"] >= 80.0),
            "cells": cells}


def changed(before: dict[str, dict | None], after: dict[str, dict | None]) -> list[dict[str, Any]]:
    """The cases whose approach error moved by more than CHANGED_MM, or that gained or lost a
    result, in case order."""
    out = []
    for k in sorted(before):
        a, b = before[k], after.get(k)
        if (a is None) != (b is None) or (a is not None and b is not None
                                          and abs(a["approach"] - b["approach"]) > CHANGED_MM):
            out.append({"case": k, "against": a, "this build": b})
    return out


def run(cfg: diagnose.Config, against: Path, per_cell: int = 40) -> dict[str, Any]:
    """The tuning world's scans through `against` and through cfg.twin (this build)."""
    cases, both, _ = diagnose.loc_cases(cfg, per_cell)
    rows, rendered, lacking = {}, {}, {}
    for tag, tw in zip(BUILDS, (against, cfg.twin)):
        rows[tag], rendered[tag], lacking[tag] = _processed(cfg, tw, tag, cases, per_cell, both)
    return {"world": cfg.world, "seed": cfg.seed, "twins": {BUILDS[0]: str(against), BUILDS[1]: str(cfg.twin)},
            "process_args": list(both + cfg.process_args), "rendered_again": rendered, "stops_lacking": lacking,
            "summary": {tag: summary(rows[tag]) for tag in BUILDS},
            "changed": changed(rows[BUILDS[0]], rows[BUILDS[1]])}


def _case_text(r: dict | None) -> str:
    if r is None:
        return "no result"
    return f"{r['approach']:.1f} mm (σ {r['sigma']:.1f}, {r['confidence']:.0f} %)"


def text(res: dict[str, Any]) -> str:
    s = res["summary"]
    args = " ".join(res["process_args"]) or "defaults"
    L = [f"{res['world']}, seed {res['seed']}: {s[BUILDS[0]]['scans']} scans ({args}); against "
         f"{res['twins'][BUILDS[0]]}, this build {res['twins'][BUILDS[1]]}",
         "second passes rendered again (the build asked for stops the scans lack): "
         + ", ".join(f"{tag} {res['rendered_again'][tag]}" for tag in BUILDS)]
    for tag in BUILDS:
        x = s[tag]
        L.append(f"{tag:>10}: within 20 mm {x['within20']} of {x['scans']}, within 2σ {x['within2sigma']} of "
                 f"{x['scans'] - x['no_result']} results, beyond 20 mm at confidence >= 80 % "
                 f"{x['confident_misses']}, no result {x['no_result']}")
    L.append("approach error, mean (mm), against -> this build:")
    L += [f"  {cell}: {s[BUILDS[0]]['cells'][cell]:.2f} -> {s[BUILDS[1]]['cells'][cell]:.2f}"
          for cell in s[BUILDS[0]]["cells"]]
    lacking = [f"{tag} {n}" for tag, n in res["stops_lacking"].items() if n]
    if lacking:
        L.append("second-pass stops still lacking after rendering again (these figures are not the builds' own): "
                 + ", ".join(lacking))
    L.append(f"scans whose approach error moved by more than {CHANGED_MM:g} mm, or that gained or lost a result: "
             f"{len(res['changed'])}")
    L += [f"  {c['case']}: {_case_text(c[BUILDS[0]])} -> {_case_text(c[BUILDS[1]])}" for c in res["changed"]]
    return "\n".join(L)
