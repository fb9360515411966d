"""System tests run INSIDE the UML bench (tests/hil/run_in_uml.sh): real vcan0, real
gpio-sim lines, the real alacsd binary."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools" / "demo"))
sys.path.insert(0, str(ROOT / "tests" / "hil"))


@pytest.fixture(scope="session")
def alacsd() -> Path:
    path = Path(os.environ.get("ALACS_ALACSD", ROOT / "build" / "release" / "edge" / "app" / "alacsd"))
    if not path.exists():
        pytest.fail(f"alacsd not built at {path} (set ALACS_ALACSD)")
    return path


@pytest.fixture(autouse=True)
def _in_bench() -> None:
    if os.environ.get("ALACS_IN_UML") != "1":
        pytest.fail("system tests run inside the HIL bench: tests/hil/run_in_uml.sh -- pytest tests/system")
