"""docs/can-protocol.md stays in step with the spec."""

from __future__ import annotations

import re
from pathlib import Path

import alacs_can
from alacs_can.spec import MESSAGES_BY_NAME

DOC = Path(__file__).resolve().parents[3] / "docs" / "can-protocol.md"


def _signal_rows() -> dict[str, dict[str, tuple[int, int]]]:
    tables: dict[str, dict[str, tuple[int, int]]] = {}
    current = None
    for line in DOC.read_text(encoding="utf-8").splitlines():
        heading = re.match(r"### (\w+)$", line)
        if heading:
            current = heading[1] if heading[1] in MESSAGES_BY_NAME else None
            continue
        row = re.match(r"\| `(\w+)` \| (\d+)(?:\.\.(\d+))? \|", line)
        if current and row:
            start = int(row[2])
            end = int(row[3]) if row[3] else start
            tables.setdefault(current, {})[row[1]] = (start, end - start + 1)
    return tables


def test_every_signal_documented_with_its_bits() -> None:
    tables = _signal_rows()
    assert set(tables) == set(MESSAGES_BY_NAME)
    for name, msg in MESSAGES_BY_NAME.items():
        assert tables[name] == {s.name: (s.start, s.length) for s in msg.signals}, name


def test_doc_mentions_contract_essentials() -> None:
    text = DOC.read_text(encoding="utf-8")
    assert "candump -L can0 | python -m cantools decode can_protocol/alacs.dbc" in text
    for reason in alacs_can.NackReason:
        assert f"| {int(reason)} | {reason.name} |" in text, reason.name
    for name, base in alacs_can.BASE_IDS.items():
        assert f"| `{name}` | 0x{base:03X}" in text, name
    assert "0x4B" in text
