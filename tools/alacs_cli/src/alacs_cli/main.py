"""``alacs``: talk to an ALACS sensor over CAN from a shell.

Works on any python-can interface: ``--interface socketcan --channel can0``,
``--interface udp_multicast --channel 239.74.163.2``, ``--interface socketcand
--channel can0 --bus-arg host=10.0.0.5 --bus-arg port=29536``, ...

Exit codes: 0 success; 1 NACK, or a result that is not MEASURED (the status and its
reason are printed); 2 usage error; 3 timeout; 4 CAN interface error; 130 Ctrl-C; 141 the
reader of stdout went away (``alacs ... | head``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import random
import re
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO, TypeVar

import can
from cantools.database import Database
from cantools.database.errors import DecodeError, EncodeError

import alacs_can
from alacs_can import LocalizationResult, Opcode
from alacs_can.doctables import MEANINGS

from . import envelope
from .link import Deadline, Decoded, Exchange, Rejected, SensorLink, Timeout
from .monitor import MonitorTable
from .progress import ProgressView

T = TypeVar("T")

EXIT_OK, EXIT_REJECTED, EXIT_USAGE, EXIT_TIMEOUT, EXIT_BUS = 0, 1, 2, 3, 4
EXIT_INTERRUPTED, EXIT_BROKEN_PIPE = 130, 141

# Commands that move the slide: on Ctrl-C or a timeout the CLI sends STOP.
MOTION_COMMANDS = frozenset({"localize", "scan-all", "scan", "home"})

# How long a scan takes, for the default --timeout. Per stop: the move, the exposure and
# the line extraction (LOCALIZE: a window, ~0.13 s a stop in the simulator, up to 0.5 s on
# a loaded board; SCAN_ALL: whole frames, several seconds a stop on the board). Until the
# first ALACS_Progress frame the largest plan is assumed (LOCALIZE: 15 stops + a 6-stop
# second pass; SCAN_ALL: the 200 mm stroke in 8 mm stops); after it, the timeout follows
# the stops the sensor says are left.
PER_STOP_S = {Opcode.LOCALIZE: 0.5, Opcode.SCAN_ALL: 4.0}
ASSUMED_STOPS = {Opcode.LOCALIZE: 15 + 6, Opcode.SCAN_ALL: 26}
MARGIN_S = 5.0
STOP_ANSWER_S = 1.0


def expected_scan_s(opcode: Opcode, stops_left: int | None = None) -> float:
    """Seconds to wait for a scan with ``stops_left`` stops to go (None: not yet known)."""
    stops = ASSUMED_STOPS[opcode] if stops_left is None else max(stops_left, 0)
    return stops * PER_STOP_S[opcode] + MARGIN_S

# Commands that only listen to the sensor: their bus gets a filter for its id block.
SENSOR_ONLY_COMMANDS = frozenset({"localize", "scan-all", "scan", "home", "stop", "clear-fault",
                                  "version", "config", "status"})

NMT_COMMANDS = {
    "start": alacs_can.NmtCommand.START,
    "stop": alacs_can.NmtCommand.STOP,
    "pre-operational": alacs_can.NmtCommand.PRE_OPERATIONAL,
    "reset-node": alacs_can.NmtCommand.RESET_NODE,
    "reset-comm": alacs_can.NmtCommand.RESET_COMM,
}


def _int(text: str) -> int:
    return int(text, 0)


def _node_id(text: str) -> int:
    value = _int(text)
    try:
        return int(alacs_can.check_node_id(value))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _bus_arg(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    for convert in (int, float):
        try:
            return key, convert(value)
        except ValueError:
            pass
    return key, {"true": True, "false": False}.get(value.lower(), value)


def _fmt_value(value: Any) -> str:
    # alacs_can.decode has rounded scaled values to their resolution already.
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() else repr(value)
    return str(value)


def format_signals(signals: Decoded) -> str:
    return " ".join(f"{k}={_fmt_value(v)}" for k, v in signals.items())


def format_frame(db: Database, frame: can.Message, t0: float | None = None) -> str:
    """One line: time, id, name and decoded signals (raw bytes if not decodable)."""
    stamp = f"{frame.timestamp - t0:10.3f}" if t0 is not None else f"{frame.timestamp:.3f}"
    ident = f"{frame.arbitration_id:08X}" if frame.is_extended_id else f"{frame.arbitration_id:03X}"
    raw = bytes(frame.data).hex(" ").upper()
    name = alacs_can.message_name(db, frame)
    if name is None:
        return f"{stamp}  {ident}  [{frame.dlc}] {raw}"
    try:
        text = format_signals(alacs_can.decode(db, frame))
    except (DecodeError, ValueError) as exc:
        return f"{stamp}  {ident}  {name:<18} [{frame.dlc}] {raw}  (undecodable: {exc})"
    if name == alacs_can.MSG_COMMAND and not alacs_can.check_command(frame.data):
        text += "  CHECKSUM-BAD"
    return f"{stamp}  {ident}  {name:<18} {text}"


_NACK_FIELDS = ("NackDetail", "NackValue", "NackLimit")


def describe_nack(ack: Decoded) -> str:
    """'OUT_OF_RANGE: STROKE -239.6 mm, limit 0 mm' (just the reason without a detail)."""
    text = str(ack.get("NackReason"))
    detail = ack.get("NackDetail")
    if detail in (None, "NONE"):
        return text
    try:
        unit = alacs_can.NACK_DETAIL_UNITS[alacs_can.NackDetail[str(detail)]]
    except KeyError:
        unit = ""
    suffix = f" {unit}" if unit else ""
    return (f"{text}: {detail} {_fmt_value(ack['NackValue'])}{suffix}, limit "
            f"{_fmt_value(ack['NackLimit'])}{suffix}")


def _name(value: Any) -> Any:
    return getattr(value, "name", value)


def _result_dict(result: LocalizationResult) -> dict[str, Any]:
    out = dataclasses.asdict(result)
    out["status"] = _name(result.status)
    out["reason"] = _name(result.reason)
    out["mode"] = _name(result.mode)
    out["complete"] = result.complete
    out["measured"] = result.measured
    return out


def print_result(result: LocalizationResult, out: TextIO) -> None:
    status, reason = _name(result.status), _name(result.reason)
    why = "" if reason == "NONE" else f" ({reason})"
    print(f"result  MeasCounter={result.meas_counter} {_name(result.mode)} {status}{why} "
          f"target={result.target_id} objects={result.object_count} "
          f"scan_age={result.scan_age_ms:g} ms cycle={result.cycle_time_ms:g} ms", file=out)

    def vec(v: tuple[float, float, float] | None, fmt: str) -> str:
        return "-" if v is None else "(" + ", ".join(format(x, fmt) for x in v) + ")"

    for obj in result.objects:
        q = obj.quality
        quality = ("-" if q is None else
                   f"sigma={q.sigma_mm:.1f} mm conf={q.confidence_pct:g}% "
                   f"diam={q.diameter_mm:g} mm occl={q.occlusion_pct:g}% "
                   f"lines={q.lines_used} points={q.points_used}")
        print(f"  object {obj.index}: centre {vec(obj.center_mm, '.1f')} mm  "
              f"approach {vec(obj.approach_mm, '.1f')} mm  normal {vec(obj.normal, '.3f')}  "
              f"{quality}", file=out)


def reason_for_status(status: str, text: str) -> str:
    """A reason's value-table text for a result of this status, without the clauses that
    name another status (FAR_FROM_ROUGH's "ROUGH_ONLY: ..." beside an AMBIGUOUS result) and
    without the Markdown."""
    others = {s.name for s in alacs_can.ResultStatus} - {status}
    kept = []
    for sentence in re.split(r"(?<=\.) ", text):
        parts = [p for p in sentence.split("; ") if p.split(":", 1)[0] not in others]
        if parts:
            kept.append("; ".join(parts))
    return " ".join(kept).replace("`", "").replace("**", "")


RESULT_MEANING = {
    "NOT_FOUND": "nothing was found",
    "ROUGH_ONLY": "the rough position echoed back, not a measurement",
    "AMBIGUOUS": "more likely another object than the target (see the reason); the best guess, low confidence",
    "FAILED": "the scan could not be completed",
    "ABORTED": "the scan was stopped",
}


class Cli:
    def __init__(self, args: argparse.Namespace, out: TextIO) -> None:
        self.args = args
        self.out = out
        self.node_id: int = args.node_id
        self.db = alacs_can.load_database(self.node_id)
        self.counter: int = args.counter if args.counter is not None else random.randrange(16)

    def open_bus(self) -> can.BusABC:
        kwargs: dict[str, Any] = {"interface": self.args.interface, "channel": self.args.channel}
        if self.args.bitrate:
            kwargs["bitrate"] = self.args.bitrate
        kwargs.update(dict(self.args.bus_arg or []))
        if self.args.cmd in SENSOR_ONLY_COMMANDS:
            # Only the sensor's id block (and NMT): in the kernel on socketcan, in
            # python-can elsewhere, so a busy bus cannot crowd out its answers.
            kwargs["can_filters"] = [{"can_id": self.node_id, "can_mask": 0x07F, "extended": False}]
        return can.Bus(**kwargs)

    def emit(self, text: str, data: dict[str, Any]) -> None:
        if self.args.json:
            print(json.dumps(data), file=self.out)
        else:
            print(text, file=self.out)

    def emit_ack(self, label: str, ack: Decoded) -> None:
        if ack.get("AckResult") != "NACK":
            # The NACK detail is 0 in every other Ack: leave it out.
            ack = {k: v for k, v in ack.items() if k not in _NACK_FIELDS}
        self.emit(f"{label:<7} {format_signals(ack)}", {"type": label, **ack})

    # --- commands -------------------------------------------------------------

    def run_command(self, link: SensorLink, opcode: Opcode, **signals: object) -> Exchange:
        timeout = self.args.timeout if self.args.timeout is not None else 2.0
        ex = self.with_counter(lambda counter: link.command(opcode, counter, timeout, **signals))
        self.emit_ack("ack", ex.ack)
        return ex

    def with_counter(self, send: Callable[[int], T]) -> T:
        """``send(counter)`` with this tool's counter, once more with the next on BAD_COUNTER.

        The sensor NACKs BAD_COUNTER, and does not execute, a command whose counter repeats
        the one it last accepted within 1 s: the previous ``alacs`` call's, say, which drew
        the same random counter (1 in 16). When the counter is this tool's own draw, not
        ``--counter``, the command is sent again with the next counter; a given counter is
        the user's, so its NACK is shown as it came.
        """
        try:
            return send(self.counter)
        except Rejected as exc:
            if self.args.counter is not None or exc.reason != "BAD_COUNTER":
                raise
        repeated, self.counter = self.counter, (self.counter + 1) & 0x0F
        print(f"alacs {self.args.cmd}: counter {repeated} repeated the sensor's last accepted "
              f"one (NACK BAD_COUNTER, not executed): sent again with counter {self.counter}",
              file=sys.stderr)
        return send(self.counter)

    def cmd_localize(self, link: SensorLink) -> int:
        a = self.args
        return self._scan(link, Opcode.LOCALIZE, a.target,
                          LocalizeMode=a.mode.upper().replace("-", "_"), TargetId=a.target,
                          RoughX=a.x, RoughY=a.y, RoughZ=a.z)

    def cmd_scan_all(self, link: SensorLink) -> int:
        return self._scan(link, Opcode.SCAN_ALL, None,
                          ScanAllMode=self.args.mode.upper().replace("-", "_"))

    def _scan(self, link: SensorLink, opcode: Opcode, target: int | None,
              **signals: object) -> int:
        """Send LOCALIZE/SCAN_ALL, show its progress, print the result.

        Without --timeout the deadline follows the scan: the largest plan until the first
        progress frame, then the stops the sensor says are left, plus a margin.
        """
        explicit = self.args.timeout is not None
        deadline = link.deadline(self.args.timeout if explicit else expected_scan_s(opcode),
                                 fixed=explicit)
        view = ProgressView(self.db, self.out, self.counter, opcode.name, self.args.json)

        def on_frame(frame: can.Message) -> None:
            view.counter = self.counter  # the one sent: it moves on once after BAD_COUNTER
            p = view.push(frame)
            if p is not None:
                deadline.follow(expected_scan_s(
                    opcode, int(p["StopsTotal"]) - int(p["StopsDone"])))

        try:
            ex = self.with_counter(lambda counter: link.command(
                opcode, counter, min(2.0, deadline.remaining()), on_frame=on_frame, **signals))
            self.emit_ack("ack", ex.ack)
            link.wait_result(ex, deadline, target, on_frame=on_frame)
        finally:
            view.close()
        assert ex.result is not None
        result = ex.result
        if self.args.json:
            print(json.dumps({"type": "result", **_result_dict(result)}), file=self.out)
        else:
            print_result(result, self.out)
        if result.measured:
            if _name(result.reason) == "OUTSIDE_GATE":
                print(f"alacs {self.args.cmd}: measured, but found outside the gate around the "
                      "rough position (the widened search): check it is the fruit you meant",
                      file=sys.stderr)
            return EXIT_OK
        status, reason = _name(result.status), _name(result.reason)
        meaning = RESULT_MEANING.get(str(status), "not a measurement")
        # What the reason means and what to do about it: the value table's own text in
        # docs/can-protocol.md, without its Markdown.
        why = reason_for_status(str(status), MEANINGS[alacs_can.ResultReason].get(str(reason), ""))
        print(f"alacs {self.args.cmd}: result {status}, reason {reason}: {meaning}"
              + (f"; {reason}: {why}" if why and reason != "NONE" else ""), file=sys.stderr)
        return EXIT_REJECTED

    def stop_and_report(self, link: SensorLink, why: str) -> None:
        """After Ctrl-C or a timeout: send STOP, then say what state the sensor is in."""
        counter = (self.counter + 1) & 0x0F
        err = sys.stderr
        try:
            link.command(Opcode.STOP, counter, STOP_ANSWER_S)
            print(f"alacs {self.args.cmd}: {why}: sent STOP (ACK)", file=err)
        except Rejected as exc:
            print(f"alacs {self.args.cmd}: {why}: sent STOP, NACK {describe_nack(exc.ack)}",
                  file=err)
        except Timeout:
            print(f"alacs {self.args.cmd}: {why}: sent STOP, no ACK within "
                  f"{STOP_ANSWER_S:g} s", file=err)
        status_id = self.db.get_message_by_name(alacs_can.MSG_STATUS).frame_id
        try:
            frame = link.recv_until(
                lambda f: not f.is_extended_id and f.arbitration_id == status_id,
                STOP_ANSWER_S)
        except Timeout:
            print(f"alacs {self.args.cmd}: no ALACS_Status within {STOP_ANSWER_S:g} s: the "
                  "sensor's state is unknown", file=err)
            return
        status = alacs_can.decode(self.db, frame)
        faults = [f.name for f in alacs_can.Fault if f in alacs_can.fault_bits(status)]
        hint = ("; send `alacs clear-fault` to resume"
                if status.get("State") in ("STOPPED", "FAULT") else "")
        print(f"alacs {self.args.cmd}: sensor left in State={status.get('State')} "
              f"Homed={status.get('Homed')} LaserOn={status.get('LaserOn')} faults: "
              f"{' '.join(str(n) for n in faults) or 'none'}{hint}", file=err)
        if self.args.json:
            print(json.dumps({"type": "stopped", "why": why, **status, "faults": faults}),
                  file=self.out)

    def cmd_home(self, link: SensorLink) -> int:
        ex = self.run_command(link, Opcode.HOME)
        if not self.args.no_wait:
            link.wait_done(ex, self.args.timeout)
            assert ex.done is not None
            if ex.done is not ex.ack:
                self.emit_ack("done", ex.done)
        return EXIT_OK

    def cmd_simple(self, opcode: Opcode) -> Callable[[SensorLink], int]:
        def run(link: SensorLink) -> int:
            self.run_command(link, opcode)
            return EXIT_OK
        return run

    def cmd_version(self, link: SensorLink) -> int:
        ex = self.with_counter(
            lambda counter: link.command(Opcode.GET_VERSION, counter, self.args.timeout))
        ack = ex.ack
        text = (f"alacsd {ack['SwMajor']}.{ack['SwMinor']}.{ack['SwPatch']}  "
                f"protocol {ack['ProtocolVersion']} (this tool: {alacs_can.PROTOCOL_VERSION})")
        self.emit(text, {"type": "version", **ack})
        return EXIT_OK

    def cmd_config(self, link: SensorLink) -> int:
        a = self.args

        def send_pages(first_counter: int) -> int:
            frames = alacs_can.encode_set_config(
                self.db, first_counter, exposure_us=a.exposure_us, brce_step=a.brce_step,
                brce_threshold=a.brce_threshold, scan_stops=a.scan_stops,
                stop_spacing_mm=a.stop_spacing_mm, heartbeat_ms=a.heartbeat_ms)
            for frame in frames:
                counter = frame.data[1] & 0x0F
                link.bus.send(frame)
                self.emit_ack("ack", link.wait_ack(Opcode.SET_CONFIG, counter, a.timeout))
            return EXIT_OK

        return self.with_counter(send_pages)

    def cmd_status(self, link: SensorLink) -> int:
        status_id = self.db.get_message_by_name(alacs_can.MSG_STATUS).frame_id
        frame = link.recv_until(
            lambda f: not f.is_extended_id and f.arbitration_id == status_id, self.args.timeout)
        status = alacs_can.decode(self.db, frame)
        faults = alacs_can.fault_bits(status)
        names = [f.name for f in alacs_can.Fault if f in faults]
        text = format_signals(status) + f"\nfaults: {' '.join(n or '' for n in names) or 'none'}"
        self.emit(text, {"type": "status", **status, "faults": names})
        return EXIT_OK

    def cmd_monitor(self, link: SensorLink) -> int:
        view = self.args.view
        if view == "auto":
            view = "table" if self.out.isatty() else "lines"
        table = MonitorTable(self.db) if view == "table" else None
        seen = 0
        t0 = None
        deadline = None if self.args.timeout is None else time.monotonic() + self.args.timeout
        next_draw = 0.0
        while self.args.count is None or seen < self.args.count:
            if deadline is not None and time.monotonic() >= deadline:
                break
            frame = link.bus.recv(timeout=0.1)
            if table is not None and time.monotonic() >= next_draw:
                next_draw = time.monotonic() + self.args.refresh
                tty = self.out.isatty()
                width = shutil.get_terminal_size().columns if tty else None
                self.out.write(table.render(time.monotonic(), clear=tty, width=width))
                self.out.flush()
            if frame is None or frame.is_error_frame:
                continue
            t0 = frame.timestamp if t0 is None else t0
            if table is not None:
                table.push(frame, time.monotonic())
            else:
                print(format_frame(self.db, frame, t0), file=self.out, flush=True)
            seen += 1
        if table is not None:
            self.out.write(table.render(time.monotonic(), clear=self.out.isatty()))
        return EXIT_OK

    def cmd_record(self, link: SensorLink) -> int:
        """Write every frame to a log (format by suffix; .log is candump -L)."""
        seen = 0
        deadline = None if self.args.duration is None else time.monotonic() + self.args.duration
        with can.Logger(str(self.args.file)) as logger:
            while self.args.count is None or seen < self.args.count:
                if deadline is not None and time.monotonic() >= deadline:
                    break
                frame = link.bus.recv(timeout=0.1)
                if frame is None:
                    continue
                frame.channel = frame.channel or self.args.channel
                logger(frame)
                seen += 1
        self.emit(f"recorded {seen} frames to {self.args.file}",
                  {"type": "record", "frames": seen, "file": str(self.args.file)})
        return EXIT_OK

    def cmd_replay(self, link: SensorLink | None) -> int:
        """Decode a log (--print) or send it onto the bus with its original timing."""
        frames = list(can.LogReader(str(self.args.file)))
        if link is None:
            t0 = frames[0].timestamp if frames else 0.0
            for frame in frames:
                if not frame.is_error_frame:
                    print(format_frame(self.db, frame, t0), file=self.out)
            return EXIT_OK
        sent = 0
        for frame in can.MessageSync(frames, timestamps=not self.args.fast,
                                     gap=0.0 if self.args.fast else 0.0001):
            if frame.is_error_frame:
                continue
            frame.channel = None
            link.bus.send(frame)
            sent += 1
        self.emit(f"replayed {sent} frames from {self.args.file}",
                  {"type": "replay", "frames": sent, "file": str(self.args.file)})
        return EXIT_OK

    def cmd_envelope(self) -> int:
        """Print the working envelope (default geometry, or --calibration FILE)."""
        a = self.args
        geo = (envelope.Geometry.from_calibration(a.calibration) if a.calibration
               else envelope.Geometry.default())
        rows = envelope.envelope(geo, a.stroke_mm)
        if a.json:
            print(json.dumps({"type": "envelope", "source": geo.source, "stroke_mm": a.stroke_mm,
                              "depth_mm": [envelope.MIN_DEPTH_MM, envelope.MAX_DEPTH_MM],
                              "rows": [dataclasses.asdict(r) for r in rows]}), file=self.out)
        else:
            self.out.write(envelope.format_table(geo, a.stroke_mm, rows))
        return EXIT_OK

    def cmd_nmt(self, link: SensorLink) -> int:
        target = 0 if self.args.all else self.node_id
        msg = alacs_can.encode_message(self.db, alacs_can.MSG_NMT, {
            "NmtCommand": int(NMT_COMMANDS[self.args.nmt_command]), "NmtNodeId": target})
        link.bus.send(msg)
        self.emit(f"sent NMT {NMT_COMMANDS[self.args.nmt_command].name} to node {target}",
                  {"type": "nmt", "command": NMT_COMMANDS[self.args.nmt_command].name,
                   "node_id": target})
        return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="alacs", description="Talk to an ALACS sensor over CAN.")
    p.add_argument("--interface", default="socketcan", help="python-can interface (socketcan)")
    p.add_argument("--channel", default="vcan0", help="python-can channel (vcan0)")
    p.add_argument("--bitrate", type=int, default=None, help="bitrate, for interfaces that set it")
    p.add_argument("--bus-arg", type=_bus_arg, action="append", metavar="KEY=VALUE",
                   help="extra python-can Bus argument, e.g. host=... port=... for socketcand "
                        "(repeatable)")
    p.add_argument("--node-id", type=_node_id, default=alacs_can.DEFAULT_NODE_ID,
                   help="sensor node id 1..127 (default 0x10)")
    p.add_argument("--counter", type=lambda s: _int(s) & 0xF, default=None,
                   help="command counter (default random; the sensor rejects a repeat of its "
                        "last accepted counter within 1 s)")
    p.add_argument("--json", action="store_true", help="print one JSON object per answer")
    sub = p.add_subparsers(dest="cmd", required=True, metavar="COMMAND")

    def timeout(sp: argparse.ArgumentParser, default: float | None) -> None:
        sp.add_argument("--timeout", type=float, default=default, metavar="S",
                        help=f"seconds to wait (default {default})")

    modes = ["stop-and-go", "continuous"]
    sp = sub.add_parser("localize", help="localize one apple near a rough position")
    sp.add_argument("--x", type=int, required=True, metavar="MM", help="rough x (right), mm")
    sp.add_argument("--y", type=int, required=True, metavar="MM", help="rough y (down), mm")
    sp.add_argument("--z", type=int, required=True, metavar="MM", help="rough z (forward), mm")
    sp.add_argument("--target", type=_int, default=0, metavar="N", help="target id 0..255")
    sp.add_argument("--mode", choices=modes, default="stop-and-go")
    sp.add_argument("--timeout", type=float, default=None, metavar="S",
                    help="seconds to wait in all (default: follows the scan, "
                         f"{expected_scan_s(Opcode.LOCALIZE):g} s until the sensor reports "
                         "its plan)")
    sp = sub.add_parser("scan-all", aliases=["scan"], help="scan the whole field of view")
    sp.add_argument("--mode", choices=modes, default="stop-and-go")
    sp.add_argument("--timeout", type=float, default=None, metavar="S",
                    help="seconds to wait in all (default: follows the scan, "
                         f"{expected_scan_s(Opcode.SCAN_ALL):g} s until the sensor reports "
                         "its plan)")
    sp = sub.add_parser("home", help="home the laser slide (waits for DONE)")
    sp.add_argument("--no-wait", action="store_true", help="return after the ACK")
    timeout(sp, 30.0)
    for name, help_ in (("stop", "stop motion and laser"), ("clear-fault", "clear latched faults")):
        timeout(sub.add_parser(name, help=help_), 2.0)
    timeout(sub.add_parser("version", help="print sensor software and protocol version"), 2.0)
    sp = sub.add_parser("config", help="SET_CONFIG: change sensor settings")
    sp.add_argument("--exposure-us", type=int)
    sp.add_argument("--brce-step", type=int)
    sp.add_argument("--brce-threshold", type=int)
    sp.add_argument("--scan-stops", type=int)
    sp.add_argument("--stop-spacing-mm", type=float)
    sp.add_argument("--heartbeat-ms", type=int)
    timeout(sp, 2.0)
    timeout(sub.add_parser("status", help="wait for one ALACS_Status frame and print it"), 2.0)
    sp = sub.add_parser("monitor", help="live decoded view of the bus")
    sp.add_argument("--count", type=int, default=None, metavar="N", help="stop after N frames")
    sp.add_argument("--view", choices=["auto", "table", "lines"], default="auto",
                    help="table: one row per message, redrawn in place (default on a "
                         "terminal); lines: one decoded line per frame")
    sp.add_argument("--refresh", type=float, default=0.25, metavar="S",
                    help="table redraw period (default 0.25 s)")
    timeout(sp, None)
    sp = sub.add_parser("record", help="record the bus to a log (candump -L format for .log)")
    sp.add_argument("file", type=Path, help="log file; the suffix picks the format "
                                            "(.log candump, .asc, .blf, .csv, .trc)")
    sp.add_argument("--count", type=int, default=None, metavar="N", help="stop after N frames")
    sp.add_argument("--duration", type=float, default=None, metavar="S",
                    help="stop after S seconds")
    sp = sub.add_parser("replay", help="replay a recorded log onto the bus, or --print it")
    sp.add_argument("file", type=Path, help="log file (candump -L .log, .asc, .blf, ...)")
    sp.add_argument("--print", action="store_true", help="decode and print; do not send")
    sp.add_argument("--fast", action="store_true", help="send back to back, not in real time")
    sp = sub.add_parser("nmt", help="send an NMT command")
    sp.add_argument("nmt_command", choices=sorted(NMT_COMMANDS))
    sp.add_argument("--all", action="store_true", help="address all nodes (node id 0)")
    sp = sub.add_parser("envelope", help="print the working envelope (where LOCALIZE can "
                                         "reach)")
    sp.add_argument("--calibration", type=Path, default=None, metavar="FILE",
                    help="calibration.json of the sensor (default: the default geometry)")
    sp.add_argument("--stroke-mm", type=float, default=envelope.DEFAULT_STROKE_MM,
                    help=f"slide stroke, motion.stroke_mm (default {envelope.DEFAULT_STROKE_MM:g})")
    sp = sub.add_parser("dbc", help="print the DBC for a node id")
    # own dest: a subparser default would overwrite the global --node-id
    sp.add_argument("--node-id", dest="dbc_node_id", type=_node_id, default=None)
    return p


def main(argv: Sequence[str] | None = None, out: TextIO | None = None) -> int:
    """Run ``alacs``; returns the exit code. A reader that goes away (``| head``) ends it
    quietly with 141, as SIGPIPE would, instead of a BrokenPipeError traceback."""
    out = out or sys.stdout
    try:
        rc = _main(argv, out)
        out.flush()
        return rc
    except BrokenPipeError:
        if out is sys.stdout:
            # The interpreter flushes stdout again at exit; point it at /dev/null first.
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


def _main(argv: Sequence[str] | None, out: TextIO) -> int:
    args = build_parser().parse_args(argv)
    if args.cmd == "envelope":
        try:
            return Cli(args, out).cmd_envelope()
        except ValueError as exc:
            print(f"alacs envelope: {exc}", file=sys.stderr)
            return EXIT_USAGE
    if args.cmd == "dbc":
        out.write(alacs_can.dbc_text(args.dbc_node_id or args.node_id))
        return EXIT_OK
    if args.cmd == "replay" and args.print:
        try:
            return Cli(args, out).cmd_replay(None)
        except BrokenPipeError:
            raise
        except (OSError, ValueError) as exc:
            print(f"alacs replay: {exc}", file=sys.stderr)
            return EXIT_USAGE
    if args.cmd == "config" and all(
        getattr(args, f) is None for f in alacs_can.CONFIG_FIELDS
    ):
        print("alacs config: give at least one setting", file=sys.stderr)
        return EXIT_USAGE
    cli = Cli(args, out)
    handlers: dict[str, Callable[[SensorLink], int]] = {
        "localize": cli.cmd_localize,
        "scan-all": cli.cmd_scan_all,
        "scan": cli.cmd_scan_all,
        "home": cli.cmd_home,
        "stop": cli.cmd_simple(Opcode.STOP),
        "clear-fault": cli.cmd_simple(Opcode.CLEAR_FAULT),
        "version": cli.cmd_version,
        "config": cli.cmd_config,
        "status": cli.cmd_status,
        "monitor": cli.cmd_monitor,
        "record": cli.cmd_record,
        "replay": cli.cmd_replay,
        "nmt": cli.cmd_nmt,
    }
    try:
        bus = cli.open_bus()
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        print(f"alacs: cannot open {args.interface} {args.channel}: {exc}", file=sys.stderr)
        return EXIT_BUS
    try:
        with bus:
            link = SensorLink(bus, cli.db)
            try:
                return handlers[args.cmd](link)
            except (KeyboardInterrupt, Timeout) as exc:
                if args.cmd in MOTION_COMMANDS:
                    cli.stop_and_report(link, "interrupted" if isinstance(
                        exc, KeyboardInterrupt) else f"timeout ({exc})")
                raise
    except Rejected as exc:
        cli.emit_ack("nack", exc.ack)
        hint = "  (try: alacs nmt start)" if exc.reason == "NMT_NOT_OPERATIONAL" else ""
        print(f"alacs {args.cmd}: NACK {describe_nack(exc.ack)}{hint}", file=sys.stderr)
        return EXIT_REJECTED
    except EncodeError as exc:
        print(f"alacs {args.cmd}: value out of range: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except Timeout as exc:
        print(f"alacs {args.cmd}: timeout: {exc}", file=sys.stderr)
        return EXIT_TIMEOUT
    except can.CanError as exc:
        print(f"alacs {args.cmd}: CAN error: {exc}", file=sys.stderr)
        return EXIT_BUS
    except KeyboardInterrupt:
        return EXIT_OK if args.cmd in ("monitor", "record") else EXIT_INTERRUPTED


if __name__ == "__main__":
    raise SystemExit(main())
