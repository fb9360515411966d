"""alacs-eval: the paper's evaluation on the digital twin, in one command.

    alacs-eval report            the full set (≥ 300 LLE cases, 120 scans per distance
                                 and occlusion), writes docs/evaluation.md and
                                 docs/figures/eval_*.png
    alacs-eval report --small    the CI set (a few minutes), into build/eval-small
    alacs-eval calibration       corner detectors and the calibration's 3D error on the
                                 twin's calibration worlds (docs/calibration.md)
    alacs-eval diagnose          where the LLE (--loc: the localization) loses on a tuning world, case by case
                                 (never the second world)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from alacs_eval import calibration, compare, diagnose, diameter, evaluate, exposure, report, stack, twin, worlds

ROOT = twin.ROOT


def _report(a: argparse.Namespace) -> int:
    work = Path(a.work) if a.work else ROOT / "build" / ("eval-small" if a.small else "eval")
    doc = Path(a.doc) if a.doc else (work / "evaluation.md" if a.small else ROOT / "docs" / "evaluation.md")
    figs = Path(a.figures) if a.figures else (work / "figures" if a.small else ROOT / "docs" / "figures")
    cfg = evaluate.Config(work=work, twin=twin.find_twin(a.twin), jobs=a.jobs, small=a.small, seed=a.seed,
                          calibration=a.calibration, quiet=a.quiet,
                          estimate_calibration=not a.small and not a.no_calibration and not a.calibration)
    t0 = time.monotonic()
    res = evaluate.run(cfg)
    res["meta"]["total_s"] = time.monotonic() - t0
    work.mkdir(parents=True, exist_ok=True)
    examples = res.pop("_examples", [])
    (work / "results.json").write_text(json.dumps(res, indent=1, default=float))
    paths = report.figures(res, figs, "eval_")
    if examples:
        paths["examples"] = report.examples_figure(examples, figs / "eval_lle_examples.png")
    command = "tools/eval/run.sh report" + (" --small" if a.small else "")
    doc.parent.mkdir(parents=True, exist_ok=True)
    kept = worlds.section_of(doc)  # `alacs-eval worlds` writes its own section; keep it
    doc.write_text(report.markdown(res, paths, doc, command))
    if kept:
        worlds.insert(doc, kept)
    print(f"alacs-eval: {doc} and {len(paths)} figures in {figs} ({res['meta']['total_s']:.0f} s); "
          f"numbers in {work / 'results.json'}")
    return 0


def _render(a: argparse.Namespace) -> int:
    """Writes the report and plots again from WORK/results.json (no scan is processed)."""
    work = Path(a.work)
    res = json.loads((work / "results.json").read_text())
    doc = Path(a.doc) if a.doc else ROOT / "docs" / "evaluation.md"
    figs = Path(a.figures) if a.figures else ROOT / "docs" / "figures"
    paths = report.figures(res, figs, "eval_")
    if (figs / "eval_lle_examples.png").exists():
        paths["examples"] = figs / "eval_lle_examples.png"
    kept = worlds.section_of(doc)
    doc.write_text(report.markdown(res, paths, doc, "tools/eval/run.sh report" + (" --small" if res["meta"]["small"] else "")))
    if kept:
        worlds.insert(doc, kept)
    print(f"alacs-eval: {doc} from {work / 'results.json'}")
    return 0


def _worlds(a: argparse.Namespace) -> int:
    """Both worlds side by side: the section of docs/evaluation.md between its markers."""
    work = Path(a.work) if a.work else ROOT / "build" / ("worlds-small" if a.small else "worlds")
    if a.regenerate and work.exists():
        import shutil
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    cfg = worlds.Config(work=work, twin=twin.find_twin(a.twin), jobs=a.jobs, small=a.small, quiet=a.quiet,
                        other_object_prior=a.other_object_prior)
    res = worlds.run(cfg)
    (work / "results.json").write_text(json.dumps(res, indent=1, default=float))
    doc = Path(a.doc) if a.doc else (work / "evaluation.md" if a.small else ROOT / "docs" / "evaluation.md")
    figs = Path(a.figures) if a.figures else (work / "figures" if a.small else ROOT / "docs" / "figures")
    fig = worlds.figure(res, figs / "eval_worlds_sigma.png")
    rel = str(fig.relative_to(doc.parent)) if fig.is_relative_to(doc.parent) else str(fig)
    worlds.insert(doc, worlds.markdown(res, rel, "tools/eval/run.sh worlds" + (" --small" if a.small else "")))
    print(f"alacs-eval: both worlds into {doc}; numbers in {work / 'results.json'}")
    return 0


def _diagnose(a: argparse.Namespace) -> int:
    """Where the LLE loses on a tuning world: worst frames, rows next to gaps, missed rows."""
    work = Path(a.work) if a.work else ROOT / "build" / "diagnose"
    extra = tuple(x for x in a.process_args if x != "--")
    gen = (("follow-up-unseen-max-stops", str(a.follow_up_unseen_max_stops)),) \
        if a.follow_up_unseen_max_stops is not None else ()
    if a.second_exposure is not None:
        gen += (("meter-second-exposure", repr(a.second_exposure)),)
    cfg = diagnose.Config(world=a.world, seed=a.seed, count=a.count, work=work, twin=twin.find_twin(a.twin),
                          jobs=a.jobs, process_args=extra, generate_args=gen, worst=a.worst, quiet=a.quiet,
                          read=a.read)
    try:
        if a.stack is not None and (not a.loc or a.diameter or a.matched_filter):
            raise ValueError("--stack goes with --loc (and not with --diameter or --matched-filter)")
        if a.stack_gain_db is not None and a.stack is None:
            raise ValueError("--stack-gain-db goes with --stack")
        if a.exposures is not None and (not a.loc or a.diameter or a.matched_filter or a.stack is not None):
            raise ValueError("--exposures goes with --loc (and not with --diameter, --matched-filter or --stack)")
        if a.against is not None:
            if not a.against:
                raise ValueError("--against needs the other build's alacs-twin")
            if not a.loc or a.diameter or a.matched_filter or a.stack is not None:
                raise ValueError("--against goes with --loc (and not with --diameter, --matched-filter or --stack)")
            print(compare.text(compare.run(cfg, twin.find_twin(a.against), a.per_cell)))
            return 0
        if a.matched_filter:
            print(diagnose.text_matched_filter(diagnose.matched_filter(cfg)))
            return 0
        if a.stack is not None:
            print(stack.text(stack.run(cfg, a.per_cell, a.stack, a.stack_gain_db)))
            return 0
        if a.exposures is not None:
            print(exposure.text(exposure.run(cfg, a.per_cell, exposure.parse_factors(a.exposures))))
            return 0
        if a.diameter:
            cases, both, _ = diagnose.loc_cases(cfg, a.per_cell)
            print(diameter.text(diameter.run(cfg, cases, both + cfg.process_args), a.worst))
            return 0
        res = diagnose.run_loc(cfg, a.per_cell) if a.loc else diagnose.run(cfg)
    except ValueError as e:
        print(f"alacs-eval diagnose: {e}", file=sys.stderr)
        return 2
    print(diagnose.text_loc(res) if a.loc else diagnose.text(res))
    return 0


def _calibration(a: argparse.Namespace) -> int:
    """Corner detectors on the tuning and holdout sets; 3D error per board, tilt and view count."""
    work = Path(a.work) if a.work else ROOT / "build" / ("calibration-quick" if a.quick else "calibration")
    tw = twin.find_twin(a.twin)
    tools = Path(a.tools_build) if a.tools_build else tw.parent.parent.parent
    cfg = calibration.Config(work=work, twin=tw, tools=tools, jobs=a.jobs, quick=a.quick, quiet=a.quiet,
                             corners=not a.study_only, detector=a.corners, outlier_sigmas=a.corner_outlier_sigmas,
                             study_world=a.study_world)
    res = calibration.run(cfg)
    (work / "results.json").write_text(json.dumps(res, indent=1, default=float))
    (work / "calibration.md").write_text("\n".join(cfg.log) + "\n")
    print(f"alacs-eval: {work / 'calibration.md'}; numbers in {work / 'results.json'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="alacs-eval", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    def common(parser: argparse.ArgumentParser, small: str, work: str) -> None:
        parser.add_argument("--small", action="store_true", help=small)
        parser.add_argument("--work", help=work)
        parser.add_argument("--doc", help="the Markdown report (default docs/evaluation.md; --small: WORK/evaluation.md)")
        parser.add_argument("--figures", help="the PNG plots (default docs/figures; --small: WORK/figures)")
        parser.add_argument("--twin", help="the alacs-twin binary (default $ALACS_TWIN or the newest build/*/tools/twin)")
        parser.add_argument("--jobs", type=int, default=2)
        parser.add_argument("--quiet", action="store_true", help="no progress bars")

    r = sub.add_parser("report", help="generate the sets (or reuse them), run both methods, write the report")
    common(r, "the small CI set", "where the scans and results go (default build/eval or build/eval-small)")
    r.add_argument("--seed", type=int, default=1)
    r.add_argument("--calibration", help="run both methods with this calibration instead of the scans' true one")
    r.add_argument("--no-calibration", action="store_true",
                   help="skip the run with a calibration estimated from the twin's calibration scans")
    r.set_defaults(func=_report)
    v = sub.add_parser("worlds", help="the benchmark, its hard cases and the second world side by side (issue 17)")
    common(v, "a few scans per world (CI)", "default build/worlds (--small: build/worlds-small)")
    v.add_argument("--regenerate", action="store_true", help="write every world's scans again")
    v.add_argument("--other-object-prior", type=float, help="the localizer's ScanParams::otherObjectPrior (0: the fit's σ alone)")
    v.set_defaults(func=_worlds)
    g = sub.add_parser("diagnose", help="where the LLE (--loc: the localization) loses on a tuning world, case by case (not the second world)")
    g.add_argument("--world", default="benchmark-hard", help="benchmark or benchmark-hard (the second world is refused)")
    g.add_argument("--seed", type=int, default=3, help="the tuning seed (default 3)")
    g.add_argument("--count", type=int, default=160, help="LLE frames (default 160)")
    g.add_argument("--worst", type=int, default=10, help="how many of the worst frames (--loc: scans beyond 20 mm) to list")
    g.add_argument("--read", choices=("line", "rough"), default="line",
                   help="LLE frames: a row the localizer keeps two samples of is read by the LLE's line's (default) "
                        "or by the one nearest the rough position")
    g.add_argument("--loc", action="store_true", help="localization: five-stop scans, the cases beyond 20 mm")
    g.add_argument("--per-cell", type=int, default=40, help="--loc: scans per distance and occlusion (default 40)")
    g.add_argument("--diameter", action="store_true",
                   help="the localization scans' occluded plain spheres (implies --loc): the sensor's diameter error "
                        "against a sphere on its samples that lie on the target (by the truth) and on the truth's "
                        "points at those rows")
    g.add_argument("--matched-filter", action="store_true",
                   help="the LLE frames: a prototype matched filter on the laser-off-subtracted red against our "
                        "kept samples, rows found per light (docs/lle.md, \"The sunlit line through a matched filter\")")
    g.add_argument("--stack", type=int, metavar="N",
                   help="--loc: the occluded scans in sun rendered again, once with one frame and once with N "
                        "frames of each stop averaged, and processed (a prototype, not the product: "
                        "alacs_eval/stack.py)")
    g.add_argument("--stack-gain-db", type=float, metavar="G",
                   help="--stack: both renders with the sensor at G dB analogue gain, the exposure scaled to keep "
                        "the same DN")
    g.add_argument("--exposures", metavar="1,K,...",
                   help="--loc: each first-pass stop of the occluded scans in sun rendered again at these factors of "
                        "its metered exposure (1 first), the target's lit rows alacs_lle finds at each, and with the "
                        "metered frame together (a prototype, not the product: alacs_eval/exposure.py)")
    g.add_argument("--against", metavar="TWIN",
                   help="--loc: the same scans through another build's alacs-twin as well (one made before a change), "
                        "side by side; the scans whose second pass a build moves are rendered again by that build "
                        "(alacs_eval/compare.py)")
    g.add_argument("--work", help="default build/diagnose")
    g.add_argument("--twin", help="the alacs-twin binary (default $ALACS_TWIN or the newest build/*/tools/twin)")
    g.add_argument("--jobs", type=int, default=2)
    g.add_argument("--quiet", action="store_true", help="no progress bars")
    g.add_argument("--follow-up-unseen-max-stops", type=int,
                   help="--loc: ScanParams::followUpUnseenMaxStops, for the scans rendered and their processing "
                        "(use another --work: the scans are rendered again)")
    g.add_argument("--second-exposure", type=float, metavar="F",
                   help="--loc: metering.second_exposure_factor for the scans rendered and their processing (use "
                        "another --work: the scans are rendered again); `-- --meter-second-exposure 0` then "
                        "processes them with one exposure per stop")
    g.add_argument("process_args", nargs=argparse.REMAINDER,
                   help="after --: options for `alacs-twin process` (e.g. --lle-subtracted-line-pct 20)")
    g.set_defaults(func=_diagnose)
    c = sub.add_parser("calibration", help="corner detectors and the calibration's 3D error (issue 17, item 6)")
    c.add_argument("--quick", action="store_true", help="the corner sets only, 4 views and 5 placements each, the default detector (CI)")
    c.add_argument("--study-only", action="store_true", help="the 3D error study only, not the corner sets")
    c.add_argument("--corners", help="alacs_calibrate --corners for the study (default: its own default)")
    c.add_argument("--corner-outlier-sigmas", type=float,
                   help="alacs_calibrate --corner-outlier-sigmas for the study (0: every corner kept; default: its own)")
    c.add_argument("--study-world", choices=("holdout", "tuning"), default="holdout",
                   help="the study's sets: the holdout's boards, tilts and view counts (reported only), or the "
                        "issue's board at 12-60 views on the tuning world, seeds 3-5 (where choices are made)")
    c.add_argument("--work", help="default build/calibration (--quick: build/calibration-quick)")
    c.add_argument("--twin", help="the alacs-twin binary (default $ALACS_TWIN or the newest build/*/tools/twin)")
    c.add_argument("--tools-build", help="the build holding alacs_calibrate and alacs_geometry_eval (default: the twin's)")
    c.add_argument("--jobs", type=int, default=2)
    c.add_argument("--quiet", action="store_true", help="no progress bars")
    c.set_defaults(func=_calibration)
    w = sub.add_parser("render", help="write the report and plots again from a previous run's results.json")
    w.add_argument("--work", required=True, help="the run's work directory (holds results.json)")
    w.add_argument("--doc", help="default docs/evaluation.md")
    w.add_argument("--figures", help="default docs/figures")
    w.set_defaults(func=_render)
    a = p.parse_args(argv)
    try:
        return a.func(a)
    except (OSError, RuntimeError) as e:
        # A tool that is missing or fails (alacs-twin, alacs_calibrate), a file that cannot be
        # read or written: the reason, not a traceback.
        print(f"alacs-eval {a.cmd}: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
