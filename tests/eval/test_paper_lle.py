"""The paper's LLE (tools/eval fallback) on synthetic frames: where the line is, what
noise removal clears, and why the printed Algorithm 1 needed a reading."""

from __future__ import annotations

import numpy as np

from alacs_eval.paper_lle_fallback import brce, focus, paper_lle, remove_noise


def line_image(h: int = 120, w: int = 160, sigma: float = 1.2, peak: float = 150.0, bg: float = 40.0,
               column=lambda r: 70.0 + 0.1 * r) -> np.ndarray:
    rows, cols = np.mgrid[0:h, 0:w]
    red = bg + peak * np.exp(-0.5 * ((cols - column(rows)) / sigma) ** 2)
    img = np.zeros((h, w, 3), np.uint8)
    img[..., 0] = np.clip(np.round(red), 0, 255)
    img[..., 1] = 30
    return img


def test_brce_marks_pixels_brighter_than_both_neighbours():
    red = np.array([[10, 10, 10, 10, 100, 10, 10, 10, 10]], np.uint8)
    m = brce(red, step=4, th=40)
    assert m.tolist() == [[0, 0, 0, 0, 1, 0, 0, 0, 0]]
    # A step edge is not a line: only one neighbour is darker.
    edge = np.array([[10] * 6 + [200] * 6], np.uint8)
    assert brce(edge, step=2, th=40).sum() == 0


def test_literal_algorithm_wraps_on_uint8_and_fires_on_flat_noise():
    rng = np.random.default_rng(1)
    flat = (100 + rng.integers(-3, 4, size=(50, 80))).astype(np.uint8)
    assert brce(flat, 4, 40, "meaning").sum() == 0
    # As printed, neighbour - centre on uint8: a centre 1 DN brighter wraps to 255 > th.
    assert brce(flat, 4, 40, "literal").mean() > 0.1


def test_noise_removal_clears_sparse_windows_and_keeps_the_line():
    g = np.zeros((100, 200), np.uint8)
    g[:, 120] = 1            # a line: 100 pixels in one column
    g[10, 20] = g[60, 30] = 1  # two specks
    c = remove_noise(g, theta=8, gamma=3)
    assert c[:, 120].sum() == 100
    assert c[10, 20] == 0 and c[60, 30] == 0


def test_paper_lle_finds_a_clean_line_to_a_fraction_of_a_pixel():
    img = line_image()
    line = paper_lle(img)
    assert line.coeffs is not None
    rows = np.arange(10, 110)
    err = np.abs(line.column_at(rows) - (70.0 + 0.1 * rows))
    assert err.mean() < 0.5  # averaging candidate columns is integer-biased, not exact
    r, c = focus(remove_noise(brce(img[..., 0])))
    assert len(r) == 120


def test_paper_lle_averages_every_segment_of_a_row():
    # Two lines in the same rows: the paper's focusing averages them (no choice of segment).
    img = line_image(column=lambda r: 50.0 + 0 * r)
    img2 = line_image(column=lambda r: 110.0 + 0 * r)
    both = np.maximum(img, img2)
    line = paper_lle(both)
    assert abs(float(np.median(line.columns)) - 80.0) < 1.0
