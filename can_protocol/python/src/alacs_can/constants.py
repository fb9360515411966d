"""Protocol constants: message names, base ids and the value tables.

The enums here are the single source of the DBC value tables (``VAL_``), so a
name used in Python, in the DBC and in the generated C ``*_CHOICE`` macros is
always the same word.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag
from typing import Final

PROTOCOL_VERSION: Final = 2
"""Sent in ``ALACS_Ack.ProtocolVersion``; bump on any incompatible change.

2: ResultHeader carries ResultReason (ObjectCount 5 bits, ResultMode moved to bits 21..23),
ResultStatus values MEASURED/NOT_FOUND/ROUGH_ONLY/AMBIGUOUS, NACK detail in ALACS_Ack,
ALACS_Progress added."""

DEFAULT_NODE_ID: Final = 0x10
"""Node id of the committed ``can_protocol/alacs.dbc``."""

NODE_ID_MIN: Final = 1
NODE_ID_MAX: Final = 127

SENSOR_NODE: Final = "ALACS"
CONTROLLER_NODE: Final = "ARM"

# Message names (part of the contract: other components match on them).
MSG_COMMAND: Final = "ALACS_Command"
MSG_ACK: Final = "ALACS_Ack"
MSG_RESULT_HEADER: Final = "ALACS_ResultHeader"
MSG_RESULT_OBJECT: Final = "ALACS_ResultObject"
MSG_STATUS: Final = "ALACS_Status"
MSG_NMT: Final = "NMT"
MSG_HEARTBEAT: Final = "Heartbeat"
MSG_EMCY: Final = "EMCY"
MSG_SDO_TX: Final = "SDO_Tx"
MSG_SDO_RX: Final = "SDO_Rx"
MSG_PROGRESS: Final = "ALACS_Progress"

# CANopen-style base ids; the frame id is base + node id, except NMT (fixed 0x000).
BASE_ID_NMT: Final = 0x000
BASE_ID_EMCY: Final = 0x080
BASE_ID_ACK: Final = 0x180
BASE_ID_COMMAND: Final = 0x200
BASE_ID_RESULT_HEADER: Final = 0x280
BASE_ID_RESULT_OBJECT: Final = 0x380
BASE_ID_STATUS: Final = 0x480
BASE_ID_SDO_TX: Final = 0x580
BASE_ID_SDO_RX: Final = 0x600
BASE_ID_PROGRESS: Final = 0x680
"""0x680..0x6FF is unused in the CiA 301 predefined connection set; the four TPDO slots
(0x180..0x480) are taken, and progress must not outrank acks, results or SDO answers."""
BASE_ID_HEARTBEAT: Final = 0x700

BASE_IDS: Final[dict[str, int]] = {
    MSG_NMT: BASE_ID_NMT,
    MSG_EMCY: BASE_ID_EMCY,
    MSG_ACK: BASE_ID_ACK,
    MSG_COMMAND: BASE_ID_COMMAND,
    MSG_RESULT_HEADER: BASE_ID_RESULT_HEADER,
    MSG_RESULT_OBJECT: BASE_ID_RESULT_OBJECT,
    MSG_STATUS: BASE_ID_STATUS,
    MSG_SDO_TX: BASE_ID_SDO_TX,
    MSG_SDO_RX: BASE_ID_SDO_RX,
    MSG_PROGRESS: BASE_ID_PROGRESS,
    MSG_HEARTBEAT: BASE_ID_HEARTBEAT,
}

NODE_OFFSET_MESSAGES: Final = frozenset(BASE_IDS) - {MSG_NMT}
"""Messages whose frame id is ``base + node_id``."""

STATUS_PERIOD_MS: Final = 100
DEFAULT_HEARTBEAT_MS: Final = 1000
MAX_OBJECTS: Final = 16
"""``ObjIndex`` is 4 bits wide, so one result carries at most 16 objects."""


def check_node_id(node_id: int) -> int:
    """Return ``node_id`` if it is a valid CANopen node id (1..127), else raise ValueError."""
    if not NODE_ID_MIN <= node_id <= NODE_ID_MAX:
        raise ValueError(f"node id must be {NODE_ID_MIN}..{NODE_ID_MAX}, got {node_id}")
    return node_id


def frame_id(message_name: str, node_id: int = DEFAULT_NODE_ID) -> int:
    """11-bit CAN id of ``message_name`` for sensor ``node_id``. Raises KeyError/ValueError."""
    base = BASE_IDS[message_name]
    if message_name not in NODE_OFFSET_MESSAGES:
        return base
    return base + check_node_id(node_id)


class Opcode(IntEnum):
    """``CmdOpcode`` / ``AckOpcode``."""

    LOCALIZE = 1
    SCAN_ALL = 2
    HOME = 3
    STOP = 4
    SET_CONFIG = 5
    GET_VERSION = 6
    CLEAR_FAULT = 7


class AckOpcode(IntEnum):
    """``AckOpcode``: the Opcode table plus INVALID for frames without a known opcode.

    The sensor cannot echo an unknown opcode in a multiplexer (decoders would reject
    the frame), so it answers INVALID and puts the received byte in ``RejectedOpcode``.
    """

    INVALID = 0
    LOCALIZE = 1
    SCAN_ALL = 2
    HOME = 3
    STOP = 4
    SET_CONFIG = 5
    GET_VERSION = 6
    CLEAR_FAULT = 7


class ScanMode(IntEnum):
    """``LocalizeMode`` / ``ScanAllMode``: how the laser slide moves during the scan."""

    STOP_AND_GO = 0
    CONTINUOUS = 1


class CfgPage(IntEnum):
    """``CfgPage``: which group of settings a SET_CONFIG frame carries."""

    ACQUISITION = 0
    SCAN = 1


class AckResult(IntEnum):
    ACK = 0
    NACK = 1
    DONE = 2


class NackReason(IntEnum):
    NONE = 0
    BAD_DLC = 1
    BAD_CHECKSUM = 2
    BAD_COUNTER = 3
    UNKNOWN_OPCODE = 4
    BUSY = 5
    NOT_HOMED = 6
    NOT_CALIBRATED = 7
    OUT_OF_RANGE = 8
    FAULT_ACTIVE = 9
    NMT_NOT_OPERATIONAL = 10
    BAD_VALUE = 11
    INTERNAL = 12


class ResultStatus(IntEnum):
    """``ResultStatus``: only MEASURED is a measurement; every other status has a ResultReason.

    The numbers of v1 are kept for the same meanings (2 was PARTIAL: the rough position
    echoed back), so a v1 reader of this nibble is not misled about FAILED/ABORTED.
    """

    MEASURED = 0
    NOT_FOUND = 1
    ROUGH_ONLY = 2
    FAILED = 3
    ABORTED = 4
    AMBIGUOUS = 5


class ResultReason(IntEnum):
    """``ResultReason``: why a result is not MEASURED (NONE when it is).

    OUTSIDE_GATE goes with MEASURED: the fruit was found by the widened search, away from
    the rough position (the lines inside the gate fitted nothing).
    """

    NONE = 0
    NO_LINES_IN_GATE = 1
    TOO_FEW_LINES = 2
    FIT_FAILED = 3
    TWO_SURFACES = 4
    FAR_FROM_ROUGH = 5
    CAMERA_FAULT = 6
    MOTION_FAULT = 7
    LASER_FAULT = 8
    STOPPED = 9
    SHUTDOWN = 10
    INTERNAL = 11
    OUTSIDE_GATE = 12
    BRIGHT_AMBIENT = 13


class NackDetail(IntEnum):
    """``NackDetail``: which limit a NACKed command broke; NackValue/NackLimit give numbers."""

    NONE = 0
    STROKE = 1
    DEPTH = 2
    LATERAL = 3
    FRAME = 4
    CROSS_FIELD = 5
    SPACING_X_STOPS = 6
    MODE = 7
    EXPOSURE = 8
    BRCE_STEP = 9
    SCAN_STOPS = 10
    STOP_SPACING = 11
    HEARTBEAT = 12


NACK_DETAIL_UNITS: Final[dict[NackDetail, str]] = {
    NackDetail.NONE: "",
    NackDetail.STROKE: "mm",
    NackDetail.DEPTH: "mm",
    NackDetail.LATERAL: "mm",
    NackDetail.FRAME: "px",
    NackDetail.CROSS_FIELD: "",
    NackDetail.SPACING_X_STOPS: "mm",
    NackDetail.MODE: "",
    NackDetail.EXPOSURE: "ms",
    NackDetail.BRCE_STEP: "",
    NackDetail.SCAN_STOPS: "",
    NackDetail.STOP_SPACING: "mm",
    NackDetail.HEARTBEAT: "ms",
}
"""Unit of ``NackValue``/``NackLimit`` for each ``NackDetail`` ("" = a plain number)."""


class ProgressPhase(IntEnum):
    """``ProgressPhase``: what a running LOCALIZE or SCAN_ALL is doing."""

    MOVING = 0
    EXPOSING = 1
    FITTING = 2
    SECOND_PASS = 3


class ResultMode(IntEnum):
    LOCALIZE = 0
    SCAN_ALL = 1


class ObjPage(IntEnum):
    CENTER = 0
    APPROACH_POINT = 1
    QUALITY = 2
    APPROACH_NORMAL = 3


class SensorState(IntEnum):
    """``ALACS_Status.State``."""

    BOOT = 0
    HOMING = 1
    IDLE = 2
    SCANNING = 3
    FAULT = 4
    STOPPED = 5


class Fault(IntFlag):
    """Fault bits: ``ALACS_Status.Fault*`` (bit n of byte 1..2) and ``EMCY.EmcyFaultBits``."""

    HOMING_TIMEOUT = 1 << 0
    LIMIT_HIT = 1 << 1
    CAMERA_TIMEOUT = 1 << 2
    CAMERA_CORRUPT = 1 << 3
    CAN_BUS_OFF = 1 << 4
    CAN_TX_OVERFLOW = 1 << 5
    CONFIG_INVALID = 1 << 6
    NOT_CALIBRATED = 1 << 7
    LASER_OVERTIME = 1 << 8
    INTERNAL = 1 << 9
    STOP_REQUESTED = 1 << 10


FAULT_SIGNALS: Final[dict[Fault, str]] = {
    Fault.HOMING_TIMEOUT: "FaultHomingTimeout",
    Fault.LIMIT_HIT: "FaultLimitHit",
    Fault.CAMERA_TIMEOUT: "FaultCameraTimeout",
    Fault.CAMERA_CORRUPT: "FaultCameraCorrupt",
    Fault.CAN_BUS_OFF: "FaultCanBusOff",
    Fault.CAN_TX_OVERFLOW: "FaultCanTxOverflow",
    Fault.CONFIG_INVALID: "FaultConfigInvalid",
    Fault.NOT_CALIBRATED: "FaultNotCalibrated",
    Fault.LASER_OVERTIME: "FaultLaserOvertime",
    Fault.INTERNAL: "FaultInternal",
    Fault.STOP_REQUESTED: "FaultStopRequested",
}
"""The 1-bit ``ALACS_Status`` signal for each fault bit (at bit 8 + n)."""


class EmcyReason(IntEnum):
    """``EMCY.EmcyReason``: the fault that raised this EMCY (fault bit index + 1)."""

    NONE = 0
    HOMING_TIMEOUT = 1
    LIMIT_HIT = 2
    CAMERA_TIMEOUT = 3
    CAMERA_CORRUPT = 4
    CAN_BUS_OFF = 5
    CAN_TX_OVERFLOW = 6
    CONFIG_INVALID = 7
    NOT_CALIBRATED = 8
    LASER_OVERTIME = 9
    INTERNAL = 10
    STOP_REQUESTED = 11


class EmcyErrorCode(IntEnum):
    """``EMCY.EmcyErrorCode``: the CiA 301 error code classes the sensor uses."""

    NO_ERROR = 0x0000
    GENERIC = 0x1000
    HARDWARE = 0x5000
    SOFTWARE_INTERNAL = 0x6100
    DATA_SET = 0x6300
    MONITORING = 0x8000
    CAN_OVERRUN = 0x8110
    CAN_BUS_OFF_RECOVERED = 0x8140
    DEVICE_SPECIFIC = 0xFF00


FAULT_EMCY_CODE: Final[dict[Fault, EmcyErrorCode]] = {
    Fault.HOMING_TIMEOUT: EmcyErrorCode.DEVICE_SPECIFIC,
    Fault.LIMIT_HIT: EmcyErrorCode.DEVICE_SPECIFIC,
    Fault.CAMERA_TIMEOUT: EmcyErrorCode.HARDWARE,
    Fault.CAMERA_CORRUPT: EmcyErrorCode.HARDWARE,
    Fault.CAN_BUS_OFF: EmcyErrorCode.CAN_BUS_OFF_RECOVERED,
    Fault.CAN_TX_OVERFLOW: EmcyErrorCode.CAN_OVERRUN,
    Fault.CONFIG_INVALID: EmcyErrorCode.DATA_SET,
    Fault.NOT_CALIBRATED: EmcyErrorCode.DATA_SET,
    Fault.LASER_OVERTIME: EmcyErrorCode.MONITORING,
    Fault.INTERNAL: EmcyErrorCode.SOFTWARE_INTERNAL,
    Fault.STOP_REQUESTED: EmcyErrorCode.GENERIC,
}
"""EmcyErrorCode the sensor sends when a fault is raised."""


def emcy_reason(fault: Fault) -> EmcyReason:
    """EmcyReason for a single fault bit (bit index + 1)."""
    return EmcyReason(fault.bit_length())


CAN_FAULTS: Final = Fault.CAN_BUS_OFF | Fault.CAN_TX_OVERFLOW


def error_register(faults: Fault | int) -> int:
    """CiA 301 error register (object 0x1001, EMCY byte 2) for the active ``faults``:
    bit 0 generic (any fault), bit 4 communication (a CAN fault)."""
    faults = int(faults)
    return (0x01 if faults else 0) | (0x10 if faults & int(CAN_FAULTS) else 0)


class NmtCommand(IntEnum):
    START = 1
    STOP = 2
    PRE_OPERATIONAL = 128
    RESET_NODE = 129
    RESET_COMM = 130


class NmtState(IntEnum):
    BOOTUP = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


class SdoClientCommand(IntEnum):
    """``SDO_Rx.SdoRxCommand`` (client → sensor), expedited transfers only."""

    DOWNLOAD_4B = 0x23
    DOWNLOAD_3B = 0x27
    DOWNLOAD_2B = 0x2B
    DOWNLOAD_1B = 0x2F
    UPLOAD_REQUEST = 0x40
    ABORT = 0x80


class SdoServerCommand(IntEnum):
    """``SDO_Tx.SdoTxCommand`` (sensor → client), expedited transfers only."""

    UPLOAD_4B = 0x43
    UPLOAD_3B = 0x47
    UPLOAD_2B = 0x4B
    UPLOAD_1B = 0x4F
    DOWNLOAD_RESPONSE = 0x60
    ABORT = 0x80



class SdoAbort(IntEnum):
    """SDO abort codes (CiA 301) the sensor's SDO server sends in ``SdoTxData``."""

    UNKNOWN_COMMAND = 0x05040001
    """Command specifier not valid, or a segmented/block transfer (only expedited)."""
    UNSUPPORTED_ACCESS = 0x06010000
    READ_ONLY = 0x06010002
    """Attempt to write a read-only object."""
    NO_OBJECT = 0x06020000
    LENGTH_MISMATCH = 0x06070010
    NO_SUBINDEX = 0x06090011
    VALUE_RANGE = 0x06090030
    """Value rejected (also: a setting the daemon's configuration check refuses)."""
    VALUE_TOO_HIGH = 0x06090031
    VALUE_TOO_LOW = 0x06090032
    GENERAL = 0x08000000
    DEVICE_STATE = 0x08000022
    """Not now: e.g. a setting changed while a scan or homing is running."""
