"""ResultCollector: header + object pages -> LocalizationResult."""

from __future__ import annotations

import can
import pytest
from cantools.database import Database

import alacs_can
from alacs_can import ObjPage, ResultCollector, ResultStatus


def header(db: Database, meas: int, count: int, status: str = "MEASURED",
           target: int = 3) -> can.Message:
    return alacs_can.encode_message(db, "ALACS_ResultHeader", dict(
        MeasCounter=meas, ObjectCount=count, ResultTargetId=target, ScanAgeMs=40,
        ResultStatus=status, ResultReason="NONE", ResultMode="LOCALIZE", CycleTime=900))


def pages(db: Database, meas: int, index: int, base: float = 0.0) -> list[can.Message]:
    common = dict(ObjIndex=index, ObjMeasCounter=meas & 0xFF)
    return [
        alacs_can.encode_message(db, "ALACS_ResultObject", dict(
            common, ObjPage="CENTER", CenterX=base - 10.5, CenterY=20.2, CenterZ=600.1)),
        alacs_can.encode_message(db, "ALACS_ResultObject", dict(
            common, ObjPage="APPROACH_POINT", ApproachX=base - 10, ApproachY=20, ApproachZ=540)),
        alacs_can.encode_message(db, "ALACS_ResultObject", dict(
            common, ObjPage="QUALITY", SigmaMm=0.7, Confidence=90, DiameterMm=75.5,
            OcclusionPct=10, LinesUsed=8, PointsUsed=999)),
        alacs_can.encode_message(db, "ALACS_ResultObject", dict(
            common, ObjPage="APPROACH_NORMAL", NormalX=0, NormalY=-0.6, NormalZ=0.8)),
    ]


def test_single_object_result(db: Database) -> None:
    col = ResultCollector(db)
    assert col.push(header(db, 42, 1)) is None
    frames = pages(db, 42, 0)
    for f in frames[:-1]:
        assert col.push(f) is None
    result = col.push(frames[-1])
    assert result is not None and result.complete
    assert (result.meas_counter, result.object_count, result.target_id) == (42, 1, 3)
    assert result.status is ResultStatus.MEASURED
    assert result.cycle_time_ms == 900 and result.scan_age_ms == 40
    obj = result.objects[0]
    assert obj.center_mm == pytest.approx((-10.5, 20.2, 600.1))
    assert obj.approach_mm == pytest.approx((-10, 20, 540))
    assert obj.normal == pytest.approx((0, -0.6, 0.8), abs=1e-4)
    assert obj.quality is not None
    assert obj.quality.points_used == 999 and obj.quality.diameter_mm == 75.5
    assert col.results[42] is result


def test_no_object_result_is_complete_on_header(db: Database) -> None:
    col = ResultCollector(db)
    result = col.push(header(db, 7, 0, status="NOT_FOUND"))
    assert result is not None and result.objects == []
    assert result.status is ResultStatus.NOT_FOUND


def test_pages_out_of_order_and_interleaved(db: Database) -> None:
    col = ResultCollector(db)
    col.push(header(db, 300, 2))
    a, b = pages(db, 300, 0, base=1), pages(db, 300, 1, base=2)
    order = [b[3], a[1], a[0], b[0], b[1], a[3], b[2]]
    assert all(col.push(f) is None for f in order)
    result = col.push(a[2])
    assert result is not None and [o.index for o in result.objects] == [0, 1]
    assert result.objects[1].center_mm is not None
    assert result.objects[1].center_mm[0] == pytest.approx(2 - 10.5)
    # a repeated page does not report the result again
    assert col.push(a[2]) is None


def test_orphans_and_foreign_frames(db: Database) -> None:
    col = ResultCollector(db)
    assert col.push(pages(db, 5, 0)[0]) is None
    assert col.orphan_frames == 1
    col.push(header(db, 5, 1))
    assert col.push(pages(db, 5, 3)[0]) is None  # index beyond ObjectCount
    assert col.orphan_frames == 2
    assert col.push(alacs_can.encode_command(db, "STOP", 1)) is None
    bad = can.Message(arbitration_id=0x390, data=b"\x0e" + bytes(7), is_extended_id=False)
    assert col.push(bad) is None and col.bad_frames == 1


def test_matches_low_byte_and_prefers_newest(db: Database) -> None:
    col = ResultCollector(db)
    col.push(header(db, 0x0105, 1))
    col.push(header(db, 0x0205, 1))  # same low byte, newer
    result = None
    for f in pages(db, 0x0205, 0):
        result = col.push(f) or result
    assert result is not None and result.meas_counter == 0x0205
    assert not col.results[0x0105].complete


def test_keeps_bounded_history(db: Database) -> None:
    col = ResultCollector(db, max_results=3)
    for meas in range(10):
        col.push(header(db, meas, 0, status="NOT_FOUND"))
    assert list(col.results) == [7, 8, 9]


def test_page_enum_order_matches_doc() -> None:
    assert [p.name for p in ObjPage] == ["CENTER", "APPROACH_POINT", "QUALITY", "APPROACH_NORMAL"]


def test_only_measured_is_a_measurement(db: Database) -> None:
    col = ResultCollector(db)
    msg = alacs_can.encode_message(db, "ALACS_ResultHeader", dict(
        MeasCounter=9, ObjectCount=0, ResultTargetId=3, ScanAgeMs=40, ResultStatus="AMBIGUOUS",
        ResultReason="TWO_SURFACES", ResultMode="LOCALIZE", CycleTime=900))
    result = col.push(msg)
    assert result is not None and not result.measured
    assert result.reason is alacs_can.ResultReason.TWO_SURFACES
    result = col.push(header(db, 10, 0))
    assert result is not None and result.measured and result.reason is alacs_can.ResultReason.NONE
