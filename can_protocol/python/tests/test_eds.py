"""The EDS and the C object-dictionary table: generated from the spec, loadable by a
real CANopen stack, and the golden SDO exchanges agree with the reference server."""

from __future__ import annotations

import json
from pathlib import Path

import can
import canopen
import pytest

import alacs_can
from alacs_can import eds, sdo
from alacs_can.spec import OBJECTS, OD_ENTRIES

ROOT = Path(__file__).resolve().parents[2]


def test_committed_eds_and_header_are_current() -> None:
    assert (ROOT / "alacs.eds").read_bytes() == eds.eds_text().encode("ascii")
    assert (ROOT / "generated" / "alacs_od.h").read_text() == eds.od_header_text()


@pytest.mark.parametrize("node_id", [0x10, 0x7F])
def test_canopen_library_loads_the_eds_as_the_spec_says(node_id: int) -> None:
    od = canopen.import_od(str(ROOT / "alacs.eds"), node_id)
    assert sorted(od.indices) == sorted(o.index for o in OBJECTS)
    for e in OD_ENTRIES:
        obj = od[e.index]
        var = obj[e.sub] if isinstance(obj, canopen.objectdictionary.ODRecord) else obj
        assert var.name == e.name
        assert var.data_type == e.type_code
        assert var.access_type == e.access
        assert var.default == e.default
        if e.access == "rw" and e.limits() != (0, (1 << (8 * e.size)) - 1):
            assert (var.min, var.max) == e.limits()
    assert od["Identity object"]["Product code"].default == 0x414C4353
    assert od[0x1018][3].default >> 16 == alacs_can.PROTOCOL_VERSION


def test_heartbeat_object_default_is_the_protocol_default() -> None:
    (hb,) = [e for e in OD_ENTRIES if e.index == 0x1017]
    # The contract's own figure (docs/can-protocol.md), not the constant the spec is built from.
    assert hb.default == alacs_can.DEFAULT_HEARTBEAT_MS == 1000


def test_golden_sdo_uploads_answer_what_the_eds_says() -> None:
    """Every golden upload of an existing entry is an expedited answer (CiA 301: 0x43, 0x47,
    0x4B or 0x4F by size) with the EDS's default as canopen reads it from the committed file:
    a check of the golden answers that does not go through the reference server that made them."""
    golden = json.loads((ROOT / "vectors" / "golden.json").read_text())
    od = canopen.import_od(str(ROOT / "alacs.eds"), 0x10)
    checked = 0
    for ex in golden["sdo_exchanges"]:
        req, rsp = bytes.fromhex(ex["request"]), bytes.fromhex(ex["response"])
        if req[0] != 0x40 or not rsp or rsp[0] == 0x80:
            continue
        index, sub = int.from_bytes(req[1:3], "little"), req[3]
        obj = od[index]
        var = obj if isinstance(obj, canopen.objectdictionary.ODVariable) else obj[sub]
        size = len(var.encode_raw(var.default))
        assert rsp[0] == 0x43 | ((4 - size) << 2), ex["name"]
        assert rsp[1:4] == req[1:4], ex["name"]
        assert int.from_bytes(rsp[4:4 + size], "little") == var.default, ex["name"]
        assert not any(rsp[4 + size:]), ex["name"]
        checked += 1
    assert checked >= 20


def test_golden_sdo_exchanges_follow_the_reference_server() -> None:
    golden = json.loads((ROOT / "vectors" / "golden.json").read_text())
    exchanges = golden["sdo_exchanges"]
    assert len(exchanges) > 30
    values = sdo.default_values()
    for ex in exchanges:
        response = sdo.reference_response(bytes.fromhex(ex["request"]), values)
        assert (response.hex().upper() if response else "") == ex["response"], ex["name"]
    aborts = {sdo.parse_response(bytes.fromhex(ex["response"])).abort
              for ex in exchanges if ex["response"] and ex["response"].startswith("80")}
    assert {alacs_can.SdoAbort.READ_ONLY, alacs_can.SdoAbort.NO_OBJECT,
            alacs_can.SdoAbort.NO_SUBINDEX, alacs_can.SdoAbort.VALUE_TOO_HIGH,
            alacs_can.SdoAbort.VALUE_TOO_LOW, alacs_can.SdoAbort.LENGTH_MISMATCH,
            alacs_can.SdoAbort.UNKNOWN_COMMAND} <= aborts


def test_reference_uploads_match_a_real_canopen_sdo_server() -> None:
    """canopen's LocalNode is an independent SDO server implementation: loaded with our
    EDS it must answer every upload request with the same bytes as the reference."""
    network = canopen.Network()
    network.connect(interface="virtual", channel="alacs_eds_test", receive_own_messages=False)
    client_bus = can.Bus(interface="virtual", channel="alacs_eds_test")
    try:
        canopen.LocalNode(0x10, str(ROOT / "alacs.eds")).associate_network(network)
        values = sdo.default_values()
        for e in OD_ENTRIES:
            request = sdo.upload_request(e.index, e.sub)
            client_bus.send(can.Message(arbitration_id=0x610, data=request, is_extended_id=False))
            answer = client_bus.recv(timeout=2.0)
            assert answer is not None and answer.arbitration_id == 0x590
            assert bytes(answer.data) == sdo.reference_response(request, values), hex(e.index)
    finally:
        client_bus.shutdown()
        network.disconnect()


def test_error_register_per_fault() -> None:
    assert alacs_can.error_register(0) == 0
    assert alacs_can.error_register(alacs_can.Fault.CAMERA_TIMEOUT) == 0x01
    assert alacs_can.error_register(alacs_can.Fault.CAN_BUS_OFF) == 0x11
