"""The paper's LLE as the evaluation runs it: tools/paper_lle/paper_lle.py (the numpy
reference that tools/lle/check.sh holds equal to the C++ paper path), adapted to the
evaluation's PaperLine. There is no second copy: a missing reference is an error."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Callable

import numpy as np

from alacs_eval.paper_line import PaperLine

ROOT = Path(__file__).resolve().parents[4]
UPSTREAM = ROOT / "tools" / "paper_lle" / "paper_lle.py"


def _adapt(fn: Callable) -> Callable[..., PaperLine]:
    """Wraps an upstream paper_lle(rgb, step, th, theta, gamma) -> per-row columns."""

    def run(rgb: np.ndarray, step: int = 4, th: int = 40, theta: int = 8, gamma: int = 3) -> PaperLine:
        out = fn(rgb, step=step, th=th, theta=theta, gamma=gamma)
        if isinstance(out, PaperLine):
            return out
        if hasattr(out, "column_at") and hasattr(out, "rows") and hasattr(out, "columns"):
            # Issue 4's PaperLine: its own curve, its own pixel count.
            rows = np.asarray(out.rows, float)
            has = getattr(out, "curve", None) is not None
            mask = getattr(out, "mask", None)
            pixels = int(np.count_nonzero(mask)) if mask is not None else int(len(rows))
            return PaperLine(rows, np.asarray(out.columns, float), None, pixels,
                             curve=(lambda r, o=out: o.column_at(r)) if has else None)
        if isinstance(out, dict):
            rows = np.asarray(sorted(out), float)
            cols = np.asarray([out[r] for r in sorted(out)], float)
        else:
            arr = np.asarray(out, float)
            if arr.ndim == 1:  # one column per image row, NaN where none
                rows = np.nonzero(np.isfinite(arr))[0].astype(float)
                cols = arr[np.isfinite(arr)]
            else:
                rows, cols = arr[:, 0], arr[:, 1]
        coeffs = np.polyfit(rows, cols, 4) if len(rows) > 4 else None
        return PaperLine(rows, cols, coeffs, int(len(rows)))

    return run


def load() -> tuple[Callable[..., PaperLine], str]:
    """(implementation, its name). Raises FileNotFoundError/ImportError when the reference
    is missing or has no paper_lle."""
    spec = importlib.util.spec_from_file_location("alacs_paper_lle_upstream", UPSTREAM)
    if not UPSTREAM.exists() or spec is None or spec.loader is None:
        raise FileNotFoundError(f"the paper's LLE reference {UPSTREAM} is missing")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    if not hasattr(mod, "paper_lle"):
        raise ImportError(f"{UPSTREAM} has no paper_lle()")
    return _adapt(mod.paper_lle), "tools/paper_lle/paper_lle.py"
