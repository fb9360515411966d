"""The ``alacs`` CLI against python-can's ``virtual`` bus and a tiny fake sensor thread.

This tests the CLI only; the daemon's protocol behaviour is tested elsewhere on vcan.
"""

from __future__ import annotations

import io
import json
import random
import subprocess
import sys
import threading
import uuid
from collections.abc import Iterator
from typing import Any

import can
import pytest

import alacs_can
from alacs_cli.main import EXIT_OK, EXIT_REJECTED, EXIT_TIMEOUT, EXIT_USAGE, main


class FakeSensor(threading.Thread):
    """Answers commands like alacsd would, from a scripted table. Not the real logic."""

    def __init__(self, channel: str, node_id: int = 0x10) -> None:
        super().__init__(daemon=True)
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.db = alacs_can.load_database(node_id)
        self.cmd_id = self.db.get_message_by_name(alacs_can.MSG_COMMAND).frame_id
        self.received: list[can.Message] = []
        self.nack: dict[str, str] = {}
        self.silent = False
        self.result_status = "MEASURED"
        self.result_reason = "NONE"
        self.nack_detail: dict[str, Any] = {}
        self.progress: list[dict[str, Any]] = []
        self.hang_after_ack = False
        self.stopped = False
        self.status_every_s: float | None = None
        self.extra_frames: list[can.Message] = []
        self.meas = 0x1FF
        # The counter of the last command accepted; the same counter again is NACKed
        # BAD_COUNTER, as alacsd does within 1 s (the fake has no clock).
        self.last_counter: int | None = None
        self._halt = threading.Event()

    def send(self, name: str, **signals: Any) -> None:
        self.bus.send(alacs_can.encode_message(self.db, name, signals))

    def ack(self, opcode: str, counter: int, result: str = "ACK", reason: str = "NONE",
            **extra: Any) -> None:
        if opcode not in ("INVALID", "GET_VERSION"):
            extra = {"NackDetail": "NONE", "NackValue": 0, "NackLimit": 0, **extra}
        self.send(alacs_can.MSG_ACK, AckOpcode=opcode, AckCounter=counter, AckResult=result,
                  NackReason=reason, **extra)

    def run(self) -> None:
        next_status = 0.0
        clock = 0.0
        while not self._halt.is_set():
            frame = self.bus.recv(timeout=0.01)
            clock += 0.01
            if self.status_every_s is not None and clock >= next_status:
                next_status = clock + self.status_every_s
                self.send_status()
            if frame is None:
                continue
            self.received.append(frame)
            if frame.arbitration_id == self.cmd_id and not self.silent:
                self.handle(frame)

    def send_status(self) -> None:
        faults = {name: int(flag == alacs_can.Fault.CAMERA_TIMEOUT or (
                      self.stopped and flag == alacs_can.Fault.STOP_REQUESTED))
                  for flag, name in alacs_can.FAULT_SIGNALS.items()}
        self.send(alacs_can.MSG_STATUS, State="STOPPED" if self.stopped else "IDLE", Homed=1,
                  LaserOn=0, Calibrated=1,
                  HomeSwitch=0, LastLatencyMs=120, MaxLatencyMs=250, DroppedFrames=0,
                  RxErrorCount=2, **faults)

    def handle(self, frame: can.Message) -> None:
        counter = frame.data[1] & 0x0F if frame.dlc > 1 else 0
        if not alacs_can.check_command(frame.data):
            self.ack("INVALID", counter, "NACK", "BAD_CHECKSUM", RejectedOpcode=frame.data[0])
            return
        cmd = alacs_can.decode(self.db, frame)
        op = str(cmd["CmdOpcode"])
        if op in self.nack:
            self.ack(op, counter, "NACK", self.nack[op], **self.nack_detail)
            return
        if counter == self.last_counter:
            self.ack(op, counter, "NACK", "BAD_COUNTER")
            return
        self.last_counter = counter
        if op == "STOP":
            self.stopped = True
        if op == "GET_VERSION":
            self.ack(op, counter, SwMajor=0, SwMinor=3, SwPatch=7,
                     ProtocolVersion=alacs_can.PROTOCOL_VERSION)
            return
        self.ack(op, counter)
        if op == "HOME":
            self.ack(op, counter, "DONE")
        elif op in ("LOCALIZE", "SCAN_ALL"):
            for extra in self.extra_frames:
                self.bus.send(extra)
            for p in self.progress:
                self.send(alacs_can.MSG_PROGRESS, **{
                    "ProgressMeasCounter": self.meas + 1, "ProgressCounter": counter,
                    "ProgressMode": op, "ElapsedS": 0, **p})
            if not self.hang_after_ack:
                self.send_result(int(cmd.get("TargetId", 0)), op)

    def send_result(self, target: int, op: str) -> None:
        self.meas += 1
        count = 1 if self.result_status in ("MEASURED", "ROUGH_ONLY") else 0
        self.send(alacs_can.MSG_RESULT_HEADER, MeasCounter=self.meas, ObjectCount=count,
                  ResultTargetId=target, ScanAgeMs=30, ResultStatus=self.result_status,
                  ResultReason=self.result_reason, ResultMode=op, CycleTime=880)
        common = dict(ObjIndex=0, ObjMeasCounter=self.meas & 0xFF)
        if count:
            self.send(alacs_can.MSG_RESULT_OBJECT, ObjPage="CENTER", CenterX=-101.5, CenterY=33.3,
                      CenterZ=612.4, **common)
            self.send(alacs_can.MSG_RESULT_OBJECT, ObjPage="APPROACH_POINT", ApproachX=-95,
                      ApproachY=30, ApproachZ=540, **common)
            self.send(alacs_can.MSG_RESULT_OBJECT, ObjPage="QUALITY", SigmaMm=0.6, Confidence=91,
                      DiameterMm=76.5, OcclusionPct=15, LinesUsed=9, PointsUsed=1500, **common)
            self.send(alacs_can.MSG_RESULT_OBJECT, ObjPage="APPROACH_NORMAL", NormalX=0,
                      NormalY=0.6, NormalZ=0.8, **common)

    def commands(self) -> list[dict[str, Any]]:
        return [alacs_can.decode(self.db, m) for m in self.received
                if m.arbitration_id == self.cmd_id]

    def stop(self) -> None:
        self._halt.set()
        self.join(timeout=2)
        self.bus.shutdown()


@pytest.fixture
def channel() -> str:
    return f"alacs-test-{uuid.uuid4().hex}"


@pytest.fixture
def sensor(channel: str) -> Iterator[FakeSensor]:
    fake = FakeSensor(channel)
    fake.start()
    yield fake
    fake.stop()


def run_cli(channel: str, *args: str) -> tuple[int, str]:
    out = io.StringIO()
    rc = main(["--interface", "virtual", "--channel", channel, *args], out=out)
    return rc, out.getvalue()


def test_localize_success(sensor: FakeSensor, channel: str) -> None:
    rc, out = run_cli(channel, "--counter", "5", "localize", "--x", "-120", "--y", "45",
                      "--z", "650", "--target", "7", "--mode", "continuous", "--timeout", "3")
    assert rc == EXIT_OK, out
    assert "AckResult=ACK" in out and "AckCounter=5" in out
    assert "LOCALIZE MEASURED target=7 objects=1" in out
    assert "centre (-101.5, 33.3, 612.4) mm" in out
    assert "normal (0.000, 0.600, 0.800)" in out
    assert "points=1500" in out
    (cmd,) = sensor.commands()
    assert cmd == {"CmdOpcode": "LOCALIZE", "CmdCounter": 5, "CmdChecksum": cmd["CmdChecksum"],
                   "LocalizeMode": "CONTINUOUS", "TargetId": 7, "RoughX": -120, "RoughY": 45,
                   "RoughZ": 650}
    assert alacs_can.check_command(sensor.received[0].data)


def test_a_drawn_counter_that_repeats_the_last_is_sent_again(
        sensor: FakeSensor, channel: str, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    # The previous call drew 6 too, under a second ago: NACK BAD_COUNTER, not executed.
    monkeypatch.setattr(random, "randrange", lambda n: 6)
    sensor.last_counter = 6
    sensor.progress = [dict(ProgressPhase="EXPOSING", StopsDone=1, StopsTotal=2,
                            ObjectsFound=0)]
    rc, out = run_cli(channel, "localize", "--x", "0", "--y", "0", "--z", "500",
                      "--timeout", "3")
    assert rc == EXIT_OK, out
    assert [c["CmdCounter"] for c in sensor.commands()] == [6, 7]
    assert [c["CmdOpcode"] for c in sensor.commands()] == ["LOCALIZE", "LOCALIZE"]
    assert "AckCounter=7" in out and "LOCALIZE MEASURED" in out
    assert "progress LOCALIZE EXPOSING stop 1/2" in out  # the second counter's progress
    assert "counter 6 repeated" in capsys.readouterr().err


def test_a_given_counter_that_repeats_the_last_is_nacked(
        sensor: FakeSensor, channel: str, capsys: pytest.CaptureFixture[str]) -> None:
    sensor.last_counter = 6
    rc, out = run_cli(channel, "--counter", "6", "localize", "--x", "0", "--y", "0",
                      "--z", "500", "--timeout", "3")
    assert rc == EXIT_REJECTED
    assert "NackReason=BAD_COUNTER" in out
    assert [c["CmdCounter"] for c in sensor.commands()] == [6]
    assert "NACK BAD_COUNTER" in capsys.readouterr().err


def test_config_pages_follow_a_counter_sent_again(
        sensor: FakeSensor, channel: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(random, "randrange", lambda n: 15)
    sensor.last_counter = 15
    rc, out = run_cli(channel, "config", "--exposure-us", "900", "--heartbeat-ms", "500")
    assert rc == EXIT_OK, out
    assert [(c["CfgPage"], c["CmdCounter"]) for c in sensor.commands()] == [
        ("ACQUISITION", 15), ("ACQUISITION", 0), ("SCAN", 1)]
    assert out.count("AckResult=ACK") == 2


def test_localize_json(sensor: FakeSensor, channel: str) -> None:
    rc, out = run_cli(channel, "--json", "localize", "--x", "0", "--y", "0", "--z", "500",
                      "--timeout", "3")
    assert rc == EXIT_OK
    ack, result = (json.loads(line) for line in out.splitlines())
    assert ack["type"] == "ack" and ack["AckResult"] == "ACK"
    assert result["type"] == "result" and result["status"] == "MEASURED" and result["complete"]
    assert result["objects"][0]["center_mm"] == pytest.approx([-101.5, 33.3, 612.4])


def test_localize_ignores_other_traffic(sensor: FakeSensor, channel: str) -> None:
    # An unrelated Ack with another counter and a result for another target come first.
    db = sensor.db
    sensor.extra_frames = [
        alacs_can.encode_message(db, "ALACS_Ack", dict(AckOpcode="LOCALIZE", AckCounter=9,
                                                       AckResult="NACK", NackReason="BUSY",
                                                       NackDetail="NONE", NackValue=0,
                                                       NackLimit=0)),
        can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False),
    ]
    rc, out = run_cli(channel, "--counter", "2", "localize", "--x", "1", "--y", "2", "--z", "300",
                      "--target", "4", "--timeout", "3")
    assert rc == EXIT_OK, out
    assert "target=4" in out


def test_localize_nack(sensor: FakeSensor, channel: str,
                       capsys: pytest.CaptureFixture[str]) -> None:
    sensor.nack["LOCALIZE"] = "NOT_HOMED"
    rc, out = run_cli(channel, "localize", "--x", "0", "--y", "0", "--z", "500", "--timeout", "3")
    assert rc == EXIT_REJECTED
    assert "NackReason=NOT_HOMED" in out
    assert "NACK NOT_HOMED" in capsys.readouterr().err


def test_localize_nmt_hint(sensor: FakeSensor, channel: str,
                           capsys: pytest.CaptureFixture[str]) -> None:
    sensor.nack["LOCALIZE"] = "NMT_NOT_OPERATIONAL"
    rc, _ = run_cli(channel, "localize", "--x", "0", "--y", "0", "--z", "500", "--timeout", "3")
    assert rc == EXIT_REJECTED
    assert "alacs nmt start" in capsys.readouterr().err


def test_localize_not_found_is_failure(sensor: FakeSensor, channel: str) -> None:
    sensor.result_status = "NOT_FOUND"
    sensor.result_reason = "NO_LINES_IN_GATE"
    rc, out = run_cli(channel, "localize", "--x", "0", "--y", "0", "--z", "500", "--timeout", "3")
    assert rc == EXIT_REJECTED
    assert "NOT_FOUND (NO_LINES_IN_GATE)" in out and "objects=0" in out


def test_localize_timeout(sensor: FakeSensor, channel: str,
                          capsys: pytest.CaptureFixture[str]) -> None:
    sensor.silent = True
    rc, _ = run_cli(channel, "localize", "--x", "0", "--y", "0", "--z", "500", "--timeout", "0.3")
    assert rc == EXIT_TIMEOUT
    assert "timeout" in capsys.readouterr().err
    # On a timeout the CLI stops the sensor (a silent one does not answer).
    assert [c["CmdOpcode"] for c in sensor.commands()] == ["LOCALIZE", "STOP"]


def test_localize_out_of_range(sensor: FakeSensor, channel: str,
                               capsys: pytest.CaptureFixture[str]) -> None:
    rc, _ = run_cli(channel, "localize", "--x", "0", "--y", "0", "--z", "3000")
    assert rc == EXIT_USAGE
    assert "out of range" in capsys.readouterr().err
    assert sensor.commands() == []


def test_scan_all(sensor: FakeSensor, channel: str) -> None:
    rc, out = run_cli(channel, "scan-all", "--timeout", "3")
    assert rc == EXIT_OK, out
    assert "SCAN_ALL MEASURED" in out


def test_home_waits_for_done(sensor: FakeSensor, channel: str) -> None:
    rc, out = run_cli(channel, "home", "--timeout", "3")
    assert rc == EXIT_OK
    assert "AckResult=ACK" in out and "AckResult=DONE" in out


def test_stop_and_clear_fault(sensor: FakeSensor, channel: str) -> None:
    # Counters of their own: two random draws repeat 1 time in 16, and the repeat's NACK and
    # resend (test_a_drawn_counter_that_repeats_the_last_is_sent_again) would add a command.
    assert run_cli(channel, "--counter", "3", "stop")[0] == EXIT_OK
    assert run_cli(channel, "--counter", "4", "clear-fault")[0] == EXIT_OK
    assert [c["CmdOpcode"] for c in sensor.commands()] == ["STOP", "CLEAR_FAULT"]


def test_version(sensor: FakeSensor, channel: str) -> None:
    rc, out = run_cli(channel, "version")
    assert rc == EXIT_OK
    assert f"alacsd 0.3.7  protocol {alacs_can.PROTOCOL_VERSION}" in out


def test_config(sensor: FakeSensor, channel: str) -> None:
    rc, out = run_cli(channel, "--counter", "15", "config", "--exposure-us", "900",
                      "--heartbeat-ms", "500")
    assert rc == EXIT_OK, out
    a, b = sensor.commands()
    assert (a["CfgPage"], a["CfgExposureValid"], a["CfgExposureUs"], a["CmdCounter"]) == (
        "ACQUISITION", 1, 900, 15)
    assert (b["CfgPage"], b["CfgHeartbeatValid"], b["CfgHeartbeatMs"], b["CmdCounter"]) == (
        "SCAN", 1, 500, 0)
    assert out.count("AckResult=ACK") == 2


def test_config_needs_a_setting(channel: str) -> None:
    assert run_cli(channel, "config")[0] == EXIT_USAGE


def test_status(sensor: FakeSensor, channel: str) -> None:
    sensor.status_every_s = 0.05
    rc, out = run_cli(channel, "status", "--timeout", "3")
    assert rc == EXIT_OK
    assert "State=IDLE" in out and "Homed=1" in out and "LastLatencyMs=120" in out
    assert "faults: CAMERA_TIMEOUT" in out


def test_status_timeout(sensor: FakeSensor, channel: str) -> None:
    assert run_cli(channel, "status", "--timeout", "0.2")[0] == EXIT_TIMEOUT


def test_monitor_count(sensor: FakeSensor, channel: str) -> None:
    sensor.status_every_s = 0.02
    rc, out = run_cli(channel, "monitor", "--count", "3", "--timeout", "5")
    assert rc == EXIT_OK
    lines = out.splitlines()
    assert len(lines) == 3
    assert all(" 490  ALACS_Status " in line and "State=IDLE" in line for line in lines)


def test_monitor_raw_and_bad_checksum(channel: str) -> None:
    db = alacs_can.load_database()
    with can.Bus(interface="virtual", channel=channel) as bus:
        done = threading.Event()
        result: dict[str, Any] = {}

        def run() -> None:
            result["rc"], result["out"] = run_cli(channel, "monitor", "--count", "3",
                                                  "--timeout", "5")
            done.set()

        t = threading.Thread(target=run)
        t.start()
        bad = bytearray(alacs_can.encode_command(db, "STOP", 1).data)
        bad[7] ^= 0xFF
        frames = [
            can.Message(arbitration_id=0x123, data=b"\xAB\xCD", is_extended_id=False),
            can.Message(arbitration_id=0x210, data=bytes(bad), is_extended_id=False),
            alacs_can.encode_message(db, "Heartbeat", {"NmtState": "OPERATIONAL"}),
        ]
        while not done.wait(0.05):
            for f in frames:
                bus.send(f)
        t.join()
    assert result["rc"] == EXIT_OK
    text = result["out"]
    assert "123  [2] AB CD" in text
    assert "CHECKSUM-BAD" in text
    assert "NmtState=OPERATIONAL" in text


def test_nmt(sensor: FakeSensor, channel: str) -> None:
    rc, _ = run_cli(channel, "nmt", "start")
    assert rc == EXIT_OK
    rc, _ = run_cli(channel, "nmt", "reset-node", "--all")
    assert rc == EXIT_OK
    for _ in range(100):
        if len(sensor.received) >= 2:
            break
        threading.Event().wait(0.01)
    nmt = [alacs_can.decode(sensor.db, m) for m in sensor.received if m.arbitration_id == 0]
    assert nmt == [{"NmtCommand": "START", "NmtNodeId": 0x10},
                   {"NmtCommand": "RESET_NODE", "NmtNodeId": 0}]


def test_other_node_id(channel: str) -> None:
    fake = FakeSensor(channel, node_id=0x22)
    fake.start()
    try:
        rc, out = run_cli(channel, "--node-id", "0x22", "version")
    finally:
        fake.stop()
    assert rc == EXIT_OK, out
    assert fake.received[0].arbitration_id == 0x222


def test_dbc_command() -> None:
    out = io.StringIO()
    assert main(["dbc", "--node-id", "0x20"], out=out) == EXIT_OK
    assert out.getvalue() == alacs_can.dbc_text(0x20)
    out = io.StringIO()
    assert main(["--node-id", "3", "dbc"], out=out) == EXIT_OK
    assert out.getvalue() == alacs_can.dbc_text(3)


def test_bad_node_id(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["dbc", "--node-id", "0"])
    assert exc.value.code == EXIT_USAGE


def test_console_entry_point() -> None:
    proc = subprocess.run([sys.executable, "-m", "alacs_cli", "--help"], capture_output=True,
                          text=True, check=False)
    assert proc.returncode == 0
    for word in ("localize", "status", "monitor", "dbc", "home", "stop", "version"):
        assert word in proc.stdout


def test_scan_alias(sensor: FakeSensor, channel: str) -> None:
    rc, out = run_cli(channel, "scan", "--mode", "continuous")
    assert rc == EXIT_OK, out
    assert sensor.commands()[-1]["CmdOpcode"] == "SCAN_ALL"


def test_monitor_table_view(sensor: FakeSensor, channel: str) -> None:
    sensor.status_every_s = 0.02
    rc, out = run_cli(channel, "monitor", "--view", "table", "--count", "5", "--timeout", "5")
    assert rc == EXIT_OK
    last = out.split("alacs monitor:")[-1]
    assert "5 frames, 1 rows" in last
    (row,) = [line for line in last.splitlines() if "ALACS_Status" in line]
    assert row.split()[0] == "490" and row.split()[2] == "5"
    assert "State=IDLE" in row and "FaultCameraTimeout=1" in row
    assert "FaultLimitHit" not in row  # zero fault bits are left out of the table


def test_record_then_replay(sensor: FakeSensor, channel: str, tmp_path: Any) -> None:
    """record writes candump -L text that cantools and replay read back; replay sends it
    onto the bus again with the recorded frames' ids and bytes."""
    log = tmp_path / "bus.log"
    sensor.status_every_s = 0.01
    rc, out = run_cli(channel, "record", str(log), "--count", "6")
    assert rc == EXIT_OK and "recorded 6 frames" in out
    lines = log.read_text().splitlines()
    assert len(lines) == 6 and all(" 490#" in line for line in lines), lines
    rc, out = main(["replay", str(log), "--print"], out=(buf := io.StringIO())), buf.getvalue()
    assert rc == EXIT_OK
    assert out.count("ALACS_Status") == 6 and "State=IDLE" in out
    sensor.status_every_s = None
    with can.Bus(interface="virtual", channel=channel) as listener:
        rc, out = run_cli(channel, "replay", str(log), "--fast")
        assert rc == EXIT_OK and "replayed 6 frames" in out
        got = [listener.recv(timeout=1.0) for _ in range(6)]
    assert all(m is not None and m.arbitration_id == 0x490 for m in got)
    assert [bytes(m.data).hex().upper() for m in got] == [
        line.split("#")[1].split()[0] for line in lines]


def test_bus_arg_parsing() -> None:
    from alacs_cli.main import _bus_arg
    assert _bus_arg("port=29536") == ("port", 29536)
    assert _bus_arg("host=10.0.0.5") == ("host", "10.0.0.5")
    assert _bus_arg("fd=true") == ("fd", True)
    import argparse
    with pytest.raises(argparse.ArgumentTypeError, match="KEY=VALUE"):
        _bus_arg("nokey")
    with pytest.raises(argparse.ArgumentTypeError, match="KEY=VALUE"):
        _bus_arg("=5")
