"""Assemble ALACS_ResultHeader + ALACS_ResultObject pages into results.

Frames are pushed in; nothing here reads a bus or a clock (libcanard style).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import can
from cantools.database import Database
from cantools.database.errors import DecodeError

from . import constants as c
from .codec import decode

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Quality:
    sigma_mm: float
    confidence_pct: float
    diameter_mm: float
    occlusion_pct: float
    lines_used: int
    points_used: int


@dataclass
class ResultObject:
    """One localized object; a page is None until its frame has arrived."""

    index: int
    center_mm: Vec3 | None = None
    approach_mm: Vec3 | None = None
    quality: Quality | None = None
    normal: Vec3 | None = None
    """Approach direction, unit vector (camera frame)."""

    @property
    def complete(self) -> bool:
        return None not in (self.center_mm, self.approach_mm, self.quality, self.normal)


@dataclass
class LocalizationResult:
    """A ResultHeader and the objects announced by it, keyed by ``meas_counter``."""

    meas_counter: int
    object_count: int
    target_id: int
    scan_age_ms: float
    status: c.ResultStatus | int
    mode: c.ResultMode | int
    cycle_time_ms: float
    objects: list[ResultObject] = field(default_factory=list)
    reason: c.ResultReason | int = c.ResultReason.NONE

    @property
    def complete(self) -> bool:
        return all(o.complete for o in self.objects)

    @property
    def measured(self) -> bool:
        """True only for ResultStatus MEASURED: every other status is not a measurement."""
        return self.status == c.ResultStatus.MEASURED


def _enum(
    enum: type[c.ResultStatus] | type[c.ResultMode] | type[c.ResultReason], raw: int
) -> c.ResultStatus | c.ResultMode | c.ResultReason | int:
    try:
        return enum(raw)
    except ValueError:
        return raw


class ResultCollector:
    """Collects result frames of one sensor.

    ``push`` every received frame (others are ignored). It returns the
    ``LocalizationResult`` when its last expected page arrives, once. Pages are
    matched to the newest header whose MeasCounter low byte equals ObjMeasCounter;
    pages without a header are counted in ``orphan_frames``. At most ``max_results``
    results are kept in ``results`` (oldest dropped). Not thread-safe.
    """

    def __init__(self, db: Database, max_results: int = 8) -> None:
        self._db = db
        self._header_id = db.get_message_by_name(c.MSG_RESULT_HEADER).frame_id
        self._object_id = db.get_message_by_name(c.MSG_RESULT_OBJECT).frame_id
        self._max = max_results
        self.results: OrderedDict[int, LocalizationResult] = OrderedDict()
        self.orphan_frames = 0
        self.bad_frames = 0

    def push(self, msg: can.Message) -> LocalizationResult | None:
        if msg.is_extended_id or msg.arbitration_id not in (self._header_id, self._object_id):
            return None
        try:
            sig = decode(self._db, msg, choices=False)
        except (DecodeError, ValueError):
            self.bad_frames += 1
            return None
        if msg.arbitration_id == self._header_id:
            return self._on_header(sig)
        return self._on_object(sig)

    def _on_header(self, sig: dict[str, int | float | str]) -> LocalizationResult | None:
        count = min(int(sig["ObjectCount"]), c.MAX_OBJECTS)
        result = LocalizationResult(
            meas_counter=int(sig["MeasCounter"]),
            object_count=int(sig["ObjectCount"]),
            target_id=int(sig["ResultTargetId"]),
            scan_age_ms=float(sig["ScanAgeMs"]),
            status=_enum(c.ResultStatus, int(sig["ResultStatus"])),
            mode=_enum(c.ResultMode, int(sig["ResultMode"])),
            cycle_time_ms=float(sig["CycleTime"]),
            objects=[ResultObject(i) for i in range(count)],
            reason=_enum(c.ResultReason, int(sig["ResultReason"])),
        )
        self.results.pop(result.meas_counter, None)
        self.results[result.meas_counter] = result
        while len(self.results) > self._max:
            self.results.popitem(last=False)
        return result if result.complete else None

    def _on_object(self, sig: dict[str, int | float | str]) -> LocalizationResult | None:
        low = int(sig["ObjMeasCounter"])
        result = next(
            (r for r in reversed(self.results.values()) if r.meas_counter & 0xFF == low), None
        )
        index = int(sig["ObjIndex"])
        if result is None or index >= len(result.objects):
            self.orphan_frames += 1
            return None
        was_complete = result.complete
        obj = result.objects[index]
        page = int(sig["ObjPage"])

        def vec(prefix: str) -> Vec3:
            return (float(sig[f"{prefix}X"]), float(sig[f"{prefix}Y"]), float(sig[f"{prefix}Z"]))

        if page == c.ObjPage.CENTER:
            obj.center_mm = vec("Center")
        elif page == c.ObjPage.APPROACH_POINT:
            obj.approach_mm = vec("Approach")
        elif page == c.ObjPage.QUALITY:
            obj.quality = Quality(
                sigma_mm=float(sig["SigmaMm"]),
                confidence_pct=float(sig["Confidence"]),
                diameter_mm=float(sig["DiameterMm"]),
                occlusion_pct=float(sig["OcclusionPct"]),
                lines_used=int(sig["LinesUsed"]),
                points_used=int(sig["PointsUsed"]),
            )
        elif page == c.ObjPage.APPROACH_NORMAL:
            obj.normal = vec("Normal")
        # A repeated page after completion must not report the result twice.
        return result if result.complete and not was_complete else None
