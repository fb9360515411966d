"""alacs-eval calibration: the corner detectors and the calibration's 3D error on the twin's
calibration worlds (docs/calibration.md, "Corner detection" and "What a calibration needs").

- Corners: `alacs_geometry_eval corners` on a tuning set (where the detector and its window
  were chosen) and on the holdout set (only reported): views detected, corner RMS / max
  against the twin's exact corners, the skipped views and why.
- Requirement: holdout calibration sets for a few boards, tilt spreads and view counts, each
  through `alacs_calibrate` and `alacs_geometry_eval check-calibration`: the mean 3D error at
  1.0-1.6 m, the median over seeds.

The holdout's per-view results are printed for the report; no parameter is chosen from them.
"""

from __future__ import annotations

import json
import re
import statistics
import subprocess
from dataclasses import dataclass, field, replace
from pathlib import Path

from alacs_eval import twin


@dataclass(frozen=True)
class CalibSet:
    """One calibration set of `alacs-twin calib`."""
    world: str
    seed: int
    views: int
    board: str = "10x7x40"
    margin_mm: float = 60.0
    tilt_deg: float | None = None  # None: the world's
    positions: str | None = None   # laser slide positions (None: the twin's nine)

    def name(self) -> str:
        tilt = "" if self.tilt_deg is None else f"_t{self.tilt_deg:g}"
        laser = "" if self.positions is None else f"_p{self.positions.count(',') + 1}"
        return f"{self.world}_{self.board}_m{self.margin_mm:g}_v{self.views}{tilt}{laser}_s{self.seed}"

    def args(self) -> list[str]:
        a = ["--world", self.world, "--seed", str(self.seed), "--views", str(self.views), "--board", self.board,
             "--margin-mm", f"{self.margin_mm:g}"]
        a += [] if self.tilt_deg is None else ["--tilt-deg", f"{self.tilt_deg:g}"]
        return a + ([] if self.positions is None else ["--positions", self.positions])


# The detector is chosen on TUNING; HOLDOUT is the second world, only reported.
TUNING = CalibSet("tuning", seed=3, views=20, board="12x9x30", margin_mm=45.0)
HOLDOUT = CalibSet("holdout", seed=11, views=20)
# Boards, tilt spreads and view counts tried on the holdout for the requirement.
# Five laser slide positions instead of nine, and one seed, keep the run to ~20 minutes on
# two busy cores; the laser plane is not what limits the 3D error here (docs/calibration.md).
_LASER = "0,50,100,150,200"
STUDY = [
    CalibSet("holdout", 0, 12, positions=_LASER),
    CalibSet("holdout", 0, 20, positions=_LASER),
    CalibSet("holdout", 0, 30, positions=_LASER),
    CalibSet("holdout", 0, 60, positions=_LASER),
    CalibSet("holdout", 0, 20, tilt_deg=15.0, positions=_LASER),
    CalibSet("holdout", 0, 20, board="8x6x60", margin_mm=60.0, positions=_LASER),
]
STUDY_SEEDS = (11,)
# The same view counts on the tuning world (where a choice may be made, e.g. the corner
# outlier test's): the board, three seeds.
TUNING_STUDY = [CalibSet("tuning", 0, v, positions=_LASER) for v in (12, 20, 30, 60)]
TUNING_STUDY_SEEDS = (3, 4, 5)


@dataclass
class Config:
    work: Path
    twin: Path
    tools: Path  # the build directory holding tools/calibrate and tools/geometry_eval
    jobs: int = 2
    quick: bool = False  # the tuning and holdout corner sets only, fewer views, the default detector only
    corners: bool = True  # the tuning and holdout corner sets (False: the 3D study only)
    detector: str | None = None  # alacs_calibrate --corners (None: its default)
    outlier_sigmas: float | None = None  # alacs_calibrate --corner-outlier-sigmas (None: its default)
    study_world: str = "holdout"  # the study's sets: "holdout" (STUDY) or "tuning" (TUNING_STUDY)
    quiet: bool = False
    windows: tuple[float, ...] = (0.25, 0.35, 0.45)
    log: list[str] = field(default_factory=list)


def _say(cfg: Config, text: str) -> None:
    cfg.log.append(text)
    if not cfg.quiet:
        print(text, flush=True)


def scans(cfg: Config, s: CalibSet) -> Path:
    """The set's scan directories, generated once (args.json holds what made them)."""
    out = cfg.work / s.name()
    signature = {"args": s.args(), "generator": twin.generator_version()}
    if twin.reuse_or_clear(out, signature):
        return out
    twin.run_lines([str(cfg.twin), "calib", "--out", str(out), "--jobs", str(cfg.jobs), *s.args()], s.views + 5,
                   f"rendering {s.name()}", cfg.quiet)
    twin.sign(out, signature)
    return out


_ROW = re.compile(r"^\| (?P<name>[^|]+?) \| (?P<det>\d+) / (?P<tot>\d+) \| (?P<rms>[\d.]+) px \| (?P<med>[\d.nan]+) px "
                  r"\| (?P<max>[\d.]+) px \|")


def corners(cfg: Config, directory: Path) -> dict:
    """`alacs_geometry_eval corners`: per detector, detected / total, RMS, median view RMS, max (px)."""
    cmd = [str(cfg.tools / "tools/geometry_eval/alacs_geometry_eval"), "corners", "--scans", str(directory),
           "--window-shares", ",".join(f"{w:g}" for w in cfg.windows)] + (["--default-only"] if cfg.quick else [])
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode not in (0, 4):
        raise RuntimeError(f"{' '.join(cmd)}: {proc.stderr.strip()}")
    rows = {}
    for line in proc.stdout.splitlines():
        m = _ROW.match(line)
        if m:
            rows[m["name"]] = {"detected": int(m["det"]), "views": int(m["tot"]), "rms_px": float(m["rms"]),
                               "median_view_rms_px": float(m["med"]), "max_px": float(m["max"])}
    skipped = proc.stdout.split("and why:\n", 1)[1].strip().splitlines() if "and why:\n" in proc.stdout else []
    return {"detectors": rows, "skipped": [s.strip() for s in skipped if s.strip() != "none"], "table": proc.stdout}


_ERR = re.compile(r"^\| (?P<z>[\d.]+) m \| \d+ \| (?P<mean>[\d.]+) mm \| (?P<max>[\d.]+) mm \| [\d.]+ mm \| "
                  r"(?P<rotated>[\d.]+) mm \|")


def calibrate(cfg: Config, directory: Path, s: CalibSet | None = None) -> dict:
    """alacs_calibrate on the set (its board; cfg.detector or the tool's default), then the
    3D error of what it estimated (refused or not)."""
    est = directory / f"estimate_{cfg.detector or 'default'}.json"
    cmd = [str(cfg.tools / "tools/calibrate/alacs_calibrate"), "--scans", str(directory), "--out", str(est)]
    if s is not None:
        cmd += ["--board", s.board, "--margin-mm", f"{s.margin_mm:g}"]
    if cfg.detector:
        cmd += ["--corners", cfg.detector]
    if cfg.outlier_sigmas is not None:
        cmd += ["--corner-outlier-sigmas", f"{cfg.outlier_sigmas:g}"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    text = proc.stdout + proc.stderr
    res: dict = {"exit": proc.returncode, "gate": {0: "passed", 3: "refused"}.get(proc.returncode, "failed"),
                 "verdict": [ln.strip() for ln in text.splitlines() if ln.startswith(("  quality.", "  total σ"))],
                 "skipped": [ln.strip() for ln in text.splitlines() if ln.startswith("  skipped ")]}
    m = re.search(r"camera_views\s+(\d+)", text)
    res["camera_views"] = int(m[1]) if m else 0
    m = re.search(r"reprojection_rms_px\s+([\d.]+)", text)
    res["reprojection_rms_px"] = float(m[1]) if m else float("nan")
    m = re.search(r"(\d+) misplaced corners left out", text)
    res["corners_left_out"] = int(m[1]) if m else 0
    # A refused calibration never loads: judge its 3D error from a copy marked not judged.
    path = est if proc.returncode == 0 else est.with_name(est.name + ".refused")
    if not path.exists():
        res["error_mm"] = {}
        return res
    if proc.returncode != 0:
        cal = json.loads(path.read_text())
        cal["quality"]["gate"] = "not_run"
        path = est.with_name(est.stem + "_unjudged.json")
        path.write_text(json.dumps(cal))
    chk = subprocess.run([str(cfg.tools / "tools/geometry_eval/alacs_geometry_eval"), "check-calibration",
                          "--calibration", str(path), "--truth", str(directory / "laser_plane_1000/calibration.json")],
                         capture_output=True, text=True)
    rows = [m for m in map(_ERR.match, chk.stdout.splitlines()) if m]
    res["error_mm"] = {m["z"]: float(m["mean"]) for m in rows}
    # The same after the camera frame's best rotation (mostly the principal point's error;
    # a hand-eye calibration with the sensor's own measurements absorbs it).
    res["error_after_rotation_mm"] = {m["z"]: float(m["rotated"]) for m in rows}
    return res


def run(cfg: Config) -> dict:
    cfg.work.mkdir(parents=True, exist_ok=True)
    out: dict = {"corners": {}, "study": []}
    sets = {"tuning": TUNING, "holdout": HOLDOUT}
    if cfg.quick:
        sets = {k: replace(v, views=4, positions="0,100,200") for k, v in sets.items()}
    for key, s in sets.items() if cfg.corners else []:
        res = corners(cfg, scans(cfg, s))
        out["corners"][key] = {"set": s.name(), "dir": str(cfg.work / s.name()), **res}
        _say(cfg, f"\n## Corners, {key} set ({s.name()})\n\n{res['table']}")
    if cfg.quick:
        return out
    study, seeds = (TUNING_STUDY, TUNING_STUDY_SEEDS) if cfg.study_world == "tuning" else (STUDY, STUDY_SEEDS)
    for s in study:
        runs = []
        for seed in seeds:
            one = replace(s, seed=seed)
            r = calibrate(cfg, scans(cfg, one), one)
            r["set"] = one.name()
            runs.append(r)
            _say(cfg, f"{one.name()}: gate {r['gate']}, {r['camera_views']} views, reprojection "
                      f"{r['reprojection_rms_px']:.3f} px, {r['corners_left_out']} corners left out, "
                      f"3D error {r['error_mm']}")
        out["study"].append({"board": s.board, "margin_mm": s.margin_mm, "views": s.views,
                             "tilt_deg": 35.0 if s.tilt_deg is None else s.tilt_deg, "runs": runs})
    sigmas = "(default)" if cfg.outlier_sigmas is None else f"{cfg.outlier_sigmas:g}"
    _say(cfg, f"\nalacs_calibrate --corners {cfg.detector or '(default)'} --corner-outlier-sigmas {sigmas}, "
              f"{cfg.study_world} world\n" + study_table(out["study"], seeds))
    return out


def study_table(study: list[dict], seeds: tuple[int, ...] = STUDY_SEEDS) -> str:
    """Markdown: per configuration, the median over seeds of the mean 3D error per distance."""
    lines = ["| board | tilt | views (found) | corners left out | gate | 1.0 m | 1.2 m | 1.4 m | 1.6 m | 1.6 m worst seed "
             "| 1.6 m after the frame's rotation |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for c in study:
        runs = c["runs"]
        found = "/".join(str(r["camera_views"]) for r in runs)
        gates = "/".join(r["gate"][0] for r in runs)
        left_out = "/".join(str(r.get("corners_left_out", 0)) for r in runs)
        med = {z: statistics.median(r["error_mm"].get(z, float("nan")) for r in runs) for z in ("1.0", "1.2", "1.4", "1.6")}
        worst = max(r["error_mm"].get("1.6", float("nan")) for r in runs)
        rotated = statistics.median(r.get("error_after_rotation_mm", {}).get("1.6", float("nan")) for r in runs)
        lines.append(f"| {c['board']} / {c['margin_mm']:g} | ±{c['tilt_deg']:g}° | {c['views']} ({found}) | {left_out} | {gates} | "
                     + " | ".join(f"{med[z]:.2f}" for z in ("1.0", "1.2", "1.4", "1.6")) + f" | {worst:.2f} | {rotated:.2f} |")
    return "\n".join(lines) + "\n(mm; mean 3D error over the grid, median over seeds " + \
        ", ".join(map(str, seeds)) + "; gate p = passed, r = refused, f = failed; views found incl. 5 placements)"
