"""Runs the C++ twin (tools/twin, `alacs-twin`): scan generation and the pipeline."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
from pathlib import Path

from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[4]


def find_twin(explicit: str | None = None) -> Path:
    """--twin, else $ALACS_TWIN, else the newest build/*/tools/twin/alacs-twin."""
    for cand in (explicit, os.environ.get("ALACS_TWIN")):
        if cand:
            p = Path(cand)
            if not p.exists():
                raise FileNotFoundError(f"alacs-twin not found at {p}")
            return p
    found = sorted(ROOT.glob("build/*/tools/twin/alacs-twin"), key=lambda p: p.stat().st_mtime, reverse=True)
    if not found:
        raise FileNotFoundError("alacs-twin is not built: cmake --build build/<dir> --target alacs-twin, or pass --twin")
    return found[0]


def run_lines(cmd: list[str], total: int, desc: str, quiet: bool = False) -> list[dict]:
    """Runs `cmd`, one JSON object per stdout line, with a progress bar."""
    out: list[dict] = []
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, bufsize=1) as proc:
        assert proc.stdout is not None
        with tqdm(total=total, desc=desc, unit="scan", disable=quiet, leave=False) as bar:
            for line in proc.stdout:
                line = line.strip()
                if line.startswith("{"):
                    out.append(json.loads(line))
                    bar.update(1)
        rc = proc.wait()
    if rc != 0:
        raise RuntimeError(f"{' '.join(cmd[:3])} ... failed with status {rc}")
    return out


GENERATOR_SOURCES = ("edge/sim", "edge/replay", "tools/twin/generate.cpp", "tools/twin/calibration_scans.cpp",
                     "tools/twin/two_pass.cpp",
                     "tools/twin/main.cpp", "edge/localize/localizer.cpp", "edge/localize/localizer.h",
                     "edge/geometry/calibration.cpp", "edge/geometry/calibration.h", "edge/geometry/triangulation.cpp",
                     "edge/localize/exposure.cpp", "edge/localize/exposure.h")


def generator_version(sources: tuple[str, ...] = GENERATOR_SOURCES) -> str:
    """A hash of the sources that decide what the twin generates (scenes, renders, plans)."""
    h = hashlib.sha256()
    for rel in sources:
        p = ROOT / rel
        for f in sorted(p.rglob("*") if p.is_dir() else [p]):
            if f.is_file() and f.suffix in (".cpp", ".h", ".txt"):
                h.update(str(f.relative_to(ROOT)).encode())
                h.update(f.read_bytes())
    return h.hexdigest()[:16]


def reuse_or_clear(out: Path, signature: dict, sig_name: str = "args.json") -> bool:
    """True when `out` holds what `signature` made (its `sig_name` file says so); otherwise
    `out` is emptied and made again, to be filled and then signed (`sign`)."""
    sig = out / sig_name
    if sig.exists() and json.loads(sig.read_text()) == signature:
        return True
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    return False


def sign(out: Path, signature: dict, sig_name: str = "args.json") -> None:
    """Marks `out` as complete for `signature` (reuse_or_clear)."""
    (out / sig_name).write_text(json.dumps(signature))


def generate(twin: Path, out: Path, set_name: str, args: dict[str, str], total: int, desc: str,
             quiet: bool = False, sources: tuple[str, ...] = GENERATOR_SOURCES) -> list[dict]:
    """A benchmark set, regenerated only when its arguments or the generator's sources changed."""
    signature = {"set": set_name, **args, "generator": generator_version(sources)}
    sig_file, index = out / "args.json", out / "set.jsonl"
    if sig_file.exists() and index.exists():
        if json.loads(sig_file.read_text()) == signature:
            cases = [json.loads(l) for l in index.read_text().splitlines() if l.strip()]
            if len(cases) == total:
                return cases
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    cmd = [str(twin), "generate", "--set", set_name, "--out", str(out)]
    for k, v in args.items():
        cmd += [f"--{k}", str(v)]
    cases = run_lines(cmd, total, desc, quiet)
    sig_file.write_text(json.dumps(signature))
    order = {c["case"]: i for i, c in enumerate(json.loads(l) for l in index.read_text().splitlines() if l.strip())}
    return sorted(cases, key=lambda c: order[c["case"]])


def process(twin: Path, dirs: list[str], jobs: int, desc: str, rows: bool = False, step: int | None = None,
            threshold: int | None = None, calibration: str | None = None, quiet: bool = False,
            other_object_prior: float | None = None, extra: tuple[str, ...] = ()) -> dict[str, dict]:
    """`alacs-twin process` on `dirs`; `extra`: further options of its own (e.g. --lle-smooth-rows 0)."""
    cmd = [str(twin), "process", "--jobs", str(jobs), *extra]
    if other_object_prior is not None:
        cmd += ["--other-object-prior", str(other_object_prior)]
    if rows:
        cmd.append("--rows")
    if step is not None:
        cmd += ["--brce-step", str(step)]
    if threshold is not None:
        cmd += ["--brce-threshold", str(threshold)]
    if calibration:
        cmd += ["--calibration", calibration]
    results = run_lines(cmd + dirs, len(dirs), desc, quiet)
    return {r["scan"]: r for r in results}


def reach(twin: Path, dirs: list[str], jobs: int, desc: str, min_rows: int, quiet: bool = False,
          listing: bool = False) -> dict[str, dict]:
    """`alacs-twin reach` on `dirs`: the slide positions (the stroke, 1 mm apart) that light
    each scan's target on `min_rows` visible rows or more, from the truth (`listing`: each
    of them, with its rows). A scan it could not read raises, naming it."""
    cmd = [str(twin), "reach", "--jobs", str(jobs), "--min-rows", str(min_rows)] + (["--list"] if listing else [])
    results = {r["scan"]: r for r in run_lines(cmd + dirs, len(dirs), desc, quiet)}
    bad = [f"{d}: {r['error']}" for d, r in results.items() if "error" in r]
    if bad or len(results) != len(dirs):
        raise RuntimeError("alacs-twin reach: " + ("; ".join(bad) or "scans without a line"))
    return results


def find_calibrate(twin_path: Path) -> Path | None:
    """alacs_calibrate (issue 5's tool) in the same build as alacs-twin, if built."""
    cand = twin_path.parent.parent / "calibrate" / "alacs_calibrate"
    return cand if cand.exists() else None


def calibration_scans(twin: Path, out: Path, seed: int, jobs: int, quiet: bool = False) -> None:
    """The twin's calibration scans (checkerboard views, laser-plane placements), cached."""
    signature = {"seed": seed, "generator": generator_version()}
    if reuse_or_clear(out, signature):
        return
    run_lines([str(twin), "calib", "--out", str(out), "--seed", str(seed), "--jobs", str(jobs)], 29,
              "generating calibration scans", quiet)
    sign(out, signature)


def calibrate(tool: Path, scans: Path, out: Path) -> tuple[bool, str]:
    """Runs alacs_calibrate on the scans; (accepted by its gate, its report)."""
    proc = subprocess.run([str(tool), "--scans", str(scans), "--out", str(out)], capture_output=True, text=True)
    return proc.returncode == 0 and out.exists(), proc.stdout + proc.stderr
