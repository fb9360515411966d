"""Bad traffic against the real alacsd on vcan inside the UML bench: unknown ids ignored and
counted, bad DLC/checksum/counter NACKed with their reason, every standard id x DLC 0..8
with random payloads survived, bus-off and restart handled without losing a result."""

from __future__ import annotations

import json
import random
import struct
import time
from pathlib import Path

import can
import exchange
import pytest
from test_can_canopen import IFACE, Alacsd, wait_for, wait_idle_homed

import alacs_can as ac

NODE = 0x10
DB = ac.load_database(NODE)
ACK_ID = ac.frame_id(ac.MSG_ACK, NODE)
CMD_ID = ac.frame_id(ac.MSG_COMMAND, NODE)
SDO_RX, SDO_TX = ac.frame_id(ac.MSG_SDO_RX, NODE), ac.frame_id(ac.MSG_SDO_TX, NODE)


def sdo_read(bus: can.BusABC, index: int, sub: int) -> int:
    bus.send(can.Message(arbitration_id=SDO_RX, data=ac.sdo.upload_request(index, sub),
                         is_extended_id=False))
    answer = wait_for(bus, lambda m: m.arbitration_id == SDO_TX and m.data[1:4] ==
                      struct.pack("<HB", index, sub), 2.0)
    assert answer is not None, f"no SDO answer for {index:04X}.{sub}"
    response = ac.sdo.parse_response(bytes(answer.data))
    assert not response.aborted, response
    return response.value()


def drain(bus: can.BusABC, max_s: float = 1.0) -> int:
    """Drop what is already received (answers to earlier junk), so waits see only new
    frames: until 50 ms pass without one, or `max_s` (periodic traffic never stops)."""
    n = 0
    end = time.monotonic() + max_s
    while time.monotonic() < end and bus.recv(timeout=0.05) is not None:
        n += 1
    return n


def ack_of(bus: can.BusABC, counter: int, timeout_s: float = 2.0, opcode: int | None = None) -> dict:
    msg = wait_for(bus, lambda m: m.arbitration_id == ACK_ID and (m.data[1] & 0x0F) == counter
                   and (opcode is None or m.data[0] == opcode), timeout_s)
    assert msg is not None, f"no ack for counter {counter}"
    return ac.decode(DB, msg)


def raw(can_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


@pytest.fixture
def daemon(alacsd: Path, tmp_path: Path):  # noqa: ANN201
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(exchange.make_scene(7)))
    d = Alacsd(alacsd, NODE, "--sim-scene", str(scene))
    bus = can.Bus(interface="socketcan", channel=IFACE)
    d.start()
    d.scene = json.loads(scene.read_text())  # type: ignore[attr-defined]
    try:
        wait_idle_homed(bus, NODE)
        yield d, bus
    finally:
        bus.shutdown()
        rc = d.stop()
        assert rc == 0, d.log[-3000:]


def localize(bus: can.BusABC, scene: dict, counter: int, target: int,
             timeout_s: float = 30.0) -> ac.LocalizationResult:
    x, y, z = scene["apples"][0]["center_mm"]
    bus.send(ac.encode_command(DB, "LOCALIZE", counter, LocalizeMode="STOP_AND_GO",
                               TargetId=target, RoughX=round(x), RoughY=round(y),
                               RoughZ=round(z, -1)))
    collector = ac.ResultCollector(DB)
    acked = False
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        m = bus.recv(timeout=0.2)
        if m is None or m.is_error_frame:
            continue
        if m.arbitration_id == ACK_ID and (m.data[1] & 0x0F) == counter and m.data[0] == 1:
            ack = ac.decode(DB, m)
            assert ack["AckResult"] == "ACK", ack
            acked = True
        result = collector.push(m)
        if result is not None and result.target_id == target:
            assert acked, "result before its ACK"
            return result
    raise AssertionError(f"no result for target {target} within {timeout_s} s")


def test_unknown_ids_ignored_and_counted(daemon) -> None:  # noqa: ANN001
    d, bus = daemon
    before = sdo_read(bus, 0x2100, 2)
    # Ids of the sensor's block that it does not consume (RPDO2..4, 0x790, one of its own
    # Tx ids), and ids of other nodes and its own heartbeat id (filtered in the kernel,
    # never seen, never counted: the kernel sends the sensor's heartbeat for it).
    ours = [0x300 + NODE, 0x400 + NODE, 0x500 + NODE, 0x100 + NODE, 0x780 + NODE, 0x480 + NODE]
    for can_id in ours:
        bus.send(raw(can_id, b"\x01\x02\x03"))
    for can_id in (0x211, 0x611, 0x123, 0x7FF, 0x700 + NODE):
        bus.send(raw(can_id, bytes(8)))
    time.sleep(0.3)
    assert sdo_read(bus, 0x2100, 2) - before == len(ours)
    status = wait_for(bus, lambda m: m.arbitration_id == ac.frame_id(ac.MSG_STATUS, NODE), 2.0)
    assert ac.decode(DB, status)["RxErrorCount"] >= len(ours)
    bus.send(ac.encode_command(DB, "GET_VERSION", 2))
    assert ack_of(bus, 2)["AckResult"] == "ACK"


def test_bad_dlc_checksum_counter_get_nack_with_reason(daemon) -> None:  # noqa: ANN001
    d, bus = daemon
    good = bytes(ac.encode_command(DB, "GET_VERSION", 5).data)
    bus.send(raw(CMD_ID, good[:7]))
    assert ack_of(bus, 5)["NackReason"] == "BAD_DLC"
    bus.send(raw(CMD_ID, b""))
    ack = ack_of(bus, 0)
    assert (ack["AckOpcode"], ack["NackReason"], ack["RejectedOpcode"]) == ("INVALID", "BAD_DLC", 0)
    bad = bytearray(good)
    bad[7] ^= 0x5A
    bus.send(raw(CMD_ID, bytes(bad)))
    assert ack_of(bus, 5)["NackReason"] == "BAD_CHECKSUM"
    unknown = bytearray([0x33, 0x06, 0, 0, 0, 0, 0, 0])
    unknown[7] = ac.command_checksum(unknown)
    bus.send(raw(CMD_ID, bytes(unknown)))
    ack = ack_of(bus, 6)
    assert (ack["AckOpcode"], ack["NackReason"], ack["RejectedOpcode"]) == (
        "INVALID", "UNKNOWN_OPCODE", 0x33)
    # The counter: accepted once, the same counter within 1 s is a duplicate.
    bus.send(ac.encode_command(DB, "CLEAR_FAULT", 7))
    assert ack_of(bus, 7)["AckResult"] == "ACK"
    bus.send(ac.encode_command(DB, "CLEAR_FAULT", 7))
    ack = ack_of(bus, 7)
    assert (ack["AckResult"], ack["NackReason"]) == ("NACK", "BAD_COUNTER")
    bus.send(ac.encode_command(DB, "CLEAR_FAULT", 8))
    assert ack_of(bus, 8)["AckResult"] == "ACK"
    # A value outside its range: BAD_VALUE.
    localize9 = bytes(ac.encode_command(DB, "LOCALIZE", 9, LocalizeMode=0, TargetId=1, RoughX=0,
                                        RoughY=0, RoughZ=600).data)
    bus.send(raw(CMD_ID, _with_crc(localize9, 1, 0x39)))  # LocalizeMode 3 (0..1), counter 9
    assert ack_of(bus, 9)["NackReason"] == "BAD_VALUE"
    assert sdo_read(bus, 0x2100, 3) >= 5


def _with_crc(data: bytes, byte: int, value: int) -> bytes:
    out = bytearray(data)
    out[byte] = value
    out[7] = ac.command_checksum(out)
    return bytes(out)


def test_every_standard_id_and_dlc_with_random_payloads(daemon) -> None:  # noqa: ANN001
    """2048 ids x DLC 0..8 once each, then 300 random frames per id of the sensor's own
    block (the ones the kernel filter lets through) x DLC: alacsd neither crashes nor
    stops answering, and a localization works afterwards."""
    d, bus = daemon
    rng = random.Random(20260522)
    sent = 0
    for can_id in range(0x800):
        for dlc in range(9):
            bus.send(raw(can_id, rng.randbytes(dlc)))
            sent += 1
        if can_id % 64 == 0:
            time.sleep(0.005)  # vcan has no flow control; do not overrun our own socket
    block = [base + NODE for base in range(0, 0x800, 0x80)] + [0x000]
    for can_id in block:
        for dlc in range(9):
            for _ in range(300 if can_id != 0 else 20):
                bus.send(raw(can_id, rng.randbytes(dlc)))
                sent += 1
            time.sleep(0.002)
    assert sent > 18432 + 40000
    time.sleep(1.0)
    assert d.alive(), d.log[-3000:]
    # Random NMT frames may have stopped or reset the node; random commands (1 in 256 has
    # a good CRC) may have stopped the sensor: put it back, then it must work as new.
    bus.send(raw(0x000, bytes([1, 0])))
    time.sleep(0.3)
    drain(bus)
    bus.send(ac.encode_command(DB, "CLEAR_FAULT", 11))
    ack_of(bus, 11, opcode=int(ac.Opcode.CLEAR_FAULT))
    bus.send(ac.encode_command(DB, "GET_VERSION", 12))
    version = ack_of(bus, 12, opcode=int(ac.Opcode.GET_VERSION))
    assert version["AckResult"] == "ACK", version
    assert version["ProtocolVersion"] == ac.PROTOCOL_VERSION
    if not wait_idle_homed_or_home(bus):
        pytest.fail("sensor not IDLE and homed after the sweep")
    result = localize(bus, d.scene, 13, 77)
    assert result.status == ac.ResultStatus.MEASURED and result.object_count == 1


def wait_idle_homed_or_home(bus: can.BusABC) -> bool:
    status_id = ac.frame_id(ac.MSG_STATUS, NODE)
    m = wait_for(bus, lambda f: f.arbitration_id == status_id, 2.0)
    if m is None:
        return False
    s = ac.decode(DB, m, choices=False)
    if not s["Homed"]:
        bus.send(ac.encode_command(DB, "HOME", 14))
    try:
        wait_idle_homed(bus, NODE, 30.0)
    except AssertionError:
        return False
    return True


def test_bus_off_then_restart_loses_no_result(daemon) -> None:  # noqa: ANN001
    """A bus-off during a scan: the sensor stops transmitting, keeps scanning, and when the
    controller reports its restart it sends EMCY 0x8140, then the ACK and the result."""
    d, bus = daemon
    x, y, z = d.scene["apples"][0]["center_mm"]
    bus.send(ac.encode_command(DB, "LOCALIZE", 3, LocalizeMode="STOP_AND_GO", TargetId=9,
                               RoughX=round(x), RoughY=round(y), RoughZ=round(z, -1)))
    # The controller's report, as the kernel sends it (error frame, CAN_ERR_BUSOFF).
    bus.send(can.Message(arbitration_id=0x040 | 0x004, is_error_frame=True, data=bytes(8)))
    t_off = time.monotonic()
    during: list[can.Message] = []
    while time.monotonic() - t_off < 0.8:
        m = bus.recv(timeout=0.1)
        if m is not None and not m.is_error_frame and (m.arbitration_id & 0x7F) == NODE:
            during.append(m)
    # Frames already in flight when the report arrived may still come; then silence. The
    # heartbeat is the kernel's (CAN_BCM) and not held: a bus-off controller drops it.
    during = [m for m in during if m.arbitration_id != ac.frame_id(ac.MSG_HEARTBEAT, NODE)]
    late = [m for m in during if m.timestamp - during[0].timestamp > 0.05] if during else []
    assert not late, [hex(m.arbitration_id) for m in during]
    bus.send(can.Message(arbitration_id=0x100, is_error_frame=True, data=bytes(8)))
    collector = ac.ResultCollector(DB)
    emcy = None
    result = None
    end = time.monotonic() + 30
    while time.monotonic() < end and result is None:
        m = bus.recv(timeout=0.2)
        if m is None or m.is_error_frame:
            continue
        if m.arbitration_id == ac.frame_id(ac.MSG_EMCY, NODE) and emcy is None:
            emcy = ac.decode(DB, m)
        result = collector.push(m) or result
    assert emcy is not None and emcy["EmcyErrorCode"] == "CAN_BUS_OFF_RECOVERED", emcy
    assert emcy["EmcyReason"] == "CAN_BUS_OFF"
    assert result is not None and result.target_id == 9
    assert result.status == ac.ResultStatus.MEASURED, result
    status = wait_for(bus, lambda m: m.arbitration_id == ac.frame_id(ac.MSG_STATUS, NODE), 2.0)
    assert ac.decode(DB, status)["FaultCanBusOff"] == 1
    assert sdo_read(bus, 0x2100, 5) == 1
    bus.send(ac.encode_command(DB, "CLEAR_FAULT", 4))
    assert ack_of(bus, 4)["AckResult"] == "ACK"
    time.sleep(0.3)
    status = wait_for(bus, lambda m: m.arbitration_id == ac.frame_id(ac.MSG_STATUS, NODE), 2.0)
    assert ac.decode(DB, status)["FaultCanBusOff"] == 0
