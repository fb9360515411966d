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


COMMITTED_DBC = Path(__file__).resolve().parents[2] / "alacs.dbc"


def _section(text: str, heading: str) -> str:
    start = text.index(heading + "\n")
    end = text.find("\n## ", start + len(heading))
    return text[start:end if end >= 0 else None]


def _int(text: str) -> int:
    return int(text, 0)


def _doc_value_tables() -> dict[tuple[str, str], dict[int, str]]:
    """{(message, signal): {value: name}} from the '## Value tables' section."""
    tables: dict[tuple[str, str], dict[int, str]] = {}
    signals: list[tuple[str, str]] = []
    for line in _section(DOC.read_text(encoding="utf-8"), "## Value tables").splitlines():
        if line.startswith("#### "):
            signals = [tuple(m.split(".")) for m in re.findall(r"`([\w.]+)`", line)]  # type: ignore[misc]
            for key in signals:
                assert key not in tables, f"{key} documented twice"
                tables[key] = {}
            continue
        row = re.match(r"\| (0x[0-9A-F]+|\d+) \| (\w+) \| (.+) \|$", line)
        if row and signals:
            assert row[3].strip(), f"{signals}: {row[2]} has no meaning"
            for key in signals:
                assert _int(row[1]) not in tables[key], f"{key}: value {row[1]} twice"
                tables[key][_int(row[1])] = row[2]
    return tables


def _dbc_value_tables() -> dict[tuple[str, str], dict[int, str]]:
    import cantools
    db = cantools.database.load_file(str(COMMITTED_DBC), strict=True)
    return {(m.name, s.name): {int(k): str(v) for k, v in s.choices.items()}
            for m in db.messages for s in m.signals if s.choices}


def test_doc_value_tables_are_the_dbcs() -> None:
    """Every value table of the DBC is in the document with every value, and nothing else."""
    doc, dbc = _doc_value_tables(), _dbc_value_tables()
    assert set(doc) == set(dbc)
    for key, table in dbc.items():
        assert doc[key] == table, key


def _rows_after(heading: str) -> dict[int, str]:
    """Value/name rows of the first table after ``heading`` (e.g. '### NACK reasons')."""
    text = DOC.read_text(encoding="utf-8")
    part = text[text.index(heading + "\n"):]
    rows: dict[int, str] = {}
    started = False
    for line in part.splitlines()[1:]:
        row = re.match(r"\| (\d+) \| (\w+) \|", line)
        if row:
            started = True
            rows[int(row[1])] = row[2]
        elif started and not line.startswith("|"):
            break
    return rows


def test_prose_tables_agree_with_the_dbc() -> None:
    dbc = _dbc_value_tables()
    assert _rows_after("### NACK reasons") == dbc[("ALACS_Ack", "NackReason")]
    assert _rows_after("### NACK detail") == dbc[("ALACS_Ack", "NackDetail")]
    assert _rows_after("### Result status and reason") == dbc[
        ("ALACS_ResultHeader", "ResultStatus")]
    text = DOC.read_text(encoding="utf-8")
    reasons = text[text.index("| Value | Reason | Meaning |"):]
    assert {int(v): n for v, n in re.findall(r"^\| (\d+) \| (\w+) \|", reasons[:3000], re.M)
            } == dbc[("ALACS_ResultHeader", "ResultReason")]


def test_partial_is_gone() -> None:
    text = DOC.read_text(encoding="utf-8")
    assert "PARTIAL" not in text.replace("protocol 1 sent this as PARTIAL", "").replace(
        "2 is what\nPARTIAL was", "").replace("PARTIAL is gone", "")
    assert "PARTIAL" not in {s.name for s in alacs_can.ResultStatus}


def test_generated_sections_are_current() -> None:
    from alacs_can import doctables
    text = DOC.read_text(encoding="utf-8")
    assert doctables.signal_tables().strip() in text
    assert doctables.value_tables().strip() in text


def test_working_envelope_documented() -> None:
    text = _section(DOC.read_text(encoding="utf-8"), "## Working envelope")
    assert "500..2000 mm" in text and "200 mm stroke" in text
    assert "| z (mm) |" in text and "```" in text
