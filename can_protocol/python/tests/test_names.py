"""generated/alacs_names.h: the value tables' names as C X-macros, as the DBC has them."""

from __future__ import annotations

import re
from pathlib import Path

import cantools

from alacs_can import names

ROOT = Path(__file__).resolve().parents[2]
HEADER = ROOT / "generated" / "alacs_names.h"


def _tables_in_header(text: str) -> dict[str, dict[int, str]]:
    tables: dict[str, dict[int, str]] = {}
    for m in re.finditer(r"#define ALACS_(\w+)_NAMES\(X\) \\\n((?:    X\(.*\n)+)", text):
        rows = re.findall(r'X\((\d+)u, "(\w+)"\)', m.group(2))
        tables[m.group(1)] = {int(v): n for v, n in rows}
    return tables


def test_committed_header_is_current() -> None:
    assert HEADER.read_text() == names.names_header_text()


def test_every_value_table_of_the_dbc_is_in_the_header_with_its_names() -> None:
    """Read against the committed DBC through cantools, not against spec.py's enums."""
    tables = _tables_in_header(HEADER.read_text())
    db = cantools.database.load_file(str(ROOT / "alacs.dbc"))
    by_signal = {f"{m.name}.{s.name}": s for m in db.messages for s in m.signals}
    checked = 0
    for enum, users in names.value_tables():
        table = tables[names.macro_name(enum)]
        for user in users:
            choices = {int(v): str(n) for v, n in by_signal[user].choices.items()}
            assert table == choices, user
            checked += 1
    with_choices = [k for k, s in by_signal.items() if s.choices]
    assert checked == len(with_choices) and len(tables) == len(names.value_tables())


def test_result_status_names_are_the_ones_integrators_see() -> None:
    tables = _tables_in_header(HEADER.read_text())
    assert tables["RESULT_STATUS"] == {0: "MEASURED", 1: "NOT_FOUND", 2: "ROUGH_ONLY", 3: "FAILED",
                                       4: "ABORTED", 5: "AMBIGUOUS"}
    assert tables["RESULT_REASON"][5] == "FAR_FROM_ROUGH"
