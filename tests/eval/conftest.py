"""tests/eval: the evaluation tools (tools/eval) and, under uml/, scan directories through
the real daemon inside the HIL bench. tests/eval/run.sh runs both."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools" / "eval" / "src"))
