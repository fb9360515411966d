"""The evaluation's metrics and camera model against hand-made cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from alacs_eval import metrics, paper_method
from alacs_eval.camera import Calibration
from alacs_eval.paper_line import PaperLine

TRUTH_DTYPE = [("row", int), ("column", float), ("x", float), ("y", float), ("z", float), ("flags", int)]


def truth(rows, cols, flags=None) -> np.ndarray:
    flags = flags if flags is not None else [0] * len(rows)
    return np.array([(r, c, 0, 0, 0, f) for r, c, f in zip(rows, cols, flags)], dtype=TRUTH_DTYPE)


def test_segments_are_central_shares_of_the_visible_rows():
    rows = np.arange(100, 201)  # span 100 rows, centre 150
    t = truth(rows, np.full(len(rows), 50.0))
    # Predict 1 px off near the centre, 10 px off at the ends: the 10 % segment sees only 1 px.
    d = metrics.segment_displacements(t, lambda r: 50.0 + np.where(np.abs(r - 150) <= 20, 1.0, 10.0))
    assert d[10] == pytest.approx(1.0)
    assert d[40] == pytest.approx(1.0)
    assert d[80] > 3.0
    assert metrics.segment_displacements(t, None)[50] != metrics.segment_displacements(t, None)[50]  # NaN


def test_hidden_rows_do_not_count_and_shorten_the_line():
    rows = np.arange(0, 100)
    flags = [0] * 60 + [1] * 40  # the lower 40 rows hidden by a leaf
    t = truth(rows, np.zeros(100), flags)
    # The visible line spans rows 0-59: its 10 % centre is around row 29.5.
    d = metrics.segment_displacements(t, lambda r: np.where(np.abs(r - 29.5) <= 3, 0.0, 100.0), segments=(10,))
    assert d[10] == 0.0


def test_a_line_counts_only_where_it_was_found():
    rows = np.arange(0, 101)
    t = truth(rows, np.full(len(rows), 20.0))
    # A line found only over rows 50-100, exact there: no displacement, half the 80 % segment covered.
    seg = metrics.segment_metrics(t, lambda r: np.where(r >= 50, 20.0, np.nan), segments=(80, 10))
    d80, c80 = seg[80]
    assert d80 == 0.0
    assert c80 == pytest.approx(41 / 81, abs=1e-9)
    assert seg[10][1] == pytest.approx(6 / 11)  # rows 45-55 around the centre, 50-55 found


def test_loc_stats_count_missing_results_as_failures():
    s = metrics.loc_stats([1.0, 3.0, 25.0, math.nan])
    assert s.mean == pytest.approx(29.0 / 3)
    assert s.success == pytest.approx(0.5)
    assert s.no_result == 1


def calibration() -> Calibration:
    n = np.array([0.985, -0.02, 0.165])
    n /= np.linalg.norm(n)
    return Calibration(2048, 1536, 2400.0, 2402.0, 1026.3, 765.8, (-0.08, 0.12, 5e-4, -3e-4, 0.0), n, 102.0,
                       np.array([1.0, 0.012, 0.004]) / np.linalg.norm([1.0, 0.012, 0.004]), 1.003)


def test_undistort_inverts_project_and_triangulation_lands_on_the_plane():
    cal = calibration()
    rng = np.random.default_rng(2)
    pts = np.column_stack([rng.uniform(-500, 500, 50), rng.uniform(-400, 400, 50), rng.uniform(800, 1800, 50)])
    px = cal.project(pts)
    xn = cal.undistort(px)
    assert np.allclose(xn, pts[:, :2] / pts[:, 2:3], atol=1e-10)
    slide = 80.0
    on_plane = cal.triangulate(px, slide)
    assert np.allclose(on_plane @ cal.normal, cal.plane_offset(slide))


def test_paper_candidate_prefers_long_lines_near_the_expected_centre():
    cal = calibration()
    long_far = PaperLine(np.arange(0, 200.0), np.full(200, 10.0), np.array([0, 0, 0, 0, 10.0]), 200)
    short_near = PaperLine(np.arange(0, 40.0), np.full(40, 100.0), np.array([0, 0, 0, 0, 100.0]), 40)
    roi = (900, 600, 300, 300)
    expected = (1000.0, 620.0)
    a = paper_method.candidate(long_far, roi, 50.0, expected)
    b = paper_method.candidate(short_near, roi, 70.0, expected)
    assert a.n == 200 and b.n == 40
    assert a.middle_px == (910.0, 700.0)
    # P = N - 2 Δd: 200 - 2·hypot(90, 80) ≈ -40.8 against 40 - 2·0 = 40.
    assert b.score > a.score
    est = paper_method.localize([a, b, None], cal)
    assert est is not None
    face, centre = est
    assert abs(face @ cal.normal - cal.plane_offset(70.0)) < 1e-6
    assert np.linalg.norm(centre - face) == pytest.approx(paper_method.NOMINAL_RADIUS_MM)


def test_confidence_against_error_strict_within_noise_and_by_rank():
    from alacs_eval import worlds

    rng = np.random.default_rng(1)
    conf = rng.uniform(0, 100, 400)

    def cov(errors):
        return worlds.coverage([{"approach": float(e), "sigma": 2.0, "confidence": float(c)}
                                for c, e in zip(conf, errors)])

    # Error falling with confidence: monotone by every measure, strongly negative rank correlation.
    falling = cov((100 - conf) / 10 + rng.normal(0, 0.3, conf.size))
    assert falling["confidence_monotone"] and falling["confidence_monotone_2se"]
    assert falling["confidence_spearman"] < -0.9
    # Error rising with confidence: refused by every measure.
    rising = cov(conf / 10 + rng.normal(0, 0.3, conf.size))
    assert not rising["confidence_monotone"] and not rising["confidence_monotone_2se"]
    assert rising["confidence_spearman"] > 0.9
    # Errors unrelated to the confidence: no rise beyond noise, and no rank correlation either.
    noise = cov(rng.exponential(1.0, conf.size))
    assert noise["confidence_monotone_2se"]
    assert abs(noise["confidence_spearman"]) < 0.15


def test_a_target_without_visible_rows_has_nothing_to_find():
    # Leaves hide every row the line crosses: no displacement and no share found (NaN), so the
    # frame is left out of the mean share found rather than counted as 0 %.
    rows = np.arange(0, 50)
    hidden = truth(rows, np.full(len(rows), 20.0), [1] * len(rows))
    seg = metrics.segment_metrics(hidden, lambda r: np.full(len(r), 20.0), segments=(50,))
    assert math.isnan(seg[50][0]) and math.isnan(seg[50][1])
    # With rows to find and no line, it is a miss.
    seen = truth(rows, np.full(len(rows), 20.0))
    assert metrics.segment_metrics(seen, None, segments=(50,))[50][1] == 0.0
    assert metrics.mean_found([1.0, 0.0, math.nan]) == pytest.approx(0.5)
    assert math.isnan(metrics.mean_found([math.nan]))


def test_the_line_alone_reads_the_lle_line_not_the_gated_samples():
    """worlds' reading of `alacs_lle`'s `line`: only its valid rows count, not the other
    segments the localizer's 3D gate keeps, so a row the line leaves to another surface is
    read on the line or not at all."""
    from alacs_eval import evaluate, worlds

    rows = np.arange(100, 140)
    t = truth(rows, np.full(len(rows), 50.0))
    # The line lies on the target in rows 100-119 and on another surface (8 px off) in
    # 120-139; a segment kept by the gate lies on the target in 120-139.
    line = [[int(r), 50.0 if r < 120 else 58.0, 1, 0] for r in rows]
    other = [[int(r), 50.0, 0, 2] for r in rows if r >= 120]
    raw = {"frames": [{"rows": line + other, "kept": [[s[0], s[1]] for s in other + line]}]}
    gated = evaluate._ours_lle({"d": raw}, {"d": t})["d"]
    alone = evaluate._ours_lle({"d": worlds._as_line_alone(raw)}, {"d": t})["d"]
    # Gated, a row with both reads the line's sample: the same 8 px where the line is off.
    # Alone, only the line's rows are there, and they are what is read.
    assert alone["disp"][80] == pytest.approx(gated["disp"][80])
    assert alone["cover"][80] == pytest.approx(1.0)
    # Rows whose line sample is invalid are not the line's: dropped from the reading.
    raw_invalid = {"frames": [{"rows": [[s[0], s[1], 0 if s[0] >= 120 else 1, s[3]] for s in line] + other,
                               "kept": [[s[0], s[1]] for s in other + line]}]}
    alone_invalid = evaluate._ours_lle({"d": worlds._as_line_alone(raw_invalid)}, {"d": t})["d"]
    assert alone_invalid["disp"][80] == pytest.approx(0.0)
    assert alone_invalid["cover"][80] == pytest.approx(0.5)
    gated_invalid = evaluate._ours_lle({"d": raw_invalid}, {"d": t})["d"]
    assert gated_invalid["cover"][80] == pytest.approx(1.0)


def test_a_row_kept_twice_reads_the_sample_nearest_the_rough_position():
    """evaluate.kept_rows by the rough position: where the 3D gate keeps the line's sample and
    another segment's in one row, the one nearer the rough position is read (the product's
    prior, not the truth); by the line, the line's; a row kept once reads alike either way."""
    from alacs_eval import evaluate, worlds

    rows = np.arange(100, 140)
    t = truth(rows, np.full(len(rows), 50.0))
    # The line lies on a leaf (12 px off, 20 mm nearer the camera) in every row; in 100-109
    # the target's own segment is kept too, nearer the rough position.
    line = [[int(r), 62.0, 1, 0] for r in rows]
    target = [[int(r), 50.0, 0, 2] for r in rows if r < 110]
    kept = [[s[0], s[1]] for s in line + target]
    raw = {"frames": [{"rows": line + target, "kept": kept,
                       "kept_from_rough_mm": [55.0] * len(line) + [35.0] * len(target)}]}
    by_line = evaluate.kept_rows(raw["frames"][0], evaluate.BY_LINE)
    by_rough = evaluate.kept_rows(raw["frames"][0], evaluate.BY_ROUGH)
    assert by_line[105] == (62.0, True)
    assert by_rough[105] == (50.0, False)
    assert by_line[120] == by_rough[120] == (62.0, True)
    # Nearest, not "another segment first": where the line's sample is the nearer, it is read;
    # a tie goes to the line; a distance the JSON could not carry (null) is the farthest.
    other = [[130, 40.0, 0, 2], [131, 40.0, 0, 2], [132, 40.0, 0, 2]]
    near_line = {"rows": line + other, "kept": [[s[0], s[1]] for s in line + other],
                 "kept_from_rough_mm": [55.0] * len(line) + [70.0, 55.0, None]}
    read = evaluate.kept_rows(near_line, evaluate.BY_ROUGH)
    assert read[130] == read[131] == read[132] == (62.0, True)
    null_line = {**near_line, "kept_from_rough_mm": [None] * len(line) + [70.0, 55.0, 60.0]}
    assert evaluate.kept_rows(null_line, evaluate.BY_ROUGH)[130] == (40.0, False)
    assert worlds._read_apart(raw["frames"][0])
    # Without the distances (an older `process`), by the rough position falls back to the line.
    plain = {"frames": [{"rows": line + target, "kept": kept}]}
    assert evaluate.kept_rows(plain["frames"][0], evaluate.BY_ROUGH) == by_line
    assert not worlds._read_apart(plain["frames"][0])
    near = evaluate._ours_lle({"d": raw}, {"d": t}, evaluate.BY_ROUGH)["d"]
    far = evaluate._ours_lle({"d": raw}, {"d": t})["d"]
    assert near["disp"][80] < far["disp"][80] == pytest.approx(12.0)


def test_the_fitted_diameter_leaves_out_the_priors_echo():
    """worlds: a result without a sphere fit (ROUGH_ONLY: the rough position or one line's
    arc) carries the prior's diameter, never a measurement; the mean over sphere fits leaves it out
    and the table counts it, while the mean of every result keeps it."""
    from alacs_eval import worlds

    fit = {"shape": "sphere", "occluded": True, "diameter": 2.0, "sphere": True, "lines": 4}
    echo = {"shape": "sphere", "occluded": True, "diameter": 14.0, "sphere": False, "lines": 0}
    one_line = {"shape": "sphere", "occluded": True, "diameter": 10.0, "sphere": False, "lines": 1}
    none = {"shape": "sphere", "occluded": True, "diameter": math.nan, "sphere": False, "lines": 0}
    assert [worlds._rough_only(r) for r in (fit, echo, one_line, none)] == [False, True, True, False]
    assert [worlds._fitted_diameter(r) for r in (fit, echo, one_line, none)] == [True, False, False, False]
    cell = worlds.diameter_by_shape([fit, echo, one_line, none])["sphere"]
    assert cell["occluded"] == pytest.approx(26.0 / 3) and cell["occluded_n"] == 3
    assert cell["occluded_fitted"] == pytest.approx(2.0) and cell["occluded_fitted_n"] == 1
    assert math.isnan(cell["clear_fitted"]) and cell["clear_fitted_n"] == 0
