"""The numpy paper LLE: its steps, and bit-for-bit agreement with the C++ kPaper path
(alacs_lle --method paper) when that binary is built (ALACS_LLE, or build/*/tools/lle)."""

from __future__ import annotations

import glob
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from paper_lle import brce, focus_rows, paper_lle, remove_noise

ROOT = Path(__file__).resolve().parents[3]


def row_image(red: list[int]) -> np.ndarray:
    rgb = np.zeros((1, len(red), 3), dtype=np.uint8)
    rgb[0, :, 0] = red
    return rgb


def test_brce_meaning_and_the_printed_form():
    bright = row_image([10, 10, 10, 10, 100, 10, 10, 10, 10])
    dip = row_image([100, 100, 100, 100, 10, 100, 100, 100, 100])
    assert brce(bright, 4, 40)[0].tolist() == [False] * 4 + [True] + [False] * 4
    assert not brce(dip, 4, 40).any()
    # As printed, on uint8: the dip fires, and so does a centre one DN above its neighbours.
    assert brce(dip, 4, 40, literal=True)[0, 4]
    assert brce(row_image([10, 10, 10, 10, 11, 10, 10, 10, 10]), 4, 40, literal=True)[0, 4]


def test_noise_removal_clears_sparse_windows_and_keeps_the_line():
    g = np.zeros((40, 80), dtype=bool)
    g[:, 30] = True          # a line: 20 candidates per band
    g[5, 70] = g[25, 71] = True  # isolated noise
    c = remove_noise(g, theta=8, gamma=3)
    assert c[:, 30].all()
    assert not c[5, 70] and not c[25, 71]


def test_line_focusing_is_the_mean_of_candidate_columns():
    c = np.zeros((3, 20), dtype=bool)
    c[0, [4, 5, 6]] = True
    c[2, [10, 13]] = True
    rows, cols, counts = focus_rows(c)
    assert rows.tolist() == [0, 2]
    assert cols.tolist() == [5.0, 11.5]
    assert counts.tolist() == [3, 2]


def synthetic(h: int = 120, w: int = 160, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    centre = 60.3 + 0.1 * y + 0.0008 * (y - h / 2) ** 2
    red = 30 + 0.2 * x + 150 * np.exp(-0.5 * (x - centre) ** 2 / 1.7) * (1 + 0.3 * rng.standard_normal((h, w)))
    rgb = np.zeros((h, w, 3), dtype=np.uint8)
    rgb[..., 0] = np.clip(np.round(red + rng.normal(0, 2, (h, w))), 0, 255)
    rgb[..., 1] = 20
    return rgb


def test_paper_lle_follows_a_line():
    line = paper_lle(synthetic())
    assert line.rows.size == 120
    truth = 60.3 + 0.1 * line.rows + 0.0008 * (line.rows - 60) ** 2
    assert np.abs(line.columns - truth).mean() < 0.7   # integer-biased, as the paper's 1-2 px
    assert np.abs(line.column_at(line.rows) - truth).mean() < 0.5


def test_bad_input_is_refused():
    with pytest.raises(ValueError):
        paper_lle(np.zeros((4, 4), dtype=np.uint8))
    with pytest.raises(ValueError):
        paper_lle(np.zeros((4, 4, 3), dtype=np.float32))
    with pytest.raises(ValueError):
        paper_lle(np.zeros((4, 4, 3), dtype=np.uint8), step=0)


def cpp_binary() -> str | None:
    env = os.environ.get("ALACS_LLE")
    if env:
        return env
    found = sorted(glob.glob(str(ROOT / "build" / "*" / "tools" / "lle" / "alacs_lle")), key=os.path.getmtime)
    return found[-1] if found else None


@pytest.mark.parametrize("literal", [False, True])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_same_as_the_cpp_paper_path(tmp_path: Path, literal: bool, seed: int):
    exe = cpp_binary()
    if exe is None:
        pytest.skip("alacs_lle is not built (set ALACS_LLE)")
    rgb = synthetic(seed=seed)
    png = tmp_path / "frame.png"
    Image.fromarray(rgb).save(png)
    out = tmp_path / "out.json"
    args = [exe, str(png), "--method", "paper", "--json", str(out), "--overlay", "none"]
    if literal:
        args += ["--form", "literal"]
    subprocess.run(args, check=True, capture_output=True)
    cpp = json.loads(out.read_text())
    line = paper_lle(rgb, literal=literal)
    got = {r["row"]: r["column"] for r in cpp["rows"] if r["column"] is not None}
    assert sorted(got) == line.rows.tolist()
    # The C++ column is the same mean, rounded to 1/256 px.
    for r, c in zip(line.rows, line.columns):
        assert abs(got[int(r)] - c) <= 1 / 512 + 1e-6
    if line.curve is not None:
        poly = cpp["polynomial"]
        t = (line.rows - poly["row_center"]) / poly["row_half_span"]
        cpp_curve = sum(c * t**k for k, c in enumerate(poly["coeffs"]))
        assert np.abs(cpp_curve - line.column_at(line.rows)).max() < 0.01
