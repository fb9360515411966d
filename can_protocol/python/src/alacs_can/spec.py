"""The ALACS CAN protocol as data: every message and signal, once.

``dbc.py`` renders this into DBC text (the committed ``can_protocol/alacs.dbc`` is
that text for node id 0x10) and everything else (cantools encode/decode, the
generated C codec, the golden vectors) is derived from the DBC. Edit the protocol
here, then run ``can_protocol/generate.sh``.

All signals are little-endian (Intel). Bit numbers are DBC start bits, i.e. bit
``n`` is bit ``n % 8`` of byte ``n // 8``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Final

from . import constants as c


@dataclass(frozen=True)
class SignalSpec:
    """One DBC signal. ``minimum``/``maximum`` are physical and default to the raw range."""

    name: str
    start: int
    length: int
    comment: str
    signed: bool = False
    scale: float = 1
    offset: float = 0
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    choices: type[IntEnum] | None = None
    mux: tuple[str, int | tuple[int, ...]] | None = None
    """(multiplexer signal, value or values) under which this signal is present."""
    is_multiplexer: bool = False

    def mux_values(self) -> tuple[int, ...]:
        """The multiplexer values under which this signal is present (() if always)."""
        if self.mux is None:
            return ()
        values = self.mux[1]
        return (values,) if isinstance(values, int) else tuple(values)

    def raw_range(self) -> tuple[int, int]:
        if self.signed:
            return -(1 << (self.length - 1)), (1 << (self.length - 1)) - 1
        return 0, (1 << self.length) - 1

    def phys_range(self) -> tuple[float, float]:
        lo, hi = self.raw_range()
        lo_p = lo * self.scale + self.offset if self.minimum is None else self.minimum
        hi_p = hi * self.scale + self.offset if self.maximum is None else self.maximum
        return lo_p, hi_p


@dataclass(frozen=True)
class MessageSpec:
    name: str
    base_id: int
    dlc: int
    sender: str
    receiver: str
    comment: str
    signals: tuple[SignalSpec, ...]
    cycle_ms: int = 0
    """0 = sent on event only."""
    node_offset: bool = True
    extra: dict[str, str] = field(default_factory=dict)

    def frame_id(self, node_id: int) -> int:
        return self.base_id + c.check_node_id(node_id) if self.node_offset else self.base_id

    def signal(self, name: str) -> SignalSpec:
        for s in self.signals:
            if s.name == name:
                return s
        raise KeyError(name)

    @property
    def has_extended_mux(self) -> bool:
        """Needs DBC extended multiplexing (SG_MUL_VAL_): a multiplexer inside a branch,
        or a signal present under more than one multiplexer value."""
        return (sum(1 for s in self.signals if s.is_multiplexer) > 1
                or any(len(s.mux_values()) > 1 for s in self.signals))


S = SignalSpec
SENSOR, ARM = c.SENSOR_NODE, c.CONTROLLER_NODE
_POS_SCALE: Final = 0.1
_NORMAL_SCALE: Final = 1 / 32767


def _op(op: c.Opcode) -> tuple[str, int]:
    return ("CmdOpcode", int(op))


def _cfg(page: c.CfgPage) -> tuple[str, int]:
    return ("CfgPage", int(page))


def _xyz(prefix: str, page: c.ObjPage, what: str) -> tuple[SignalSpec, ...]:
    mux = ("ObjPage", int(page))
    return (
        S(f"{prefix}X", 16, 16, f"{what}, camera frame x (right).", signed=True,
          scale=_POS_SCALE, unit="mm", mux=mux),
        S(f"{prefix}Y", 32, 16, f"{what}, camera frame y (down).", signed=True,
          scale=_POS_SCALE, unit="mm", mux=mux),
        S(f"{prefix}Z", 48, 16, f"{what}, camera frame z (forward, >= 0).",
          scale=_POS_SCALE, unit="mm", mux=mux),
    )


COMMAND = MessageSpec(
    c.MSG_COMMAND, c.BASE_ID_COMMAND, 8, ARM, SENSOR,
    "Command from the arm controller. Byte 7 is CRC-8/SAE-J1850 over bytes 0..6. "
    "Answered by ALACS_Ack with the same counter.",
    (
        S("CmdOpcode", 0, 8, "What to do; selects the payload layout.", is_multiplexer=True,
          minimum=1, maximum=7, choices=c.Opcode),
        S("CmdCounter", 8, 4, "4-bit rolling counter, +1 per command; echoed in AckCounter. "
          "A command repeating the previous accepted counter within 1 s is NACKed BAD_COUNTER."),
        S("CmdChecksum", 56, 8,
          "CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF) over bytes 0..6."),
        # LOCALIZE
        S("LocalizeMode", 12, 4, "Slide motion during the scan.", maximum=1,
          choices=c.ScanMode, mux=_op(c.Opcode.LOCALIZE)),
        S("TargetId", 16, 8, "Caller's id for this apple, echoed in ResultTargetId.",
          mux=_op(c.Opcode.LOCALIZE)),
        S("RoughX", 24, 12, "Rough apple position from the arm's camera, x (right), camera frame.",
          signed=True, unit="mm", mux=_op(c.Opcode.LOCALIZE)),
        S("RoughY", 36, 12, "Rough apple position, y (down), camera frame.",
          signed=True, unit="mm", mux=_op(c.Opcode.LOCALIZE)),
        S("RoughZ", 48, 8, "Rough apple position, z (forward), camera frame, 10 mm/bit.",
          scale=10, unit="mm", mux=_op(c.Opcode.LOCALIZE)),
        # SCAN_ALL
        S("ScanAllMode", 12, 4, "Slide motion during the scan.", maximum=1,
          choices=c.ScanMode, mux=_op(c.Opcode.SCAN_ALL)),
        # SET_CONFIG: two pages; a field is applied only if its valid bit is 1.
        S("CfgPage", 12, 4, "Which group of settings this SET_CONFIG frame carries.",
          is_multiplexer=True, maximum=1, choices=c.CfgPage, mux=_op(c.Opcode.SET_CONFIG)),
        S("CfgExposureValid", 16, 1, "1: apply CfgExposureUs.", mux=_cfg(c.CfgPage.ACQUISITION)),
        S("CfgBrceStepValid", 17, 1, "1: apply CfgBrceStep.", mux=_cfg(c.CfgPage.ACQUISITION)),
        S("CfgBrceThresholdValid", 18, 1, "1: apply CfgBrceThreshold.",
          mux=_cfg(c.CfgPage.ACQUISITION)),
        S("CfgExposureUs", 24, 16, "Camera exposure time (0 is rejected with BAD_VALUE).",
          unit="us", minimum=1, mux=_cfg(c.CfgPage.ACQUISITION)),
        S("CfgBrceStep", 40, 4, "bRCE laser-line extraction step, 1..15.",
          minimum=1, mux=_cfg(c.CfgPage.ACQUISITION)),
        S("CfgBrceThreshold", 48, 8, "bRCE laser-line intensity threshold (grey levels).",
          mux=_cfg(c.CfgPage.ACQUISITION)),
        S("CfgScanStopsValid", 16, 1, "1: apply CfgScanStops.", mux=_cfg(c.CfgPage.SCAN)),
        S("CfgStopSpacingValid", 17, 1, "1: apply CfgStopSpacingMm.", mux=_cfg(c.CfgPage.SCAN)),
        S("CfgHeartbeatValid", 18, 1, "1: apply CfgHeartbeatMs.", mux=_cfg(c.CfgPage.SCAN)),
        S("CfgScanStops", 20, 4, "Number of slide stops (laser lines) per scan, 1..15.",
          minimum=1, mux=_cfg(c.CfgPage.SCAN)),
        S("CfgStopSpacingMm", 24, 8, "Slide distance between stops.", scale=0.1, unit="mm",
          mux=_cfg(c.CfgPage.SCAN)),
        S("CfgHeartbeatMs", 32, 16, "Heartbeat producer period (CANopen 0x1017); 0 = off.",
          unit="ms", mux=_cfg(c.CfgPage.SCAN)),
    ),
)

_NACK_DETAIL_MUX: Final = ("AckOpcode", tuple(
    int(op) for op in c.Opcode if op is not c.Opcode.GET_VERSION))
"""Bytes 3..7 are free in the Ack of every opcode but GET_VERSION (and INVALID)."""

ACK = MessageSpec(
    c.MSG_ACK, c.BASE_ID_ACK, 8, SENSOR, ARM,
    "Answer to every ALACS_Command (also to rejected frames). DONE follows ACK when a "
    "long command (HOME) has finished.",
    (
        S("AckOpcode", 0, 8, "Echo of CmdOpcode; INVALID if the command had no known opcode.",
          is_multiplexer=True, maximum=7, choices=c.AckOpcode),
        S("AckCounter", 8, 4, "Echo of CmdCounter."),
        S("AckResult", 12, 4, "ACK: accepted; NACK: rejected (see NackReason); DONE: finished.",
          maximum=2, choices=c.AckResult),
        S("NackReason", 16, 8, "Why the command was rejected or failed; NONE unless NACK.",
          maximum=12, choices=c.NackReason),
        S("RejectedOpcode", 24, 8, "Byte 0 of the rejected command (0 if its DLC was 0).",
          mux=("AckOpcode", int(c.AckOpcode.INVALID))),
        S("SwMajor", 24, 8, "alacsd version, major.", mux=("AckOpcode", int(c.Opcode.GET_VERSION))),
        S("SwMinor", 32, 8, "alacsd version, minor.", mux=("AckOpcode", int(c.Opcode.GET_VERSION))),
        S("SwPatch", 40, 8, "alacsd version, patch.", mux=("AckOpcode", int(c.Opcode.GET_VERSION))),
        S("ProtocolVersion", 48, 8, f"This protocol's version ({c.PROTOCOL_VERSION}).",
          mux=("AckOpcode", int(c.Opcode.GET_VERSION))),
        S("NackDetail", 24, 8, "Which limit a NACKed command broke (NONE if none applies or "
          "not a NACK).", maximum=max(c.NackDetail), choices=c.NackDetail, mux=_NACK_DETAIL_MUX),
        S("NackValue", 32, 16, "The offending value, in the unit NackDetail names "
          "(saturating; 0 when NackDetail is NONE).", signed=True, scale=0.1,
          mux=_NACK_DETAIL_MUX),
        S("NackLimit", 48, 16, "The limit NackValue broke, same unit (saturating; 0 when "
          "NackDetail is NONE).", signed=True, scale=0.1, mux=_NACK_DETAIL_MUX),
    ),
)

RESULT_HEADER = MessageSpec(
    c.MSG_RESULT_HEADER, c.BASE_ID_RESULT_HEADER, 8, SENSOR, ARM,
    "First frame of a measurement result; ObjectCount x 4 ALACS_ResultObject pages follow.",
    (
        S("MeasCounter", 0, 16, "Measurement counter, +1 per result (wraps)."),
        S("ObjectCount", 16, 5, "Number of objects that follow (0..16).", maximum=c.MAX_OBJECTS),
        S("ResultMode", 21, 3, "Command that produced this result.", maximum=1,
          choices=c.ResultMode),
        S("ResultTargetId", 24, 8, "TargetId of the LOCALIZE command (0 for SCAN_ALL)."),
        S("ScanAgeMs", 32, 16, "Time since the last camera frame of the scan was exposed "
          "(saturating).", unit="ms"),
        S("ResultStatus", 48, 4, "Outcome: only MEASURED is a measurement.",
          maximum=max(c.ResultStatus), choices=c.ResultStatus),
        S("ResultReason", 52, 4, "Why the result is not MEASURED (NONE if it is; OUTSIDE_GATE if "
          "MEASURED by the widened search).",
          maximum=max(c.ResultReason), choices=c.ResultReason),
        S("CycleTime", 56, 8, "Time from the localize command to this result, 20 ms/bit "
          "(saturating).", scale=20, unit="ms"),
    ),
)

RESULT_OBJECT = MessageSpec(
    c.MSG_RESULT_OBJECT, c.BASE_ID_RESULT_OBJECT, 8, SENSOR, ARM,
    "One page of one object of the result with the same MeasCounter (low byte). "
    "Sent in page order CENTER, APPROACH_POINT, QUALITY, APPROACH_NORMAL per object.",
    (
        S("ObjPage", 0, 4, "Which page of the object this frame carries.", is_multiplexer=True,
          maximum=3, choices=c.ObjPage),
        S("ObjIndex", 4, 4, "Object index, 0..ObjectCount-1."),
        S("ObjMeasCounter", 8, 8, "Low byte of the ResultHeader's MeasCounter."),
        *_xyz("Center", c.ObjPage.CENTER, "Apple centre"),
        *_xyz("Approach", c.ObjPage.APPROACH_POINT, "Approach (pre-grasp) point"),
        S("SigmaMm", 16, 8, "1 sigma (3D) of the approach point, the chance of another object "
          "included; saturates: 25.5 means 25.5 mm or more.", scale=0.1, unit="mm",
          mux=("ObjPage", int(c.ObjPage.QUALITY))),
        S("Confidence", 24, 8, "Detection confidence.", unit="%", maximum=100,
          mux=("ObjPage", int(c.ObjPage.QUALITY))),
        S("DiameterMm", 32, 8, "Estimated apple diameter.", scale=0.5, unit="mm",
          mux=("ObjPage", int(c.ObjPage.QUALITY))),
        S("OcclusionPct", 40, 8, "Estimated occluded share of the visible surface.", unit="%",
          maximum=100, mux=("ObjPage", int(c.ObjPage.QUALITY))),
        S("LinesUsed", 48, 4, "Laser lines that hit the object.",
          mux=("ObjPage", int(c.ObjPage.QUALITY))),
        S("PointsUsed", 52, 12, "3D points used by the fit (saturating at 4095).",
          mux=("ObjPage", int(c.ObjPage.QUALITY))),
        *(S(f"Normal{axis}", start, 16, f"Approach direction unit vector, {axis.lower()} "
            "component (scale 1/32767).", signed=True, scale=_NORMAL_SCALE,
            minimum=-1, maximum=1, mux=("ObjPage", int(c.ObjPage.APPROACH_NORMAL)))
          for axis, start in (("X", 16), ("Y", 32), ("Z", 48))),
    ),
)

_FAULT_COMMENTS: Final[dict[c.Fault, str]] = {
    c.Fault.HOMING_TIMEOUT: "Home switch not reached in time.",
    c.Fault.LIMIT_HIT: "Slide reached a travel limit.",
    c.Fault.CAMERA_TIMEOUT: "No camera frame in time.",
    c.Fault.CAMERA_CORRUPT: "Corrupt or short camera frame.",
    c.Fault.CAN_BUS_OFF: "CAN controller went bus-off (latched until CLEAR_FAULT).",
    c.Fault.CAN_TX_OVERFLOW: "CAN transmit queue overflowed.",
    c.Fault.CONFIG_INVALID: "Stored configuration invalid; defaults in use.",
    c.Fault.NOT_CALIBRATED: "No valid camera/laser calibration.",
    c.Fault.LASER_OVERTIME: "Laser on-time limit hit; laser forced off.",
    c.Fault.INTERNAL: "Internal software error.",
    c.Fault.STOP_REQUESTED: "STOP command or NMT stop received; cleared by CLEAR_FAULT.",
}

STATUS = MessageSpec(
    c.MSG_STATUS, c.BASE_ID_STATUS, 8, SENSOR, ARM,
    "Sensor status, every 100 ms. Fault bits 0..10 are 1-bit signals Fault* at bits 8..18 "
    "(bits 19..23 reserved, 0), the same bits as EMCY.EmcyFaultBits.",
    (
        S("State", 0, 4, "Sensor state.", maximum=5, choices=c.SensorState),
        S("Homed", 4, 1, "1: slide homed."),
        S("LaserOn", 5, 1, "1: laser on."),
        S("Calibrated", 6, 1, "1: valid calibration loaded."),
        S("HomeSwitch", 7, 1, "1: home switch active."),
        *(S(name, 8 + flag.bit_length() - 1, 1, f"Fault bit {flag.bit_length() - 1} "
            f"{flag.name}: {_FAULT_COMMENTS[flag]}")
          for flag, name in c.FAULT_SIGNALS.items()),
        S("LastLatencyMs", 24, 12, "Latency of the last result: last exposure to ResultHeader "
          "queued (saturating).", unit="ms"),
        S("MaxLatencyMs", 36, 12, "Largest LastLatencyMs since boot or CLEAR_FAULT (saturating).",
          unit="ms"),
        S("DroppedFrames", 48, 8, "Camera frames dropped since boot (saturating)."),
        S("RxErrorCount", 56, 8, "Received frames with unknown ids or bad content "
          "(saturating)."),
    ),
    cycle_ms=c.STATUS_PERIOD_MS,
)

PROGRESS = MessageSpec(
    c.MSG_PROGRESS, c.BASE_ID_PROGRESS, 8, SENSOR, ARM,
    "Progress of a running LOCALIZE or SCAN_ALL: on every phase change, after every stop "
    "and at least every 500 ms until the result is sent.",
    (
        S("ProgressMeasCounter", 0, 16, "MeasCounter the result of this scan will carry."),
        S("ProgressCounter", 16, 4, "CmdCounter of the command that started the scan."),
        S("ProgressMode", 20, 4, "Command that started the scan.", maximum=1,
          choices=c.ResultMode),
        S("ProgressPhase", 24, 4, "What the scan is doing now.", maximum=max(c.ProgressPhase),
          choices=c.ProgressPhase),
        S("StopsDone", 32, 8, "Slide stops exposed so far (both passes)."),
        S("StopsTotal", 40, 8, "Slide stops planned so far; grows when a second pass is "
          "planned."),
        S("ObjectsFound", 48, 8, "Objects found so far (SCAN_ALL); 0 or 1 for LOCALIZE once "
          "fitted."),
        S("ElapsedS", 56, 8, "Time since the command, 0.5 s/bit (saturating).", scale=0.5,
          unit="s"),
    ),
)

NMT = MessageSpec(
    c.MSG_NMT, c.BASE_ID_NMT, 2, ARM, SENSOR,
    "CANopen NMT node control (fixed id 0x000).",
    (
        S("NmtCommand", 0, 8, "NMT command specifier.", minimum=1, maximum=130,
          choices=c.NmtCommand),
        S("NmtNodeId", 8, 8, "Addressed node id; 0 = all nodes.", maximum=127),
    ),
    node_offset=False,
)

HEARTBEAT = MessageSpec(
    c.MSG_HEARTBEAT, c.BASE_ID_HEARTBEAT, 1, SENSOR, ARM,
    "CANopen heartbeat / boot-up, every CfgHeartbeatMs (default 1000 ms).",
    (S("NmtState", 0, 8, "NMT state of the sensor.", maximum=127, choices=c.NmtState),),
    cycle_ms=c.DEFAULT_HEARTBEAT_MS,
)

EMCY = MessageSpec(
    c.MSG_EMCY, c.BASE_ID_EMCY, 8, SENSOR, ARM,
    "CANopen emergency: sent when a fault is raised and (code NO_ERROR) when all are cleared.",
    (
        S("EmcyErrorCode", 0, 16, "CiA 301 error code.", choices=c.EmcyErrorCode),
        S("EmcyErrorRegister", 16, 8, "CiA 301 error register (object 0x1001)."),
        S("EmcyFaultBits", 24, 16, "All active fault bits (same bits as ALACS_Status Fault*)."),
        S("EmcyReason", 40, 8, "The fault that raised this EMCY (fault bit + 1; 0 = cleared).",
          maximum=11, choices=c.EmcyReason),
    ),
)

SDO_TX = MessageSpec(
    c.MSG_SDO_TX, c.BASE_ID_SDO_TX, 8, SENSOR, ARM,
    "CANopen SDO response (server to client), expedited transfers only.",
    (
        S("SdoTxCommand", 0, 8, "SDO server command specifier.", choices=c.SdoServerCommand),
        S("SdoTxIndex", 8, 16, "Object dictionary index."),
        S("SdoTxSubIndex", 24, 8, "Object dictionary subindex."),
        S("SdoTxData", 32, 32, "Expedited data, or abort code for ABORT."),
    ),
)

SDO_RX = MessageSpec(
    c.MSG_SDO_RX, c.BASE_ID_SDO_RX, 8, ARM, SENSOR,
    "CANopen SDO request (client to server), expedited transfers only.",
    (
        S("SdoRxCommand", 0, 8, "SDO client command specifier.", choices=c.SdoClientCommand),
        S("SdoRxIndex", 8, 16, "Object dictionary index."),
        S("SdoRxSubIndex", 24, 8, "Object dictionary subindex."),
        S("SdoRxData", 32, 32, "Expedited data (download), 0 for upload requests."),
    ),
)

MESSAGES: Final[tuple[MessageSpec, ...]] = (
    NMT, EMCY, ACK, COMMAND, RESULT_HEADER, RESULT_OBJECT, STATUS, SDO_TX, SDO_RX, PROGRESS,
    HEARTBEAT,
)
"""All messages, in frame-id order."""

MESSAGES_BY_NAME: Final[dict[str, MessageSpec]] = {m.name: m for m in MESSAGES}


# --- CANopen object dictionary (the SDO server's objects) ------------------------------
#
# alacsd serves these over expedited SDO (SDO_Rx/SDO_Tx). The EDS file
# (can_protocol/alacs.eds) and the C table the daemon's SDO server is built from
# (can_protocol/generated/alacs_od.h) are both generated from this list.

OD_DEVICE_TYPE: Final = 0x00000000
"""0x1000: no CiA device profile (the sensor is manufacturer-specific)."""
OD_VENDOR_ID: Final = 0x00000000
"""0x1018.1: no CiA-assigned vendor id yet; 0 says so."""
OD_PRODUCT_CODE: Final = 0x414C4353
"""0x1018.2: ASCII "ALCS"."""
OD_REVISION: Final = c.PROTOCOL_VERSION << 16
"""0x1018.3: major revision = protocol version (CiA 301: major changes break compatibility)."""

_DATA_TYPES: Final = {"UNSIGNED8": (0x0005, 1), "UNSIGNED16": (0x0006, 2),
                      "UNSIGNED32": (0x0007, 4)}


@dataclass(frozen=True)
class OdEntry:
    """One object-dictionary variable (a VAR, or one sub-index of a RECORD)."""

    index: int
    sub: int
    symbol: str
    """C name: ALACS_OD_<symbol>_INDEX etc."""
    name: str
    """EDS ParameterName (what canopen's ``node.sdo[...]`` is keyed by)."""
    data_type: str
    access: str
    """'ro', 'rw' or 'const' (EDS AccessType)."""
    default: int
    comment: str
    low: int | None = None
    high: int | None = None
    unit: str = ""

    @property
    def size(self) -> int:
        return _DATA_TYPES[self.data_type][1]

    @property
    def type_code(self) -> int:
        return _DATA_TYPES[self.data_type][0]

    def limits(self) -> tuple[int, int]:
        full = (1 << (8 * self.size)) - 1
        return (self.low if self.low is not None else 0,
                self.high if self.high is not None else full)


@dataclass(frozen=True)
class OdObject:
    """One object-dictionary index: a VAR (one entry, sub 0) or a RECORD."""

    index: int
    name: str
    entries: tuple[OdEntry, ...]
    record: bool = False
    category: str = "optional"
    """'mandatory', 'optional' or 'manufacturer' (EDS object lists)."""


def _var(index: int, symbol: str, name: str, data_type: str, access: str, default: int,
         comment: str, category: str = "optional", **kw: object) -> OdObject:
    return OdObject(index, name, (OdEntry(index, 0, symbol, name, data_type, access, default,
                                          comment, **kw),), category=category)  # type: ignore[arg-type]


def _record(index: int, name: str, category: str,
            subs: tuple[tuple[str, str, str, str, int, str, dict[str, object]], ...]) -> OdObject:
    entries = [OdEntry(index, 0, f"{_sym(name)}_HIGHEST_SUB", "Highest sub-index supported",
                       "UNSIGNED8", "const", len(subs), "Number of sub-indices that follow.")]
    for n, (symbol, sub_name, data_type, access, default, comment, kw) in enumerate(subs, 1):
        entries.append(OdEntry(index, n, symbol, sub_name, data_type, access, default, comment,
                               **kw))  # type: ignore[arg-type]
    return OdObject(index, name, tuple(entries), record=True, category=category)


def _sym(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name.upper()).strip("_")


OBJECTS: Final[tuple[OdObject, ...]] = (
    _var(0x1000, "DEVICE_TYPE", "Device type", "UNSIGNED32", "ro", OD_DEVICE_TYPE,
         "CiA 301 device type: 0, no standard device profile.", category="mandatory"),
    _var(0x1001, "ERROR_REGISTER", "Error register", "UNSIGNED8", "ro", 0,
         "CiA 301 error register: bit 0 any fault active, bit 4 a CAN fault (bus-off, "
         "transmit overflow). Also sent in EMCY.EmcyErrorRegister.", category="mandatory"),
    _var(0x1017, "PRODUCER_HEARTBEAT_TIME", "Producer heartbeat time", "UNSIGNED16", "rw",
         c.DEFAULT_HEARTBEAT_MS,
         "Heartbeat period in ms, 0 = off. The same setting as SET_CONFIG CfgHeartbeatMs.",
         unit="ms"),
    _record(0x1018, "Identity object", "mandatory", (
        ("IDENTITY_VENDOR_ID", "Vendor-ID", "UNSIGNED32", "ro", OD_VENDOR_ID,
         "CiA vendor id; 0: none assigned.", {}),
        ("IDENTITY_PRODUCT_CODE", "Product code", "UNSIGNED32", "ro", OD_PRODUCT_CODE,
         'ASCII "ALCS".', {}),
        ("IDENTITY_REVISION", "Revision number", "UNSIGNED32", "ro", OD_REVISION,
         "High 16 bits: protocol version; low 16 bits: 0.", {}),
        ("IDENTITY_SERIAL", "Serial number", "UNSIGNED32", "ro", 0,
         "Serial number (0 until the appliance provisions one).", {}),
    )),
    _record(0x2000, "Acquisition settings", "manufacturer", (
        ("CFG_EXPOSURE_US", "Exposure time", "UNSIGNED16", "rw", 3000,
         "Camera exposure time in us; SET_CONFIG CfgExposureUs.",
         {"low": 1, "unit": "us"}),
        ("CFG_BRCE_STEP", "bRCE step", "UNSIGNED8", "rw", 4,
         "bRCE laser-line extraction step; SET_CONFIG CfgBrceStep.", {"low": 1, "high": 15}),
        ("CFG_BRCE_THRESHOLD", "bRCE threshold", "UNSIGNED8", "rw", 40,
         "bRCE laser-line intensity threshold (grey levels); SET_CONFIG CfgBrceThreshold.", {}),
    )),
    _record(0x2001, "Scan settings", "manufacturer", (
        ("CFG_SCAN_STOPS", "Scan stops", "UNSIGNED8", "rw", 7,
         "Slide stops (laser lines) per scan; SET_CONFIG CfgScanStops.",
         {"low": 1, "high": 15}),
        ("CFG_STOP_SPACING", "Stop spacing", "UNSIGNED16", "rw", 133,
         "Slide distance between stops in 0.1 mm (SET_CONFIG CfgStopSpacingMm carries "
         "0..25.5 mm; the daemon accepts 0.5..50 mm).", {"unit": "0.1 mm"}),
    )),
    _record(0x2100, "CAN diagnostics", "manufacturer", (
        ("DIAG_RX_FRAMES", "Frames received", "UNSIGNED32", "ro", 0,
         "Frames that passed the kernel filter (the sensor's id block and NMT).", {}),
        ("DIAG_RX_UNKNOWN_ID", "Unknown ids", "UNSIGNED32", "ro", 0,
         "Frames on an id of the sensor's block that it does not consume (ignored).", {}),
        ("DIAG_RX_BAD_FRAMES", "Bad frames", "UNSIGNED32", "ro", 0,
         "Commands NACKed for DLC, checksum, opcode, counter or value; bad NMT/SDO frames.",
         {}),
        ("DIAG_RX_ERROR_FRAMES", "Error frames", "UNSIGNED32", "ro", 0,
         "Error frames reported by the CAN controller.", {}),
        ("DIAG_BUS_OFF_COUNT", "Bus-off events", "UNSIGNED32", "ro", 0,
         "Times the controller went bus-off.", {}),
        ("DIAG_TX_RETRIES", "Transmit retries", "UNSIGNED32", "ro", 0,
         "Writes refused by the kernel (ENOBUFS, interface down) and retried later.", {}),
        ("DIAG_TX_DROPPED_STATUS", "Status frames dropped", "UNSIGNED32", "ro", 0,
         "Periodic frames replaced by a newer one while the bus was unavailable.", {}),
        ("DIAG_TX_DROPPED_RESULT", "Result frames dropped", "UNSIGNED32", "ro", 0,
         "Acks/result frames dropped because the result queue was full (should stay 0).",
         {}),
    )),
)
"""The object dictionary, in index order."""

OD_ENTRIES: Final[tuple[OdEntry, ...]] = tuple(e for o in OBJECTS for e in o.entries)
