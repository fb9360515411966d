"""Where the LLE loses on a tuning world, case by case (issue 17).

`alacs-eval diagnose --world benchmark-hard --seed 3` generates (or reuses) a world's
single LLE frames, runs our pipeline on them as `worlds` does (the localizer's 3D-gated
samples), and prints what the aggregates of `worlds` hide:

- the mean per light, and the frames whose worst central segment is beyond 0.6 px;
- the worst frames, with the generator's note (light, distance, neighbours, occlusion);
- the row error against the distance (rows) to the nearest end of the kept run: partial
  occlusion and laser shadow bias the rows next to a gap;
- why the target's visible rows were not found: no sample at all, a sample the 3D gate
  dropped, one marked at an occluding edge (kEdge) or rejected by the fit.

It works on the worlds parameters may be tuned on only: the second world (`holdout`) is
refused, because its cases are not to be looked at while a parameter is chosen
(docs/evaluation.md "The second world"). Extra `alacs-twin process` options (for example
`--lle-subtracted-line-pct 20`) go after `--`, to compare settings on the same frames.
`--matched-filter` measures a prototype detector against our kept samples (not the product).
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from alacs_eval import evaluate, metrics, twin, worlds
from alacs_eval.scans import Scan, target_truth

TUNING_WORLDS = ("benchmark", "benchmark-hard")
WORST_PX = 0.6  # the worst-case bound for one frame
GAP_BINS = (1, 2, 3, 4, 6, 8, 12, 10**9)
# LaserLine RowStatus, as `alacs-twin process --rows` writes it (image/lle.h).
STATUS = {0: "a sample the 3D gate dropped", 1: "rejected by the line's fit", 2: "another segment, dropped",
          3: "at an occluding edge (kEdge)"}


@dataclasses.dataclass
class Config:
    world: str
    seed: int
    count: int
    work: Path
    twin: Path
    jobs: int = 2
    process_args: tuple[str, ...] = ()
    # `alacs-twin generate` options that change the scans themselves (the second pass's
    # stops are rendered where the generator's localizer asks for them), as (name, value)
    # pairs, e.g. (("follow-up-unseen-max-stops", "16"),); they go to `process` too.
    generate_args: tuple[tuple[str, str], ...] = ()
    worst: int = 10
    quiet: bool = False
    # How a row the localizer keeps twice is read (evaluate.kept_rows): evaluate.BY_LINE or
    # evaluate.BY_ROUGH; the other reading's means are printed beside.
    read: str = "line"


# The readings of a row the localizer keeps twice (evaluate.kept_rows), as the text names them.
READINGS = {"line": "the LLE's line", "rough": "the sample nearest the rough position"}


def _gap_distance(row: int, rows: set[int]) -> int:
    """Rows from `row` to the nearest row of the run without a sample (1: next to a gap)."""
    k = 1
    while (row - k) in rows and (row + k) in rows and k <= GAP_BINS[-2]:
        k += 1
    return k


def _miss_reason(row: int, column: float, samples: dict[int, list]) -> str:
    near = [s for s in samples.get(row, []) if abs(s[1] - column) <= 2.0]
    if near:
        return STATUS.get(int(near[0][3]) if len(near[0]) > 3 else -1, "a sample not kept")
    return "only another surface's sample" if samples.get(row) else "no sample"


# Where a measured row's kept sample came from (evaluate.kept_rows): the LLE's line, or
# another segment that passed the localizer's 3D gate (another surface, or the fruit where a
# leaf made the line).
SOURCES = ("the LLE's line", "another segment")


def _line_on(raw: dict, scan: Scan, target_truth: np.ndarray) -> str:
    """What the LLE's own line (its valid rows, what `alacs_lle` reports) lies on: the
    target's (the worlds' measure: at least half of its visible rows within 2 px), a
    fragment of it, a neighbour's, another surface (leaf, branch, backdrop), or no line."""
    if len(metrics.visible_rows(target_truth)) < metrics.MIN_VISIBLE_ROWS:
        return "nothing to find"
    if worlds._line_alone(raw, target_truth) >= 0.5:
        return "the target"
    line = worlds.line_columns(raw).items()
    if not line:
        return "no line"
    frame = next(f for f in scan.frames if f.laser_on)
    on: Counter = Counter()
    for a in scan.truth_scene()["apples"]:
        vis = metrics.visible_rows(target_truth if a["id"] == scan.target_id else scan.truth_rows(frame, a["id"]))
        cols = {int(r): float(c) for r, c in zip(vis["row"], vis["column"])}
        on["a fragment of the target" if a["id"] == scan.target_id else "a neighbour"] += sum(
            1 for r, c in line if r in cols and abs(cols[r] - c) <= 2.0)
    best, n = on.most_common(1)[0] if on else ("", 0)
    return best if 2 * n >= len(line) else "another surface"


def refuse_second_world(world: str) -> None:
    if world not in TUNING_WORLDS:
        raise ValueError(f"diagnose looks at tuning worlds only ({', '.join(TUNING_WORLDS)}); "
                         f"'{world}' is kept out of tuning (docs/evaluation.md \"The second world\")")


def _lle_set(cfg: Config) -> tuple[list[dict], list[str], dict[str, dict]]:
    """The world's LLE frames (generated or reused) and `alacs-twin process --rows` on them."""
    refuse_second_world(cfg.world)
    out = cfg.work / f"{cfg.world}-{cfg.seed}" / "lle"
    cases = twin.generate(cfg.twin, out, "lle", {"world": cfg.world, "count": cfg.count, "seed": cfg.seed,
                                                 "jobs": cfg.jobs},
                          cfg.count, f"{cfg.world}: generating", cfg.quiet, sources=worlds.WORLD_SOURCES)
    dirs = [c["dir"] for c in cases]
    step, th = evaluate.DEFAULT_COMBO
    raw = twin.process(cfg.twin, dirs, cfg.jobs, f"{cfg.world}: our LLE", rows=True, step=step, threshold=th,
                       quiet=cfg.quiet, extra=cfg.process_args)
    return cases, dirs, raw


# A prototype, not the product: a matched filter across the line on the laser-off-subtracted
# red, with hysteresis along it (docs/lle.md, "The sunlit line through a matched filter"). The kernel: a
# Gaussian of the line's width (σ 1.5 px) less its mean over ±8 px, so that a slope of the
# ambient left by the subtraction does not count; each row's best column, its response over
# the row's robust σ (MAD); rows at MF_SEED σ or more start the line, rows at MF_GROW σ or
# more join it when a row within 2 of them, already in, lies within 2 px per row apart.
MF_SIGMA_PX, MF_HALF_PX, MF_SEED, MF_GROW = 1.5, 8, 5.0, 3.0


def _mf_columns(diff: np.ndarray) -> dict[int, int]:
    """Row (in `diff`) -> column of the matched filter's line (see above)."""
    k = np.arange(-MF_HALF_PX, MF_HALF_PX + 1)
    g = np.exp(-0.5 * (k / MF_SIGMA_PX) ** 2)
    g -= g.mean()
    resp = np.array([np.convolve(row, g[::-1], mode="same") for row in diff])
    sigma = 1.4826 * np.median(np.abs(resp - np.median(resp, axis=1, keepdims=True)), axis=1) + 1e-9
    cols = np.argmax(resp, axis=1)
    z = resp[np.arange(len(cols)), cols] / sigma
    taken = z >= MF_SEED
    while True:
        grown = taken.copy()
        for y in np.nonzero((z >= MF_GROW) & ~taken)[0]:
            grown[y] = any(0 <= y + dy < len(cols) and taken[y + dy] and abs(int(cols[y + dy]) - int(cols[y])) <= 2 * abs(dy)
                           for dy in (-2, -1, 1, 2))
        if (grown == taken).all():
            return {int(y): int(cols[y]) for y in np.nonzero(taken)[0]}
        taken = grown


def matched_filter(cfg: Config) -> dict[str, Any]:
    """Per light: the visible rows of the target that our kept samples and the prototype each
    put within 2 px of the truth, on the frames whose laser-off frame was subtracted."""
    cases, dirs, raw = _lle_set(cfg)
    out: dict[str, Counter] = {}
    for c in cases:
        d = c["dir"]
        s = Scan.load(d)
        on = next(f for f in s.frames if f.laser_on)
        off = [f for f in s.frames if not f.laser_on and f.exposure_us == on.exposure_us]
        if not off or not raw.get(d, {}).get("laser_off_subtracted") or s.roi is None:
            continue
        red = lambda f: s.region(f, s.roi)[:, :, 0].astype(float)  # noqa: E731
        x0, y0 = s.roi[0], s.roi[1]
        mf = {y0 + y: x0 + x for y, x in _mf_columns(red(on) - red(off[-1])).items()}
        kept = {r: col for r, (col, _) in evaluate.kept_rows(raw[d].get("frames", [{}])[0]).items()}
        n = out.setdefault(c["lighting"], Counter())
        for tr in metrics.visible_rows(s.truth_rows(on, s.target_id)):
            r = int(round(tr["row"]))
            ours = bool(r in kept and abs(kept[r] - tr["column"]) <= 2.0)
            proto = bool(r in mf and abs(mf[r] - tr["column"]) <= 2.0)
            n.update(rows=1, ours=int(ours), proto=int(proto), either=int(ours or proto),
                     proto_off=int(r in mf and not proto))
    return {"world": cfg.world, "seed": cfg.seed, "lights": {k: dict(v) for k, v in sorted(out.items())}}


def text_matched_filter(res: dict[str, Any]) -> str:
    L = [f"{res['world']}, seed {res['seed']}: the target's visible rows within 2 px of the truth, frames with "
         f"the laser-off frame subtracted (a prototype matched filter against our kept samples; not the product)"]
    for light, n in res["lights"].items():
        pct = lambda k: 100.0 * n.get(k, 0) / max(1, n["rows"])  # noqa: E731
        L.append(f"  {light}: rows {n['rows']}, ours {pct('ours'):.1f} %, prototype {pct('proto'):.1f} %, "
                 f"either {pct('either'):.1f} %; the prototype's rows beyond 2 px {pct('proto_off'):.1f} %")
    return "\n".join(L)


def run(cfg: Config) -> dict[str, Any]:
    cases, dirs, raw = _lle_set(cfg)
    truths, notes, line_on = {}, {}, Counter()
    for d in dirs:
        s = Scan.load(d)
        truths[d] = s.truth_rows(next(f for f in s.frames if f.laser_on), s.target_id)
        notes[d] = s.note
        line_on[_line_on(raw.get(d, {}), s, truths[d])] += 1
    ours = evaluate._ours_lle(raw, truths, cfg.read)
    other_read = evaluate.BY_ROUGH if cfg.read == evaluate.BY_LINE else evaluate.BY_LINE
    other = evaluate._ours_lle(raw, truths, other_read)

    frames, by_light = [], {}
    gap_err: dict[int, list[float]] = {b: [] for b in GAP_BINS}
    missed: Counter = Counter()
    by_source: dict[str, list[float]] = {k: [] for k in SOURCES}
    visible = 0
    for c in cases:
        d = c["dir"]
        disp = ours[d]["disp"]
        finite = [v for v in disp.values() if math.isfinite(v)]
        frames.append({"case": c["case"], "lighting": c["lighting"], "worst": max(finite) if finite else math.nan,
                       "mean50": disp[50], "found80": ours[d]["cover"][80], "note": notes[d]})
        by_light.setdefault(c["lighting"], []).append(frames[-1])
        f = raw.get(d, {}).get("frames", [{}])[0]
        samples: dict[int, list] = {}
        for s in f.get("rows", []):
            samples.setdefault(int(s[0]), []).append(s)
        per_row = evaluate.kept_rows(f, cfg.read)
        kept = {r: col for r, (col, _) in per_row.items()}
        source = {r: SOURCES[0] if line else SOURCES[1] for r, (_, line) in per_row.items()}
        vis = metrics.visible_rows(truths[d])
        if len(vis) < 3:
            continue
        centre, half = 0.5 * (vis["row"][0] + vis["row"][-1]), 0.5 * (vis["row"][-1] - vis["row"][0])
        keys = set(kept)
        for row, col in zip(vis["row"], vis["column"]):
            r = int(round(row))
            if r in kept:
                g = _gap_distance(r, keys)
                gap_err[next(b for b in GAP_BINS if g <= b)].append(abs(kept[r] - col))
                by_source[source[r]].append(abs(kept[r] - col))
            if abs(row - centre) <= 0.8 * half + 1e-9:
                visible += 1
                if r not in kept:
                    missed[_miss_reason(r, float(col), samples)] += 1
    frames.sort(key=lambda x: -x["worst"] if math.isfinite(x["worst"]) else math.inf)
    return {
        "world": cfg.world, "seed": cfg.seed, "frames": len(frames), "process_args": list(cfg.process_args),
        "segments": {s: float(np.nanmean([ours[d]["disp"][s] for d in dirs])) for s in metrics.SEGMENTS},
        "read": cfg.read, "other_read": other_read,
        "other": {s: float(np.nanmean([other[d]["disp"][s] for d in dirs])) for s in metrics.SEGMENTS},
        "other_worst": max((v for d in dirs for v in other[d]["disp"].values() if math.isfinite(v)), default=math.nan),
        "found80": metrics.mean_found(ours[d]["cover"][80] for d in dirs),
        "no_rows_to_find": sum(not metrics.has_rows_to_find(truths[d]) for d in dirs),
        "beyond": sum(1 for x in frames if math.isfinite(x["worst"]) and x["worst"] > WORST_PX),
        "by_light": {k: {"n": len(v), "mean50": float(np.nanmean([x["mean50"] for x in v])),
                         "found80": metrics.mean_found(x["found80"] for x in v)} for k, v in sorted(by_light.items())},
        "worst": frames[:cfg.worst],
        "gap": [{"upto": b, "n": len(v), "mean": float(np.mean(v)) if v else math.nan,
                 "beyond": int(np.sum(np.asarray(v) > WORST_PX))} for b, v in gap_err.items()],
        "missed": {"visible_rows": visible, **dict(missed.most_common())},
        "line_on": dict(line_on.most_common()),
        "by_source": {k: {"n": len(v), "beyond": int(np.sum(np.asarray(v) > WORST_PX)),
                          "px_rows_beyond": float(np.sum([e for e in v if e > WORST_PX]))}
                      for k, v in by_source.items()},
    }


def text(res: dict[str, Any]) -> str:
    f2 = lambda x: "–" if not math.isfinite(x) else f"{x:.3f}"  # noqa: E731
    args = " ".join(res["process_args"]) or "defaults"
    L = [f"{res['world']}, seed {res['seed']}: {res['frames']} LLE frames ({args}); a row kept twice read by "
         f"{READINGS[res['read']]}",
         "mean per central segment (px): " + " ".join(f"{s}% {f2(v)}" for s, v in res["segments"].items()),
         f"rows found (central 80 %): {100 * res['found80']:.1f} % (frames with fewer than "
         f"{metrics.MIN_VISIBLE_ROWS} visible rows of the target, left out: {res['no_rows_to_find']}); "
         f"frames whose worst segment is beyond "
         f"{WORST_PX} px: {res['beyond']}",
         f"read by {READINGS[res['other_read']]} instead (px): "
         + " ".join(f"{s}% {f2(v)}" for s, v in res["other"].items()) + f"; worst frame {f2(res['other_worst'])}",
         "", "by light:"]
    L += [f"  {k}: n {v['n']}, mean at 50 % {f2(v['mean50'])} px, found {100 * v['found80']:.1f} %"
          for k, v in res["by_light"].items()]
    L += ["", "worst frames:"]
    L += [f"  {x['case']} worst {f2(x['worst'])} px, at 50 % {f2(x['mean50'])}, found {100 * x['found80']:.0f} %: "
          f"{x['note']}" for x in res["worst"]]
    L += ["", "row error against the distance to the kept run's nearest gap (rows):"]
    lo = 1
    for g in res["gap"]:
        label = f"{lo}" if g["upto"] == lo else (f"{lo}-{g['upto']}" if g["upto"] < 10**9 else f">={lo}")
        L.append(f"  {label:>6}: n {g['n']:6d}, mean {f2(g['mean'])} px, beyond {WORST_PX} px: {g['beyond']}")
        lo = g["upto"] + 1
    L += ["", f"rows measured, by where their kept sample came from (beyond {WORST_PX} px: rows, px summed):"]
    L += [f"  {k}: n {v['n']}, beyond {v['beyond']}, {v['px_rows_beyond']:.0f} px"
          for k, v in res["by_source"].items()]
    m = dict(res["missed"])
    total = m.pop("visible_rows")
    on = res["line_on"]
    L += ["", "the LLE's own line, before the 3D gate (what alacs_lle reports), lies on: "
          + ", ".join(f"{k} {n}" for k, n in on.items())
          + f" (the target's in {on.get('the target', 0)} of {sum(on.values()) - on.get('nothing to find', 0)} frames "
          "with something to find)"]
    L += ["", f"visible rows of the target (central 80 %): {total}; not found, by reason:"]
    L += [f"  {100 * n / max(total, 1):5.1f} %  {k}" for k, n in m.items()]
    return "\n".join(L)


# ---- localization ---------------------------------------------------------------------

LOC_MISS_MM = metrics.TOLERANCE_MM  # the end effector's tolerance: a miss beyond it is what the arm feels


def _what_was_fitted(centre: np.ndarray, scene: dict, target_id: int) -> str:
    """Which apple of the scene the fitted centre is nearest (within its radius), if any."""
    best, best_d = None, math.inf
    for a in scene["apples"]:
        d = float(np.linalg.norm(centre - np.asarray(a["center_mm"])))
        if d < best_d:
            best, best_d = a, d
    if best is None or best_d > best["radius_mm"]:
        return "no apple (leaves, or pieces of two objects)"
    return "the target" if best["id"] == target_id else "a neighbour"


def estimate_errors(scan: Scan, estimate: dict) -> dict[str, float] | None:
    """The approach-point error, σ and confidence of one `process` estimate; None: no result."""
    if not estimate.get("ok"):
        return None
    _, _, approach = target_truth(scan)
    return {"approach": float(np.linalg.norm(np.asarray(estimate["approach_mm"]) - approach)),
            "sigma": float(estimate["sigma_mm"]), "confidence": float(estimate["confidence_pct"])}


def loc_cases(cfg: Config, per_cell: int) -> tuple[list[dict], tuple[str, ...], Path]:
    """A tuning world's five-stop scans (generated, or reused from cfg.work), the options
    their generation took that `process` must take too, and where they are."""
    refuse_second_world(cfg.world)
    out = cfg.work / f"{cfg.world}-{cfg.seed}" / "loc"
    total = per_cell * len(evaluate.DISTANCES) * 2
    cases = twin.generate(cfg.twin, out, "loc", {"world": cfg.world, "count": per_cell, "seed": cfg.seed,
                                                 "jobs": cfg.jobs, **dict(cfg.generate_args)},
                          total, f"{cfg.world}: generating", cfg.quiet, sources=worlds.WORLD_SOURCES)
    return cases, tuple(x for k, v in cfg.generate_args for x in (f"--{k}", v)), out


def run_loc(cfg: Config, per_cell: int = 40) -> dict[str, Any]:
    """A tuning world's five-stop scans (`per_cell` per distance and occlusion), processed as
    `worlds` does; the cases beyond 20 mm with their scenes and what the fit took for the target."""
    cases, both, out = loc_cases(cfg, per_cell)
    dirs = [c["dir"] for c in cases]
    raw = twin.process(cfg.twin, dirs, cfg.jobs, f"{cfg.world}: our localization", quiet=cfg.quiet,
                       extra=both + cfg.process_args)
    rows = []
    for c in cases:
        d = c["dir"]
        s = Scan.load(d)
        r = raw.get(d, {})
        e, first = r.get("multi", {}), estimate_errors(s, r.get("first_pass", r.get("multi", {})))
        row = {"case": c["case"], "occluded": bool(c["occluded"]), "distance": int(c["distance_mm"]),
               "note": s.note, "stops": int(r.get("follow_up_stops", 0)), "ok": bool(e.get("ok")),
               "first": first["approach"] if first else math.nan}
        if e.get("ok"):
            fitted, scene = np.asarray(e["center_mm"]), s.truth_scene()
            row.update(estimate_errors(s, e))
            row.update({"lines": int(e["lines_used"]), "doubt": e.get("doubt", "NONE"),
                        # No line used: the rough position stands in (FAR_FROM_ROUGH, or no fit).
                        "fitted": (_what_was_fitted(fitted, scene, s.target_id) if int(e["lines_used"]) > 0
                                   else "nothing (the rough position stands in)"),
                        "rival": (f"{_what_was_fitted(np.asarray(e['rival_center_mm']), scene, s.target_id)} "
                                  f"({100 * float(e['rival_share']):.0f} %)" if e.get("rival_share", 0) > 0
                                  else "none")})
        else:
            row.update({"approach": math.nan, "sigma": math.nan, "confidence": 0.0, "lines": 0,
                        "doubt": e.get("error", "none"), "fitted": "no result", "rival": "none"})
        rows.append(row)
    res = [x for x in rows if x["ok"]]
    misses = sorted((x for x in res if x["approach"] > LOC_MISS_MM), key=lambda x: -x["approach"])
    none = [x for x in rows if not x["ok"]]  # no result at all: nothing went out
    # The misses again, with every row the LLE gave and the 3D gate kept, against the truth.
    by_case = {c["case"]: c["dir"] for c in cases}
    why = worlds.explain_misses(cfg.twin, [by_case[x["case"]] for x in misses + none], cfg.jobs,
                                f"{cfg.world}: the misses' rows", cfg.quiet, extra=both + cfg.process_args)
    reach = twin.reach(cfg.twin, [by_case[x["case"]] for x in misses + none], cfg.jobs,
                       f"{cfg.world}: what any stop could light", worlds.MEASURABLE_ROWS, cfg.quiet,
                       listing=True) if misses + none else {}
    for x in misses + none:
        x.update(why[by_case[x["case"]]])
        scan_reach = reach.get(by_case[x["case"]], {})
        x["reach"], x["identity"] = worlds.reach_text(scan_reach), worlds.identity_text(scan_reach)
    cells = {}
    for occ in (False, True):
        for dist in evaluate.DISTANCES:
            sel = [x["approach"] for x in res if x["occluded"] == occ and x["distance"] == dist]
            cells[f"{'occluded' if occ else 'clear'} {dist}"] = float(np.mean(sel)) if sel else math.nan
    return {
        "world": cfg.world, "seed": cfg.seed, "scans": len(rows), "results": len(res),
        "no_result": len(rows) - len(res),
        "process_args": list(both + cfg.process_args), "cells": cells,
        "stops_missing": sum(int(raw.get(c["dir"], {}).get("follow_up_missing", 0)) for c in cases),
        "work": str(out),
        "within20": float(np.mean([x["ok"] and x["approach"] <= LOC_MISS_MM for x in rows])),
        "within2sigma": float(np.mean([x["approach"] <= 2.0 * x["sigma"] for x in res])) if res else math.nan,
        "confident_misses": sum(1 for x in misses if x["confidence"] >= 80.0),
        "misses_by_fitted": dict(Counter(x["fitted"] for x in misses).most_common()),
        "misses_by_lines": dict(sorted(Counter(x["lines"] for x in misses).items())),
        "misses_by_cause": dict(Counter(x["cause"] for x in misses).most_common()),
        "misses": misses[:cfg.worst] if cfg.worst else misses,
        "no_result_cases": none,
    }


def text_loc(res: dict[str, Any]) -> str:
    args = " ".join(res["process_args"]) or "defaults"
    L = [f"{res['world']}, seed {res['seed']}: {res['scans']} scans, {res['results']} results ({args})",
         "approach error, mean (mm): " + ", ".join(f"{k} {v:.1f}" for k, v in res["cells"].items()),
         f"within 20 mm (all scans): {100 * res['within20']:.1f} %; within 2σ: {100 * res['within2sigma']:.1f} %; "
         f"beyond 20 mm at confidence >= 80 %: {res['confident_misses']}",
         "beyond 20 mm, what the fit took for the target: "
         + ", ".join(f"{k} {n}" for k, n in res["misses_by_fitted"].items()),
         "beyond 20 mm, by lines in the fit: " + ", ".join(f"{k}: {n}" for k, n in res["misses_by_lines"].items()),
         f"beyond 20 mm, why ({worlds.MISS_CAUSES_TEXT}): "
         + ", ".join(f"{k} {n}" for k, n in res["misses_by_cause"].items())]
    if res["stops_missing"]:
        # The scans were rendered with the second-pass stops that the localizer of their
        # generation asked for; a change to the LLE or the plan asks for others.
        L.append(f"second-pass stops the scans lack: {res['stops_missing']} (the figures above are not this "
                 f"build's: delete {res['work']} to render the scans again)")
    L += ["", "worst cases:"]
    seen = ("; the target's rows lit {lit_rows} (stops lit {stops_lit}), found {found_rows}, kept {kept_on} "
            "(other rows kept {kept_off}), {cause}; any stop lights it at {reach}; the rough position names it at "
            "{identity}: {note}")
    L += [f"  {x['case']} {x['approach']:.1f} mm (first pass {x['first']:.1f}, +{x['stops']} stops), "
          f"σ {x['sigma']:.1f}, confidence {x['confidence']:.0f} %, {x['lines']} lines, {x['doubt']}, "
          f"fitted {x['fitted']}, rival {x['rival']}" + seen.format(**x) for x in res["misses"]]
    if res["no_result_cases"]:
        L += ["", f"no result ({res['no_result']} scans; counted above as not within 20 mm):"]
        L += [f"  {x['case']} (+{x['stops']} stops): {x['doubt']}" + seen.format(**x) for x in res["no_result_cases"]]
    return "\n".join(L)
