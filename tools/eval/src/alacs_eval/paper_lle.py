"""Which implementation of the paper's LLE the evaluation runs: issue 4's
tools/paper_lle/paper_lle.py when it exists, else paper_lle_fallback."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Callable

import numpy as np

from alacs_eval.paper_lle_fallback import PaperLine, paper_lle as fallback

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
    """(implementation, its name)."""
    if UPSTREAM.exists():
        spec = importlib.util.spec_from_file_location("alacs_paper_lle_upstream", UPSTREAM)
        if spec is not None and spec.loader is not None:
            mod = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(mod)
            if hasattr(mod, "paper_lle"):
                return _adapt(mod.paper_lle), "tools/paper_lle/paper_lle.py"
    return fallback, "tools/eval (fallback)"
