"""Issue 16 on the host side: result status and reason, NACK detail, progress, timeouts that
follow the scan, STOP on Ctrl-C/timeout, quiet broken pipes, clean numbers, the envelope."""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import can
import pytest
from test_cli import FakeSensor, run_cli

import alacs_can
from alacs_can.doctables import MEANINGS
from alacs_cli import envelope, main as cli_main
from alacs_cli.main import (EXIT_BROKEN_PIPE, EXIT_INTERRUPTED, EXIT_OK, EXIT_REJECTED,
                            EXIT_TIMEOUT, EXIT_USAGE, expected_scan_s, main)
from alacs_cli.progress import ProgressView

DOC = Path(__file__).resolve().parents[3] / "docs" / "can-protocol.md"
LOCALIZE = ("localize", "--x", "0", "--y", "0", "--z", "1200")


@pytest.mark.parametrize(("status", "reason"), [
    ("ROUGH_ONLY", "TOO_FEW_LINES"), ("AMBIGUOUS", "TWO_SURFACES"),
    ("NOT_FOUND", "NO_LINES_IN_GATE"), ("NOT_FOUND", "BRIGHT_AMBIENT"), ("FAILED", "CAMERA_FAULT"),
    ("ABORTED", "STOPPED")])
def test_every_status_but_measured_fails_and_says_why(
        sensor: FakeSensor, channel: str, capsys: pytest.CaptureFixture[str],
        status: str, reason: str) -> None:
    sensor.result_status, sensor.result_reason = status, reason
    rc, out = run_cli(channel, *LOCALIZE, "--timeout", "3")
    assert rc == EXIT_REJECTED, out
    assert f"{status} ({reason})" in out
    err = capsys.readouterr().err
    assert f"result {status}, reason {reason}" in err
    # ... and what the reason means, as the DBC's value table says it.
    assert MEANINGS[alacs_can.ResultReason][reason].replace("`", "") in err


@pytest.mark.parametrize(("status", "said", "not_said"), [
    ("AMBIGUOUS", "AMBIGUOUS: the fit goes out", "ROUGH_ONLY: the rough position goes out"),
    ("ROUGH_ONLY", "ROUGH_ONLY: the rough position goes out", "AMBIGUOUS: the fit goes out")])
def test_a_reason_is_explained_for_its_status_alone(
        sensor: FakeSensor, channel: str, capsys: pytest.CaptureFixture[str],
        status: str, said: str, not_said: str) -> None:
    # FAR_FROM_ROUGH's value table says what it means with either status; the CLI says the
    # part that applies.
    sensor.result_status, sensor.result_reason = status, "FAR_FROM_ROUGH"
    rc, _ = run_cli(channel, *LOCALIZE, "--timeout", "3")
    assert rc == EXIT_REJECTED
    err = capsys.readouterr().err
    assert "more likely a neighbour" in err and said in err, err
    assert not_said not in err, err


def test_rough_only_in_json_is_not_measured(sensor: FakeSensor, channel: str) -> None:
    sensor.result_status, sensor.result_reason = "ROUGH_ONLY", "FAR_FROM_ROUGH"
    rc, out = run_cli(channel, "--json", *LOCALIZE, "--timeout", "3")
    result = json.loads(out.splitlines()[-1])
    assert rc == EXIT_REJECTED
    assert (result["status"], result["reason"], result["measured"]) == (
        "ROUGH_ONLY", "FAR_FROM_ROUGH", False)


def test_nack_printed_with_reason_and_detail(sensor: FakeSensor, channel: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    sensor.nack["LOCALIZE"] = "OUT_OF_RANGE"
    sensor.nack_detail = {"NackDetail": "STROKE", "NackValue": -239.6, "NackLimit": 0}
    rc, out = run_cli(channel, *LOCALIZE, "--timeout", "3")
    assert rc == EXIT_REJECTED
    assert "NackDetail=STROKE NackValue=-239.6 NackLimit=0" in out
    assert "NACK OUT_OF_RANGE: STROKE -239.6 mm, limit 0 mm" in capsys.readouterr().err


def test_ack_without_nack_hides_the_detail(sensor: FakeSensor, channel: str) -> None:
    rc, out = run_cli(channel, *LOCALIZE, "--timeout", "3")
    assert rc == EXIT_OK
    assert "NackDetail" not in out


def _progress(total: int) -> list[dict[str, Any]]:
    steps = [dict(ProgressPhase="MOVING", StopsDone=0, StopsTotal=total, ObjectsFound=0)]
    steps += [dict(ProgressPhase="EXPOSING", StopsDone=i, StopsTotal=total, ObjectsFound=0)
              for i in range(1, total + 1)]
    steps.append(dict(ProgressPhase="FITTING", StopsDone=total, StopsTotal=total,
                      ObjectsFound=1))
    return steps


def test_progress_plain_lines_when_piped(sensor: FakeSensor, channel: str) -> None:
    sensor.progress = _progress(3)
    sensor.progress.insert(2, dict(sensor.progress[1]))  # a repeat is not printed twice
    rc, out = run_cli(channel, *LOCALIZE, "--timeout", "3")
    assert rc == EXIT_OK
    lines = [line for line in out.splitlines() if line.startswith("progress")]
    assert lines == [
        "progress LOCALIZE MOVING stop 0/3 objects 0 elapsed 0 s",
        "progress LOCALIZE EXPOSING stop 1/3 objects 0 elapsed 0 s",
        "progress LOCALIZE EXPOSING stop 2/3 objects 0 elapsed 0 s",
        "progress LOCALIZE EXPOSING stop 3/3 objects 0 elapsed 0 s",
        "progress LOCALIZE FITTING stop 3/3 objects 1 elapsed 0 s"]


def test_progress_json(sensor: FakeSensor, channel: str) -> None:
    sensor.progress = _progress(2)
    rc, out = run_cli(channel, "--json", "scan-all", "--timeout", "3")
    assert rc == EXIT_OK
    kinds = [json.loads(line)["type"] for line in out.splitlines()]
    assert kinds == ["ack", "progress", "progress", "progress", "progress", "result"]


def test_progress_of_another_command_is_ignored() -> None:
    db = alacs_can.load_database()
    view = ProgressView(db, out := io.StringIO(), counter=3, mode="LOCALIZE", tty=False)
    frame = alacs_can.encode_message(db, alacs_can.MSG_PROGRESS, dict(
        ProgressMeasCounter=1, ProgressCounter=4, ProgressMode="LOCALIZE",
        ProgressPhase="MOVING", StopsDone=0, StopsTotal=7, ObjectsFound=0, ElapsedS=0))
    assert view.push(frame) is None and out.getvalue() == ""


def test_progress_bar_on_a_terminal() -> None:
    db = alacs_can.load_database()
    out = io.StringIO()
    view = ProgressView(db, out, counter=3, mode="SCAN_ALL", tty=True)
    for done in range(5):
        view.push(alacs_can.encode_message(db, alacs_can.MSG_PROGRESS, dict(
            ProgressMeasCounter=1, ProgressCounter=3, ProgressMode="SCAN_ALL",
            ProgressPhase="EXPOSING", StopsDone=done, StopsTotal=26, ObjectsFound=done,
            ElapsedS=done)))
    task = view._bar.tasks[0]
    assert (task.completed, task.total) == (4, 26)
    assert "EXPOSING objects 4" in task.description
    view.close()
    assert not any(line.startswith("progress ") for line in out.getvalue().splitlines())


def test_default_timeout_follows_the_scan() -> None:
    # SCAN_ALL sweeps the stroke in 26 stops of whole frames: far beyond the old 20 s.
    assert expected_scan_s(alacs_can.Opcode.SCAN_ALL) > 100
    assert expected_scan_s(alacs_can.Opcode.LOCALIZE) < expected_scan_s(alacs_can.Opcode.SCAN_ALL)
    assert expected_scan_s(alacs_can.Opcode.SCAN_ALL, 2) < expected_scan_s(
        alacs_can.Opcode.SCAN_ALL, 20)


def test_timeout_shrinks_when_the_sensor_says_nothing_is_left(
        sensor: FakeSensor, channel: str, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """No --timeout: after a progress frame with every stop done, the CLI waits the margin
    only (not the 15 s assumed for an unknown LOCALIZE plan)."""
    monkeypatch.setattr(cli_main, "MARGIN_S", 0.5)
    sensor.progress = [dict(ProgressPhase="FITTING", StopsDone=7, StopsTotal=7,
                            ObjectsFound=0)]
    sensor.hang_after_ack = True
    sensor.status_every_s = 0.05
    t0 = time.monotonic()
    rc, _ = run_cli(channel, *LOCALIZE)
    assert rc == EXIT_TIMEOUT
    assert time.monotonic() - t0 < 5
    assert "no complete result within 0.5 s" in capsys.readouterr().err


def test_timeout_sends_stop_and_reports_the_state(sensor: FakeSensor, channel: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    sensor.hang_after_ack = True
    sensor.status_every_s = 0.05
    rc, _ = run_cli(channel, *LOCALIZE, "--timeout", "0.5")
    assert rc == EXIT_TIMEOUT
    assert [c["CmdOpcode"] for c in sensor.commands()] == ["LOCALIZE", "STOP"]
    err = capsys.readouterr().err
    assert "sent STOP (ACK)" in err
    assert "sensor left in State=STOPPED" in err and "STOP_REQUESTED" in err
    assert "alacs clear-fault" in err


def test_ctrl_c_sends_stop_and_reports_the_state(sensor: FakeSensor, channel: str,
                                                 monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    def interrupt(self: ProgressView, frame: can.Message) -> None:
        if frame.arbitration_id == 0x690:
            raise KeyboardInterrupt

    monkeypatch.setattr(ProgressView, "push", interrupt)
    sensor.progress = _progress(2)
    sensor.hang_after_ack = True
    sensor.status_every_s = 0.05
    rc, _ = run_cli(channel, *LOCALIZE, "--timeout", "5")
    assert rc == EXIT_INTERRUPTED
    assert [c["CmdOpcode"] for c in sensor.commands()] == ["LOCALIZE", "STOP"]
    err = capsys.readouterr().err
    assert "interrupted: sent STOP (ACK)" in err and "sensor left in State=STOPPED" in err


class _ClosedPipe(io.StringIO):
    def write(self, text: str) -> int:
        raise BrokenPipeError(32, "Broken pipe")


def test_json_status_into_a_closed_pipe(sensor: FakeSensor, channel: str) -> None:
    sensor.status_every_s = 0.05
    rc = main(["--interface", "virtual", "--channel", channel, "--json", "status"],
              out=_ClosedPipe())
    assert rc == EXIT_BROKEN_PIPE


def test_no_broken_pipe_traceback_in_a_real_pipe(tmp_path: Path) -> None:
    db = alacs_can.load_database()
    log = tmp_path / "many.log"
    status = alacs_can.encode_message(db, alacs_can.MSG_STATUS, dict(
        State="IDLE", Homed=1, LaserOn=0, Calibrated=1, HomeSwitch=0, LastLatencyMs=1,
        MaxLatencyMs=1, DroppedFrames=0, RxErrorCount=0,
        **{s: 0 for s in alacs_can.FAULT_SIGNALS.values()}))
    log.write_text("".join(f"({i}.000000) vcan0 490#{bytes(status.data).hex().upper()}\n"
                           for i in range(20000)))
    proc = subprocess.Popen([sys.executable, "-m", "alacs_cli", "--json", "replay", str(log),
                             "--print"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.readline()  # like `| head -1`
    proc.stdout.close()
    err = proc.stderr.read().decode()
    proc.wait(timeout=60)
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert proc.returncode == EXIT_BROKEN_PIPE


def test_decoded_values_have_no_float_noise(sensor: FakeSensor, channel: str) -> None:
    db = sensor.db
    frame = alacs_can.encode_message(db, alacs_can.MSG_RESULT_OBJECT, dict(
        ObjPage="CENTER", ObjIndex=0, ObjMeasCounter=1, CenterX=-19.9, CenterY=56.3,
        CenterZ=1200.7))
    assert alacs_can.decode(db, frame)["CenterX"] == -19.9
    with can.Bus(interface="virtual", channel=channel) as bus:
        rc_out: dict[str, Any] = {}
        import threading

        def run() -> None:
            rc_out["v"] = run_cli(channel, "--json", "monitor", "--count", "1", "--timeout", "3")

        t = threading.Thread(target=run)
        t.start()
        time.sleep(0.3)
        bus.send(frame)
        t.join()
    rc, out = rc_out["v"]
    assert rc == EXIT_OK
    assert "-19.9" in out and "-19.900000000000002" not in out and "56.3" in out


def test_envelope_default_matches_the_doc() -> None:
    rc, out = run_cli("unused", "envelope")
    assert rc == EXIT_OK
    table = "\n".join(out.splitlines()[2:])
    assert table in DOC.read_text(encoding="utf-8")
    assert "| 1200 | -97 .. 104 |" in out


def test_envelope_from_a_calibration_file(tmp_path: Path) -> None:
    cal = tmp_path / "calibration.json"
    cal.write_text(json.dumps({
        "format": "alacs-calibration/1",
        "camera": {"width_px": 2048, "height_px": 1536, "fx_px": 2400, "fy_px": 2400,
                   "cx_px": 1024, "cy_px": 768, "distortion": [0, 0, 0, 0, 0]},
        "laser": {"plane_normal": [1, 0, 0], "plane_offset_mm": 100, "slide_axis": [1, 0, 0],
                  "slide_scale": 1.0}}))
    rc, out = run_cli("unused", "--json", "envelope", "--calibration", str(cal),
                      "--stroke-mm", "150")
    assert rc == EXIT_OK
    doc = json.loads(out)
    # A plane facing x: it reaches x = 100..250 mm at every depth, clipped by the view.
    assert doc["rows"][0]["laser_x_mm"] == pytest.approx([100, 250])
    assert doc["rows"][0]["x_mm"] == pytest.approx([100, 500 * 1024 / 2400])
    assert doc["source"] == str(cal)


def test_envelope_bad_calibration(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "x.json"
    bad.write_text("{}")
    assert run_cli("unused", "envelope", "--calibration", str(bad))[0] == EXIT_USAGE
    assert "not a calibration file" in capsys.readouterr().err


def test_envelope_agrees_with_the_daemons_slide_rule() -> None:
    geo = envelope.Geometry.default()
    for row in envelope.envelope(geo):
        lo, hi = row.laser_x_mm
        assert geo.slide_for_point((lo, 0.0, row.depth_mm)) == pytest.approx(0, abs=1e-6)
        assert geo.slide_for_point((hi, 0.0, row.depth_mm)) == pytest.approx(200, abs=1e-6)
    # The simulator's sheet crosses the optical axis at 1.2 m near mid-stroke.
    assert 90 < geo.slide_for_point((0, 0, 1200)) < 110
    assert re.search(r"Working envelope", envelope.format_table(geo, 200, envelope.envelope(geo)))
