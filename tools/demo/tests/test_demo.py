"""The demo's own bookkeeping: frame counts, whole status blocks, the node's first frame
reported as it was, and a quiet install step. (The demo itself runs in the UML bench.)"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import can
import pytest

import alacs_can

DEMO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(DEMO))

import demo  # noqa: E402
import exchange  # noqa: E402


def _log(tmp_path: Path, statuses: int) -> Path:
    db = alacs_can.load_database()
    status = alacs_can.encode_message(db, alacs_can.MSG_STATUS, dict(
        State="IDLE", Homed=1, LaserOn=0, Calibrated=1, HomeSwitch=0, LastLatencyMs=1,
        MaxLatencyMs=1, DroppedFrames=0, RxErrorCount=0,
        **{s: 0 for s in alacs_can.FAULT_SIGNALS.values()}))
    hb = alacs_can.encode_message(db, alacs_can.MSG_HEARTBEAT, {"NmtState": "BOOTUP"})
    lines = [f"(0.000000) vcan0 710#{bytes(hb.data).hex().upper()}"]
    lines += [f"({i + 1}.000000) vcan0 490#{bytes(status.data).hex().upper()}"
              for i in range(statuses)]
    lines.append("(99.000000) vcan0 123#01")
    log = tmp_path / "candump.log"
    log.write_text("\n".join(lines) + "\n")
    return log


def test_counts_are_frames_not_lines(tmp_path: Path) -> None:
    log = _log(tmp_path, statuses=25)
    text = exchange.decode_log_with_cantools(log)
    shown = demo.sparse_status(text)
    assert len(text.splitlines()) > 27 * 3  # cantools spreads a frame over many lines
    assert (shown.frames, shown.status, shown.status_shown) == (27, 25, 3)


def test_status_bodies_come_with_their_header(tmp_path: Path) -> None:
    text = exchange.decode_log_with_cantools(_log(tmp_path, statuses=12))
    lines = demo.sparse_status(text).lines
    headers = [i for i, line in enumerate(lines) if line.startswith("ALACS_Status(")]
    assert len(headers) == 2
    for i in headers:
        assert " 490#" in lines[i - 1]  # the candump line right before
        assert lines[i + 1].strip().startswith("State: IDLE")
    # every body line belongs to a shown header: no orphaned "State:" lines
    assert sum(line.strip().startswith("State:") for line in lines) == 2
    assert "Heartbeat(" in lines and any("Unknown frame id" in line for line in lines)


def _hb(state: int, node_id: int = 0x10) -> can.Message:
    return can.Message(arbitration_id=0x700 + node_id, data=bytes([state]), dlc=1,
                       is_extended_id=False)


def test_boot_up_reported_only_when_seen() -> None:
    db = alacs_can.load_database()
    text = exchange.describe_start(db, [_hb(0x00)], 0x10)
    assert text == "first frame from node 0x10: its boot-up (Heartbeat NmtState BOOTUP 0x00)"
    text = exchange.describe_start(db, [_hb(0x05)], 0x10)
    assert "first frame from node 0x10: Heartbeat (NmtState=OPERATIONAL)" in text
    assert "no boot-up (NmtState BOOTUP 0x00) seen" in text and "OPERATIONAL (0x05)" in text


def test_first_frame_may_be_a_status() -> None:
    db = alacs_can.load_database()
    status = alacs_can.encode_message(db, alacs_can.MSG_STATUS, dict(
        State="BOOT", Homed=0, LaserOn=0, Calibrated=0, HomeSwitch=0, LastLatencyMs=0,
        MaxLatencyMs=0, DroppedFrames=0, RxErrorCount=0,
        **{s: 0 for s in alacs_can.FAULT_SIGNALS.values()}))
    text = exchange.describe_start(db, [status, _hb(0x7F)], 0x10)
    assert text.startswith("first frame from node 0x10: ALACS_Status (State=BOOT")
    assert "PRE_OPERATIONAL (0x7F)" in text


def _quiet(tmp_path: Path, command: str) -> subprocess.CompletedProcess[str]:
    script = (f"source {DEMO / 'quiet.sh'}; "
              f"quiet_step 'installing' {tmp_path / 'logs' / 'install.log'} bash -c '{command}'")
    return subprocess.run(["bash", "-c", script], capture_output=True, text=True, check=False)


def test_install_step_prints_one_line(tmp_path: Path) -> None:
    proc = _quiet(tmp_path, "for i in $(seq 1700); do echo apt line $i; done")
    assert proc.returncode == 0
    assert proc.stdout == ""
    assert proc.stderr.splitlines() == [
        f"demo: installing ... done (log: {tmp_path / 'logs' / 'install.log'})"]
    assert len((tmp_path / "logs" / "install.log").read_text().splitlines()) == 1700


def test_install_step_shows_the_log_on_failure(tmp_path: Path) -> None:
    proc = _quiet(tmp_path, "echo E: Unable to locate package foo; exit 100")
    assert proc.returncode == 100
    assert "demo: installing ... FAILED (exit 100)" in proc.stderr
    assert "E: Unable to locate package foo" in proc.stderr


def test_run_sh_uses_the_quiet_steps() -> None:
    text = (DEMO / "run.sh").read_text()
    assert "quiet_step" in text and "tools/bootstrap.sh" in text
    assert "\ntools/bootstrap.sh\n" not in text


@pytest.mark.parametrize("doc", ["docs/hil.md"])
def test_hil_doc_names_the_built_daemon(doc: str) -> None:
    root = DEMO.parents[1]
    text = (root / doc).read_text()
    assert "build/edge/alacsd" not in text
    assert "build/release/edge/app/alacsd" in text
    assert "build/release/edge/app/alacsd" in (root / "tests" / "run").read_text()
