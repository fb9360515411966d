"""`alacs-eval diagnose`: the frame-by-frame look at a tuning world's LLE refuses the
second world, and on a few hard frames reports what the aggregates hide."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from alacs_eval import cli, compare, diagnose, diameter, evaluate, exposure, metrics, stack, twin, worlds
from alacs_eval.scans import Scan, target_truth


@pytest.mark.parametrize("look", [["--count", "2"], ["--loc", "--per-cell", "1"], ["--diameter", "--per-cell", "1"],
                                  ["--loc", "--stack", "2", "--per-cell", "1"],
                                  ["--loc", "--exposures", "1,2", "--per-cell", "1"],
                                  ["--loc", "--against", "/bin/true", "--per-cell", "1"]],
                         ids=["lle", "localization", "diameter", "stack", "exposures", "two builds"])
def test_the_second_world_is_refused(tmp_path, capsys, look):
    assert cli.main(["diagnose", *look, "--world", "holdout", "--work", str(tmp_path),
                     "--twin", os.environ.get("ALACS_TWIN", "/bin/true")]) == 2
    assert "kept out of tuning" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # nothing generated


def test_exposures_prototype_counts_the_targets_lit_rows_it_finds(tmp_path, capsys):
    """`diagnose --loc --exposures`: its factors start at the metered exposure; a row counts
    as found where the target is visible and lit (flags 0) and a valid sample lies within
    2 px; a row of another apple, a hidden row, a far sample or an invalid one does not."""
    assert exposure.parse_factors("1,2,4") == (1.0, 2.0, 4.0)
    for bad in ("2,4", "1", "1,1", "1,x", "1,40"):
        with pytest.raises(ValueError, match="--exposures"):
            exposure.parse_factors(bad)
    assert cli.main(["diagnose", "--exposures", "1,2", "--world", "benchmark-hard", "--work", str(tmp_path),
                     "--twin", "/bin/true"]) == 2
    assert "--exposures goes with --loc" in capsys.readouterr().err
    truth_csv = tmp_path / "t.csv"
    truth_csv.write_text("apple_id,row,column_px,x_mm,y_mm,z_mm,flags\n"
                         "1,510,120.5,0,0,0,0\n1,511,121.0,0,0,0,0\n1,512,121.5,0,0,0,1\n"
                         "2,513,140.0,0,0,0,0\n1,514,122.5,0,0,0,0\n")
    truth = exposure.target_rows(truth_csv, 1, 100, 500)
    assert truth == {10: 20.5, 11: 21.0, 14: 22.5}
    lle = {"rows": [{"row": 10, "column": 21.9, "valid": True}, {"row": 11, "column": 23.5, "valid": True},
                    {"row": 13, "column": 40.0, "valid": True}, {"row": 14, "column": 22.5, "valid": False},
                    {"row": 12, "column": 21.5, "valid": True}, {"row": 15, "column": None, "valid": False}]}
    assert exposure.found_rows(lle, truth) == {10}


def _twin():
    tw = os.environ.get("ALACS_TWIN")
    if not tw:
        pytest.fail("set ALACS_TWIN to the alacs-twin binary (tests/eval/run.sh does)")
    return twin.find_twin(tw)


def test_a_few_hard_frames_are_diagnosed(tmp_path):
    cfg = diagnose.Config(world="benchmark-hard", seed=3, count=8, work=tmp_path, twin=_twin(),
                          quiet=True, worst=3)
    res = diagnose.run(cfg)
    assert res["frames"] == 8
    assert len(res["worst"]) == 3
    assert res["worst"][0]["worst"] >= res["worst"][-1]["worst"]
    # Every visible row is either found or missed for a named reason.
    found_rows = sum(g["n"] for g in res["gap"])
    assert found_rows > 0
    assert res["missed"]["visible_rows"] > 0
    # ... and every row measured came from the LLE's line or from another segment.
    assert set(res["by_source"]) == set(diagnose.SOURCES)
    assert sum(v["n"] for v in res["by_source"].values()) == found_rows
    assert res["by_source"][diagnose.SOURCES[0]]["n"] > 0
    assert all(k in diagnose.STATUS.values() or k in ("no sample", "only another surface's sample",
                                                      "a sample not kept", "visible_rows") for k in res["missed"])
    # Every frame's own line (what alacs_lle reports) is said to lie on something.
    assert sum(res["line_on"].values()) == 8
    assert set(res["line_on"]) <= {"the target", "a fragment of the target", "a neighbour", "another surface",
                                   "no line", "nothing to find"}
    # The same frames with another setting: the options reach `alacs-twin process`.
    again = diagnose.run(dataclasses.replace(cfg, process_args=("--lle-smooth-rows", "0")))
    assert again["process_args"] == ["--lle-smooth-rows", "0"]
    assert again["segments"] != res["segments"]
    text = diagnose.text(res)
    assert "worst frames:" in text and "not found, by reason:" in text and "lies on:" in text
    # `process --rows` gives each kept sample's distance from the rough position, one each,
    # all within the gate (ScanParams::gateMm, 90 mm).
    dirs = sorted(str(p) for p in (tmp_path / "benchmark-hard-3" / "lle").glob("lle_*"))
    frames = [f for r in twin.process(_twin(), dirs, 2, "rows", rows=True, quiet=True).values()
              for f in r.get("frames", [])]
    assert frames and all(evaluate.has_distances(f) for f in frames)
    assert any(f["kept"] for f in frames)
    assert all(0.0 <= d <= 90.0 + 1e-6 for f in frames for d in f["kept_from_rough_mm"])
    # The other reading of a row kept twice is printed beside; asked for, the two swap.
    assert "read by the sample nearest the rough position instead" in text
    rough = diagnose.run(dataclasses.replace(cfg, read="rough"))
    assert rough["segments"] == pytest.approx(res["other"], nan_ok=True)
    assert rough["other"] == pytest.approx(res["segments"], nan_ok=True)
    assert "a row kept twice read by the sample nearest the rough position" in diagnose.text(rough)


def test_a_few_hard_scans_are_diagnosed(tmp_path):
    cfg = diagnose.Config(world="benchmark-hard", seed=3, count=0, work=tmp_path, twin=_twin(),
                          quiet=True, worst=0)
    res = diagnose.run_loc(cfg, per_cell=1)
    assert res["scans"] == 8
    assert set(res["cells"]) == {f"{o} {d}" for o in ("clear", "occluded") for d in (1000, 1200, 1400, 1600)}
    # Every miss listed is one, worst first, and says what the fit took for the target.
    errors = [m["approach"] for m in res["misses"]]
    assert all(e > diagnose.LOC_MISS_MM for e in errors) and errors == sorted(errors, reverse=True)
    assert sum(res["misses_by_fitted"].values()) == len(res["misses"])
    assert 0.0 <= res["within20"] <= 1.0
    text = diagnose.text_loc(res)
    assert "within 20 mm" in text and "worst cases:" in text
    # Scans rendered by this build have every second-pass stop its localizer asks for; when
    # they lack some (rendered before a change to the LLE or the plan), the text says so.
    assert res["stops_missing"] == 0 and "lack" not in text
    assert "second-pass stops the scans lack: 3" in diagnose.text_loc(dict(res, stops_missing=3))
    assert sum(res["misses_by_cause"].values()) == len(res["misses"])
    # Why a scan misses, from the truth at its stops. A clear scan: its stops light the
    # target, the LLE finds most of those rows and the 3D gate keeps them.
    clear = str(sorted((tmp_path / "benchmark-hard-3" / "loc").glob("d1000_occ0_*"))[0])
    detail = twin.process(cfg.twin, [clear], 1, "rows", rows=True, quiet=True)[clear]
    scan = Scan.load(clear)
    why = worlds.miss_cause(scan, detail)
    assert why["stops_lit"] >= 3 and why["lit_rows"] >= 3 * worlds.MEASURABLE_ROWS
    assert 0.8 * why["lit_rows"] <= why["found_rows"] <= why["lit_rows"]
    assert why["kept_on"] >= 0.8 * why["lit_rows"]
    assert why["cause"] == "found, not taken"
    _check_diameter_sources(scan, detail)
    # `--diameter` takes the occluded plain spheres among the cases (here the clear scan,
    # marked as one), and refuses a set without any.
    one = {"case": "one", "dir": clear, "occluded": True, "shape": "sphere", "distance_mm": 1000}
    split = diameter.run(cfg, [one, dict(one, shape="oblate"), dict(one, occluded=False)], ())
    assert split["scans"] == 1 and split["used"] == 1
    assert split["rows"][0]["samples"] == pytest.approx(diameter.scan_sources(scan, detail)["samples"])
    assert "of which 1 with 3 lines" in diameter.text(split) and "median absolute" in diameter.text(split)
    with pytest.raises(ValueError, match="plain sphere"):
        diameter.run(cfg, [dict(one, shape="oblate")], ())
    # The aimed frame is no stop, and a frame served twice counts once.
    aimed = next(i for i, f in enumerate(scan.frames) if f.tag == "aimed")
    stops = [f for f in detail["frames"] if f["frame"] != aimed]
    assert worlds.miss_cause(scan, dict(detail, frames=stops + stops)) == why
    # Only valid samples count: rejected by the line's fit (kOutlier) or at an edge (kEdge), not.
    invalid = [dict(f, rows=[[r[0], r[1], 0, 1 + 2 * (i % 2)] for i, r in enumerate(f.get("rows", []))], arc=[])
               for f in detail["frames"]]
    assert worlds.miss_cause(scan, dict(detail, frames=invalid))["found_rows"] == 0
    # With the samples taken away, it reads as lit but not found; with the target never lit,
    # as not lit; with no frame taken at all (a refused plan), as not processed.
    blind = dict(detail, frames=[dict(f, rows=[], arc=[], kept=[]) for f in detail["frames"]])
    unseen = worlds.miss_cause(scan, blind)
    assert unseen["cause"] == "lit, not found" and unseen["found_rows"] == 0
    assert unseen["lit_rows"] == why["lit_rows"] and unseen["stops_lit"] == why["stops_lit"]

    class Dark:  # the same scan with the target hidden at every stop
        frames, target_id = scan.frames, scan.target_id

        def truth_rows(self, frame, apple_id):
            return scan.truth_rows(frame, apple_id)[:0]

    assert worlds.miss_cause(Dark(), detail)["cause"] == "not lit"
    assert worlds.miss_cause(scan, dict(detail, frames=[]))["cause"] == "not processed"
    # The listing says it for each miss.
    miss = dict(res["misses"][0]) if res["misses"] else {
        "case": "d1000_occ1_0000", "approach": 31.0, "first": 31.0, "stops": 6, "sigma": 20.0, "confidence": 18.0,
        "lines": 0, "doubt": "FAR_FROM_ROUGH", "fitted": "nothing", "rival": "none", "note": "sun"}
    miss.update(unseen)
    miss.setdefault("reach", worlds.reach_text({}))
    miss.setdefault("identity", worlds.identity_text({}))
    listed = diagnose.text_loc(dict(res, misses=[miss], misses_by_cause={unseen["cause"]: 1}))
    assert f"the target's rows lit {why['lit_rows']} (stops lit {why['stops_lit']}), found 0" in listed
    assert "why (" in listed and "lit, not found 1" in listed and "any stop lights it at" in listed
    _check_stack(cfg, clear, tmp_path)
    assert "the rough position names it at " + miss["identity"] in listed
    # Its positions, as runs of the stroke with the most rows each lights.
    assert worlds.reach_text({"lit": [[10.0, 8], [11.0, 9], [12.0, 8], [20.0, 10]]}) == \
        "10-12 mm (9 rows), 20 mm (10 rows)"
    assert worlds.reach_text({"lit": []}) == "no position"
    assert worlds.reach_text({"error": "no truth"}) == "unknown (no truth)"
    assert worlds.identity_text({"identity_pct": 96.6}) == "97 %" and worlds.identity_text({}) == "unknown"
    # The classes: a run narrower than the second pass's spacing can fall between its stops.
    assert worlds.reach_class({"positions": 0}) == worlds.REACH_CLASSES[0]
    assert worlds.reach_class({"positions": 7, "widest_run_mm": 6.0}) == worlds.REACH_CLASSES[1]
    assert worlds.reach_class({"positions": 8, "widest_run_mm": 7.0}) == worlds.REACH_CLASSES[2]
    # `alacs-twin render --truth` gives the truth at any slide position (which stops would
    # have lit a hidden fruit): at a recorded stop, the scan's own truth file.
    stop = next(f for f in scan.frames if f.laser_on and f.truth)
    out = tmp_path / "render"
    subprocess.run([str(cfg.twin), "render", "--scene", str(scan.dir / scan.truth_file), "--slide",
                    repr(stop.slide_mm), "--roi", "0,0,8,8", "--out", str(out) + ".png", "--truth",
                    str(out) + ".csv"], check=True)
    assert (scan.dir / stop.truth).read_text() == Path(str(out) + ".csv").read_text()
    assert subprocess.run([str(cfg.twin), "render", "--out", str(out) + ".png", "--truth",
                           str(tmp_path / "no" / "such.csv")], capture_output=True).returncode == 1
    # `alacs-twin reach` reads the same truth at any slide position: at the scan's stops it
    # counts the target's visible, lit rows of each stop's truth file (min-rows 1: every stop
    # that lights any), and a clear target lights 8 or more over many millimetres of stroke.
    stops = [f for f in scan.frames if f.laser_on and f.truth and f.tag != "aimed"]
    slides = ",".join(repr(f.slide_mm) for f in stops)
    got = subprocess.run([str(cfg.twin), "reach", "--slides", slides, "--min-rows", "1", "--list", clear],
                         capture_output=True, text=True, check=True).stdout
    lit = {round(p, 3): n for p, n in json.loads(got)["lit"]}
    for f in stops:
        visible = len(metrics.visible_rows(scan.truth_rows(f, scan.target_id)))
        assert lit.get(round(f.slide_mm, 3), 0) == visible, f.slide_mm
    assert sum(v > 0 for v in lit.values()) >= 3
    # The sweep covers the whole stroke, both ends included, and keeps the positions that
    # light 8 rows or more (the fit's bar): the same as every position listed at a bar of 1.
    swept = json.loads(subprocess.run([str(cfg.twin), "reach", clear], capture_output=True, text=True,
                                      check=True).stdout)
    every = json.loads(subprocess.run([str(cfg.twin), "reach", "--min-rows", "1", "--list", "--slides",
                                       ",".join(str(p) for p in range(201)), clear], capture_output=True, text=True,
                                      check=True).stdout)
    assert swept["positions"] == sum(n >= worlds.MEASURABLE_ROWS for _, n in every["lit"])
    assert swept["max_rows"] == every["max_rows"] >= max(lit.values())
    assert worlds.reach_class(swept) == worlds.REACH_CLASSES[2] and swept["widest_run_mm"] >= 20
    # A directory that is no scan, or a scan without its truth, is named in its line; options
    # out of range are refused.
    bad = subprocess.run([str(cfg.twin), "reach", str(tmp_path)], capture_output=True, text=True)
    assert bad.returncode == 0 and "manifest" in json.loads(bad.stdout)["error"]
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "manifest.json").write_text("{not json")
    broken = subprocess.run([str(cfg.twin), "reach", str(tmp_path / "broken")], capture_output=True, text=True)
    assert broken.returncode == 0 and "error" in json.loads(broken.stdout)
    assert subprocess.run([str(cfg.twin), "reach", "--step-mm", "0", clear], capture_output=True).returncode == 2
    _check_identity(cfg.twin, Path(clear), tmp_path / "identity")


def _check_identity(twin_bin: Path, clear: Path, work: Path):
    """`alacs-twin reach`'s identity_pct: how surely the rough position names the target for an
    observer who knows every fruit's centre. A rough position on the target names it; one on
    a fruit 300 mm away names that fruit, one halfway either; a scan without one says nothing."""
    shutil.copytree(clear, work)
    manifest, scene_file = work / "manifest.json", work / json.loads((work / "manifest.json").read_text())["scan"]["truth"]
    m, scene = json.loads(manifest.read_text()), json.loads(scene_file.read_text())
    target = next(a for a in scene["apples"] if a["id"] == m["scan"]["target_id"])
    far = dict(target, id=max(a["id"] for a in scene["apples"]) + 1,
               center_mm=[target["center_mm"][0] + 300.0, *target["center_mm"][1:]])
    scene["apples"] = [target, far]  # (the neighbours out: they would weigh in between)
    scene_file.write_text(json.dumps(scene))

    def identity(rough):
        m["scan"]["rough_mm"] = rough
        if rough is None:
            del m["scan"]["rough_mm"]
        manifest.write_text(json.dumps(m))
        line = json.loads(subprocess.run([str(twin_bin), "reach", str(work)], capture_output=True, text=True,
                                         check=True).stdout)
        assert "error" not in line, line
        return line["identity_pct"]

    assert identity(target["center_mm"]) == pytest.approx(100.0, abs=0.5)
    assert identity(far["center_mm"]) < 0.01
    halfway = [(a + b) / 2.0 for a, b in zip(target["center_mm"], far["center_mm"])]
    assert identity(halfway) == pytest.approx(50.0, abs=0.01)
    assert identity(None) is None
    # The report's sum: the expected confusions, the best share within 20 mm they leave, and the
    # misses whose target the rough position names surely.
    rows = [{"identity_pct": 100.0, "approach": 1.0}, {"identity_pct": 50.0, "approach": 40.0},
            {"identity_pct": 99.0, "approach": math.nan}, {"identity_pct": None, "approach": 2.0}]
    assert worlds.identity_summary(rows) == {"n": 3, "expected_confusions": pytest.approx(0.51),
                                             "best_within20": pytest.approx(1.0 - 0.51 / 3), "misses": 2,
                                             "misses_named": 1}


def _check_stack(cfg, clear, tmp_path):
    """`diagnose --loc --stack`: every frame of a scan is rendered again from its scene at
    the recorded slide, exposure, laser and crop, with fresh noise, and the copy replays."""
    case = {"case": "one", "dir": clear, "occluded": True, "distance_mm": 1000}
    manifest = json.loads((Path(clear) / "manifest.json").read_text())
    jobs = stack.render_jobs(Path(clear), tmp_path / "x", 3, 0.0)
    assert len(jobs) == len(manifest["frames"])
    f0, j0 = manifest["frames"][0], jobs[0]
    gain = json.loads((Path(clear) / "truth" / "scene.json").read_text())["sensor"]["gain_db"]
    assert j0[j0.index("--exposure-us") + 1] == str(round(f0["exposure_us"] * 10 ** (gain / 20)))
    assert j0[j0.index("--average") + 1] == "3" and j0[j0.index("--gain-db") + 1] == "0.0"
    assert j0[j0.index("--roi") + 1] == ",".join(map(str, f0["crop_px"]))
    dirs = stack.render_set(cfg.twin, [case], tmp_path / "stack2", 2, None, 2, True)
    again = Scan.load(dirs[0])
    assert [f.file for f in again.frames] == [f.file for f in Scan.load(clear).frames]
    for f in again.frames[:3]:
        new = np.asarray(Image.open(Path(dirs[0]) / f.file), dtype=np.float64)
        old = np.asarray(Image.open(Path(clear) / f.file), dtype=np.float64)
        assert new.shape == old.shape
        assert np.any(new != old)  # fresh noise ...
        assert abs(float(new.mean()) - float(old.mean())) < 1.0  # ... of the same scene
    # Reused when asked again with the same arguments (the frames are not rendered anew).
    stamp = (Path(dirs[0]) / again.frames[0].file).stat().st_mtime_ns
    assert stack.render_set(cfg.twin, [case], tmp_path / "stack2", 2, None, 2, True) == dirs
    assert (Path(dirs[0]) / again.frames[0].file).stat().st_mtime_ns == stamp
    raw = twin.process(cfg.twin, dirs, 1, "stacked", quiet=True)
    rows = stack._errors(raw, dirs, [case])
    assert rows[0]["ok"] and rows[0]["approach"] < diagnose.LOC_MISS_MM
    s = stack.summary(rows)
    assert s["within20"] == 1 and s["scans"] == 1 and s["confident_misses"] == 0
    for frames in (1, stack.MAX_FRAMES + 1):
        with pytest.raises(ValueError, match="--stack wants"):
            stack.run(cfg, 1, frames)


def test_the_stacking_summary_counts_what_it_says(tmp_path, capsys):
    """`diagnose --stack`: the occluded sunlit cases are chosen by the set's light (else the
    scan's note), a moving frame is refused, and the summary and text count misses,
    confident misses and second-pass stops lacking as they are."""
    cases = [{"dir": "a", "occluded": True, "lighting": "sun"}, {"dir": "b", "occluded": False, "lighting": "sun"},
             {"dir": "c", "occluded": True, "lighting": "direct"}]
    assert stack.sunlit_occluded(cases) == cases[:1]
    scan = tmp_path / "moving"
    (scan / "truth").mkdir(parents=True)
    (scan / "truth" / "scene.json").write_text(json.dumps({"sensor": {"gain_db": 6.0}}))
    frame = {"file": "frames/frame_0000.png", "slide_mm": 10.0, "exposure_us": 100, "laser_on": True}
    (scan / "manifest.json").write_text(json.dumps({"scan": {}, "frames": [frame]}))
    assert len(stack.render_jobs(scan, tmp_path / "out", 2, None)) == 1
    (scan / "manifest.json").write_text(json.dumps(
        {"scan": {}, "frames": [dict(frame, slide_start_mm=9.0, slide_end_mm=11.0)]}))
    with pytest.raises(ValueError, match="moved"):
        stack.render_jobs(scan, tmp_path / "out", 2, None)
    row = {"case": "x", "distance": 1000, "ok": True, "approach": 1.0, "sigma": 1.0, "confidence": 90.0,
           "lines": 5, "stops_missing": 0}
    rows = [row, dict(row, case="y", approach=30.0, confidence=85.0, stops_missing=2),
            dict(row, case="z", distance=1600, ok=False, approach=math.nan, confidence=0.0)]
    s = stack.summary(rows)
    assert (s["scans"], s["results"], s["within20"], s["confident_misses"], s["stops_missing"]) == (3, 2, 1, 1, 2)
    assert s["within2sigma"] == 1 and s["cells"][1000] == pytest.approx(15.5) and math.isnan(s["cells"][1600])
    res = {"world": "benchmark-hard", "seed": 3, "gain_db": 0.0, "sets": {"stored": s, "2 frames": s},
           "rows": {"stored": rows, "2 frames": rows}}
    text = stack.text(res)
    assert "the sensor at 0 dB" in text and "within 20 mm 1 of 3" in text and "confident misses 1" in text
    assert "  y: stored 30.0 mm, 5 lines, 85 %, 2" in text and "  x:" not in text
    # The command line: --stack goes with --loc alone, and its gain with it.
    for bad in (["--stack", "2"], ["--loc", "--diameter", "--stack", "2"], ["--loc", "--stack-gain-db", "0"]):
        assert cli.main(["diagnose", *bad, "--work", str(tmp_path / "w"), "--twin", str(_twin())]) == 2
        assert "--stack" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()


def test_rendered_frames_averaged_have_less_noise(tmp_path):
    """`alacs-twin render --average N` averages N frames of their own noise (without the
    laser, the noise of the difference of two such renders falls by about the square root
    of N, to the 8-bit rounding) and of one speckle (a laser at rest keeps its speckle:
    averaging does not smooth it, as it would if each frame drew its own); `--gain-db` with
    the exposure scaled keeps the level and lowers the noise; bad values are refused."""
    tw = str(_twin())
    common = ["render", "--roi", "900,600,256,256", "--exposure-us", "3000"]

    def frame(*extra):
        out = tmp_path / f"f{len(list(tmp_path.iterdir()))}.png"
        subprocess.run([tw, *common, *extra, "--out", str(out)], check=True, capture_output=True)
        return np.asarray(Image.open(out), dtype=np.float64)[:, :, 0]  # red

    dark = ("--laser", "0")
    one = frame(*dark, "--frame", "0") - frame(*dark, "--frame", "500")
    four = frame(*dark, "--frame", "0", "--average", "4") - frame(*dark, "--frame", "500", "--average", "4")
    assert 0.45 < four.std() / one.std() < 0.7, four.std() / one.std()
    assert abs(four.mean()) < 0.2 and abs(one.mean()) < 0.2
    long = str(round(3000 * 10 ** (6 / 20)))  # the scene's 6 dB
    zero = frame(*dark, "--frame", "0", "--gain-db", "0", "--exposure-us", long)
    assert abs(zero.mean() - frame(*dark, "--frame", "0").mean()) < 0.5
    z = frame(*dark, "--frame", "7", "--gain-db", "0", "--exposure-us", long) - zero
    assert z.std() < 0.8 * one.std()
    # On the line: the averaged frames keep the first frame's speckle.
    a, b = frame("--frame", "0", "--average", "4"), frame("--frame", "500", "--average", "4")
    line = a - frame(*dark) > 30
    redrawn = (np.mean([frame("--frame", str(i)) for i in range(4)], axis=0)
               - np.mean([frame("--frame", str(i)) for i in range(500, 504)], axis=0))
    assert line.sum() > 300
    assert (a - b)[line].std() > 1.5 * redrawn[line].std()
    for bad in (["--average", "0"], ["--average", "65"], ["--gain-db", "49"]):
        r = subprocess.run([tw, *common, *bad, "--out", str(tmp_path / "bad.png")], capture_output=True, text=True)
        assert r.returncode == 2 and "alacs-twin render" in r.stderr


def _check_diameter_sources(scan, detail):
    """`diagnose --loc --diameter` on a clear scan: the kept samples it takes for the target's
    lie where the truth's points are, and samples moved off the line are none of its."""
    measured, exact = diameter.target_samples(scan, detail)
    assert len(measured) == len(exact) >= 3 * worlds.MEASURABLE_ROWS
    centre, radius, _ = target_truth(scan)
    # The truth's points are the target's surface (a spheroid: within its aspect of the radius).
    assert np.median(np.abs(np.linalg.norm(exact - centre, axis=1) - radius)) < 0.15 * radius
    # Triangulated as the sensor does, a sample lies within a millimetre of its truth point.
    assert np.median(np.linalg.norm(measured - exact, axis=1)) < 1.0
    src = diameter.scan_sources(scan, detail)
    assert src is not None and src["samples_n"] == len(measured)
    assert abs(src["exact"]) < 10.0 and abs(src["samples"]) < 10.0
    moved = dict(detail, frames=[dict(f, kept=[[r, c + 3.0 * diameter.BAND_PX] for r, c in f.get("kept", [])])
                                 for f in detail["frames"]])
    assert len(diameter.target_samples(scan, moved)[0]) < 0.1 * len(measured)
    # The stops only: the aimed frame (which the five-line result does not use) adds nothing,
    # and a frame served twice counts once.
    aimed = [f for f in detail["frames"] if scan.frames[f["frame"]].tag == "aimed"]
    assert aimed and any(f.get("kept") for f in aimed)
    stops = [f for f in detail["frames"] if scan.frames[f["frame"]].tag != "aimed"]
    assert np.array_equal(diameter.target_samples(scan, dict(detail, frames=stops + stops))[0], measured)
    # Too few lines in the sensor's fit, or too few samples on the target: left out.
    assert diameter.scan_sources(scan, dict(detail, multi={"ok": True, "lines_used": 2})) is None
    few = [dict(f, kept=f.get("kept", [])[:2]) for f in detail["frames"]]
    assert diameter.scan_sources(scan, dict(detail, frames=few)) is None


def test_the_sphere_fit_of_the_diameter_diagnosis_finds_a_known_cap():
    rng = np.random.default_rng(7)
    centre, radius = np.array([30.0, -20.0, 1200.0]), 36.0
    # An off-axis patch about 50 degrees across, facing the camera (z is away from it): the
    # part of a fruit that lines past a leaf see.
    theta = rng.uniform(0.2, 1.0, 400)
    phi = rng.uniform(-0.6, 0.6, 400)
    normal = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)], axis=1)
    cap = centre + radius * normal
    c, r = diameter.fit_sphere(cap, centre + [5.0, 5.0, 10.0], 45.0, huber_mm=0.0)
    assert abs(r - radius) < 1e-6 and np.linalg.norm(c - centre) < 1e-6
    # Noise and a few far samples (a leaf's): the Huber fit stays near, least squares does not.
    noisy = cap + rng.normal(0.0, 0.2, cap.shape)
    noisy[:20] -= 8.0 * normal[:20]
    _, r_huber = diameter.fit_sphere(noisy, centre, 40.0)
    _, r_lsq = diameter.fit_sphere(noisy, centre, 40.0, huber_mm=0.0)
    assert abs(r_huber - radius) < 0.5 * abs(r_lsq - radius)
    assert abs(r_huber - radius) < 1.0


def test_two_builds_side_by_side_each_on_its_own_second_pass(tmp_path):
    tw = _twin()
    cfg = diagnose.Config(world="benchmark-hard", seed=3, count=0, work=tmp_path, twin=tw, quiet=True, worst=0)
    # The same build against itself: nothing moves, and its figures are diagnose --loc's.
    same = compare.run(cfg, tw, per_cell=1)
    assert same["changed"] == [] and same["summary"]["against"] == same["summary"]["this build"]
    assert same["rendered_again"] == {"against": 0, "this build": 0}
    alone = diagnose.run_loc(cfg, per_cell=1)
    mine = same["summary"]["this build"]
    assert mine["scans"] == alone["scans"] == 8 and mine["no_result"] == alone["no_result"]
    assert mine["within20"] == round(alone["within20"] * 8)
    assert mine["cells"] == pytest.approx(alone["cells"], nan_ok=True)
    # A build whose second pass goes elsewhere (a fit more than 1σ of the rough position's
    # error from it counts as far, and the new stops go round the rough position): its scans
    # are rendered again, by it, into a directory of its own, and then lack no stop; the
    # scans of this build's set are left as they were.
    other = tmp_path / "other-twin"
    other.write_text(f"#!/bin/sh\ncmd=$1; shift\ncase $cmd in generate|process) exec {tw} $cmd "
                     f"--follow-up-far-sigmas 1 \"$@\";; esac\nexec {tw} $cmd \"$@\"\n")
    other.chmod(0o755)
    before = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "benchmark-hard-3" / "loc").glob("d*/manifest.json")}
    res = compare.run(cfg, other, per_cell=1)
    assert res["rendered_again"]["against"] > 0 and res["rendered_again"]["this build"] == 0
    assert res["stops_lacking"] == {"against": 0, "this build": 0}
    assert len(list((tmp_path / "benchmark-hard-3" / "loc-against").glob("d*"))) == res["rendered_again"]["against"]
    after = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "benchmark-hard-3" / "loc").glob("d*/manifest.json")}
    assert after == before
    assert res["summary"]["this build"] == mine
    text = compare.text(res)
    assert "second passes rendered again" in text and f"rendered again (the build asked for stops the scans " \
        f"lack): against {res['rendered_again']['against']}, this build 0" in text
    assert "still lacking" not in text


def test_a_build_that_is_no_twin_is_refused_with_a_reason(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(twin, "generate", lambda *a, **k: [{"case": "d1000_occ0_0000", "dir": str(tmp_path / "x")}])
    for against, why in (("/bin/true", "gave no result line for 1 of 1 scans"), ("/bin/false", "failed with status 1"),
                         ("", "--against needs")):
        assert cli.main(["diagnose", "--loc", "--per-cell", "1", "--work", str(tmp_path), "--twin", "/bin/true",
                         "--against", against]) == 2
        assert why in capsys.readouterr().err


def test_the_two_builds_summary_counts_what_it_says():
    rows = {"d1000_occ1_0000": {"approach": 25.0, "sigma": 10.0, "confidence": 85.0},
            "d1000_occ1_0001": {"approach": 3.0, "sigma": 1.0, "confidence": 90.0},
            "d1600_occ0_0000": {"approach": 1.0, "sigma": 1.0, "confidence": 99.0},
            "d1600_occ0_0001": None}
    s = compare.summary(rows)
    assert (s["scans"], s["no_result"], s["within20"], s["within2sigma"], s["confident_misses"]) == (4, 1, 2, 1, 1)
    assert s["cells"]["occluded 1000"] == 14.0 and s["cells"]["clear 1600"] == 1.0
    assert math.isnan(s["cells"]["clear 1000"])
    after = dict(rows, d1000_occ1_0001={"approach": 5.5, "sigma": 1.0, "confidence": 90.0},
                 d1600_occ0_0000={"approach": 2.9, "sigma": 1.0, "confidence": 99.0},
                 d1600_occ0_0001={"approach": 2.0, "sigma": 1.0, "confidence": 99.0})
    assert [c["case"] for c in compare.changed(rows, after)] == ["d1000_occ1_0001", "d1600_occ0_0001"]


def test_a_generator_option_reaches_the_render_and_the_processing(tmp_path, monkeypatch, capsys):
    # --follow-up-unseen-max-stops changes which second-pass stops are rendered: it goes to
    # `alacs-twin generate` (so the set's signature changes and it is rendered again) and
    # to `process`, ahead of the options after `--`.
    seen = {}

    def generate(tw, out, set_name, args, total, desc, quiet=False, sources=()):
        seen["generate"] = dict(args)
        return []

    def process(tw, dirs, jobs, desc, quiet=False, extra=()):
        seen["process"] = list(extra)
        return {}

    monkeypatch.setattr(twin, "generate", generate)
    monkeypatch.setattr(twin, "process", process)
    monkeypatch.setattr(twin, "find_twin", lambda t: t)
    rc = cli.main(["diagnose", "--loc", "--per-cell", "1", "--work", str(tmp_path), "--twin", "/bin/true",
                   "--follow-up-unseen-max-stops", "32", "--", "--fit-when-far-from-rough"])
    assert rc == 0
    assert seen["generate"]["follow-up-unseen-max-stops"] == "32"
    assert seen["process"] == ["--follow-up-unseen-max-stops", "32", "--fit-when-far-from-rough"]
    assert "results (--follow-up-unseen-max-stops 32 --fit-when-far-from-rough)" in capsys.readouterr().out


def test_the_matched_filter_prototype_follows_a_faint_line_and_not_noise():
    """`diagnose --matched-filter`'s prototype: a line of 8 DN over a 6 px profile in noise
    of 2 DN (a peak 4 times the noise, where the LLE found 41 % of the sunlit rows of the hard
    cases' seed 3, docs/lle.md) is found on most rows at its column; the same noise alone
    seeds hardly a row."""
    rng = np.random.default_rng(5)
    rows, cols = 200, 120
    noise = rng.normal(0.0, 2.0, (rows, cols))
    truth = 60.0 + 0.1 * np.arange(rows)  # a gently slanted line
    x = np.arange(cols)[None, :]
    line = 8.0 * np.exp(-0.5 * ((x - truth[:, None]) / 1.5) ** 2)
    found = diagnose._mf_columns(noise + line)
    on_line = sum(abs(c - truth[y]) <= 2.0 for y, c in found.items())
    assert on_line >= 0.8 * rows, on_line
    assert len(found) - on_line <= 0.05 * rows
    assert len(diagnose._mf_columns(noise)) <= 0.05 * rows


def test_a_second_exposure_in_sun_is_recorded_by_the_generator_and_merged_by_process(tmp_path):
    # metering.second_exposure_factor through the twin: `generate` records a laser-off frame
    # at the second exposure and a second laser frame (tag "second") at every stop of both
    # passes, at the stop's position; `process` merges each into its stop's frame, and with
    # the factor 0 replays the same scan with one exposure a stop.
    tw = _twin()
    out = tmp_path / "set"
    subprocess.run([str(tw), "generate", "--set", "loc", "--out", str(out), "--world", "benchmark-hard",
                    "--count", "1", "--distance-mm", "1200", "--occluded", "1", "--lighting", "sun", "--seed", "5",
                    "--meter-second-exposure", "2"], check=True, capture_output=True)
    (case,) = [json.loads(line) for line in (out / "set.jsonl").read_text().splitlines()]
    first_us, second_us = case["laser_exposure_us"], case["second_exposure_us"]
    assert second_us == min(3000, 2 * first_us)
    frames = json.loads((Path(case["dir"]) / "manifest.json").read_text())["frames"]
    stops = [f for f in frames if f.get("tag") in ("stop", "follow_up")]
    seconds = [f for f in frames if f.get("tag") == "second"]
    assert len(stops) >= 5 and len(seconds) == len(stops)
    assert all(f["laser_on"] and f["exposure_us"] == second_us for f in seconds)
    assert sorted(f["slide_mm"] for f in seconds) == pytest.approx(sorted(f["slide_mm"] for f in stops))
    assert any(not f["laser_on"] and f["exposure_us"] == second_us for f in frames)

    def processed(factor: str) -> dict:
        run = subprocess.run([str(tw), "process", case["dir"], "--meter-second-exposure", factor], check=True,
                             capture_output=True, text=True)
        return json.loads(run.stdout)

    two, one = processed("2"), processed("0")
    assert two["second_exposure_us"] == second_us and "second_exposure_us" not in one
    assert two["laser_off_frames"] == one["laser_off_frames"] + 1
    by_index = {i: f for i, f in enumerate(frames)}
    taken = [f for f in two["frames"] if f["tag"] in ("stop", "follow_up")]
    assert len(taken) == len(stops)
    for f, g in zip(taken, [f for f in one["frames"] if f["tag"] in ("stop", "follow_up")]):
        # The second frame is the stop's own at the second exposure; its rows only add.
        second = by_index[f["second_frame"]]
        assert second["tag"] == "second" and second["slide_mm"] == pytest.approx(by_index[f["frame"]]["slide_mm"])
        assert f["frame"] == g["frame"]
        assert f["points"] == g["points"] + f["second_joined"]
    assert sum(f["second_joined"] for f in taken) > 0
    assert all("second_frame" not in f for f in one["frames"])
