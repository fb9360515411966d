"""Command/response exchanges with one sensor over any python-can bus.

This is the CLI's I/O edge: it owns the bus and the clock; all protocol knowledge
comes from ``alacs_can``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import can
from cantools.database import Database
from cantools.database.errors import DecodeError

import alacs_can
from alacs_can import AckResult, LocalizationResult, Opcode, ResultCollector

Decoded = dict[str, alacs_can.codec.Value]


class Timeout(Exception):
    """Nothing suitable arrived in time; ``str()`` says what was awaited."""


class Rejected(Exception):
    """The sensor answered NACK; ``ack`` is the decoded Ack."""

    def __init__(self, ack: Decoded) -> None:
        super().__init__(f"NACK {ack.get('NackReason')}")
        self.ack = ack

    @property
    def reason(self) -> str:
        return str(self.ack.get("NackReason"))


class Deadline:
    """A deadline that progress may move: ``follow(s)`` sets it to ``s`` seconds from now
    (unless ``fixed``, as for an explicit --timeout)."""

    def __init__(self, clock: Callable[[], float], seconds: float, fixed: bool = True) -> None:
        self._clock = clock
        self.at = clock() + seconds
        self.fixed = fixed
        self.budget_s = seconds

    def follow(self, seconds: float) -> None:
        if not self.fixed:
            self.at = self._clock() + seconds
            self.budget_s = seconds

    def remaining(self) -> float:
        return self.at - self._clock()


@dataclass
class Exchange:
    command: can.Message
    ack: Decoded
    done: Decoded | None = None
    result: LocalizationResult | None = None


class SensorLink:
    """Sends commands to sensor ``db`` (its node id) on ``bus`` and waits for answers."""

    def __init__(self, bus: can.BusABC, db: Database,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.bus = bus
        self.db = db
        self._clock = clock
        self._ack_id = db.get_message_by_name(alacs_can.MSG_ACK).frame_id
        self.collector = ResultCollector(db)

    def deadline(self, timeout_s: float, fixed: bool = True) -> Deadline:
        return Deadline(self._clock, timeout_s, fixed)

    def recv_until(self, accept: Callable[[can.Message], bool], timeout_s: float | Deadline,
                   on_frame: Callable[[can.Message], object] | None = None) -> can.Message:
        """Receive frames until ``accept(frame)``; feed every frame to ``on_frame``.

        Raises Timeout after ``timeout_s`` seconds (or when the Deadline passes).
        """
        deadline = (timeout_s if isinstance(timeout_s, Deadline)
                    else Deadline(self._clock, timeout_s))
        while True:
            remaining = deadline.remaining()
            if remaining <= 0:
                raise Timeout(f"no answer within {deadline.budget_s:g} s")
            frame = self.bus.recv(timeout=min(remaining, 0.1))
            if frame is None or frame.is_error_frame:
                continue
            if on_frame is not None:
                on_frame(frame)
            if accept(frame):
                return frame

    def _ack_matcher(self, opcode: Opcode, counter: int,
                     results: tuple[AckResult, ...]) -> Callable[[can.Message], bool]:
        wanted = {r.name for r in results}

        def accept(frame: can.Message) -> bool:
            if frame.is_extended_id or frame.arbitration_id != self._ack_id:
                return False
            try:
                ack = alacs_can.decode(self.db, frame)
            except (DecodeError, ValueError):
                return False
            return (
                ack["AckCounter"] == counter
                and ack["AckOpcode"] in (opcode.name, "INVALID")
                and (ack["AckResult"] in wanted or ack["AckResult"] == "NACK")
            )

        return accept

    def wait_ack(self, opcode: Opcode, counter: int, timeout_s: float,
                 results: tuple[AckResult, ...] = (AckResult.ACK, AckResult.DONE),
                 on_frame: Callable[[can.Message], object] | None = None) -> Decoded:
        """Wait for an Ack of ``opcode``/``counter`` with one of ``results``.

        Raises Rejected on NACK and Timeout when nothing matching arrives.
        """
        frame = self.recv_until(self._ack_matcher(opcode, counter, results), timeout_s, on_frame)
        ack = alacs_can.decode(self.db, frame)
        if ack["AckResult"] == "NACK":
            raise Rejected(ack)
        return ack

    def command(self, opcode: Opcode, counter: int, timeout_s: float,
                on_frame: Callable[[can.Message], object] | None = None,
                **signals: object) -> Exchange:
        """Send a command and wait for its ACK (or DONE). Raises Rejected / Timeout."""
        msg = alacs_can.encode_command(self.db, opcode, counter, **signals)
        self.bus.send(msg)

        def seen(frame: can.Message) -> None:
            if on_frame is not None:
                on_frame(frame)
            self.collector.push(frame)

        ack = self.wait_ack(opcode, counter, timeout_s, on_frame=seen)
        return Exchange(command=msg, ack=ack)

    def wait_done(self, exchange: Exchange, timeout_s: float) -> Exchange:
        """After an ACK, wait for the DONE of the same command. Raises Rejected / Timeout."""
        if exchange.ack["AckResult"] != "DONE":
            opcode = Opcode[str(exchange.ack["AckOpcode"])]
            counter = int(exchange.ack["AckCounter"])
            exchange.done = self.wait_ack(opcode, counter, timeout_s, results=(AckResult.DONE,))
        else:
            exchange.done = exchange.ack
        return exchange

    def wait_result(self, exchange: Exchange, timeout_s: float | Deadline,
                    target_id: int | None,
                    on_frame: Callable[[can.Message], object] | None = None) -> Exchange:
        """After an ACK, wait for a complete result (for ``target_id`` if given); every
        frame is also given to ``on_frame`` (progress)."""
        found: list[LocalizationResult] = []

        def accept(frame: can.Message) -> bool:
            if on_frame is not None:
                on_frame(frame)
            result = self.collector.push(frame)
            if result is not None and (target_id is None or result.target_id == target_id):
                found.append(result)
                return True
            return False

        # Results may already be complete from frames read while waiting for the Ack.
        for result in reversed(self.collector.results.values()):
            if result.complete and (target_id is None or result.target_id == target_id):
                exchange.result = result
                return exchange
        try:
            self.recv_until(accept, timeout_s)
        except Timeout:
            partial = next(reversed(self.collector.results.values()), None)
            budget = timeout_s.budget_s if isinstance(timeout_s, Deadline) else timeout_s
            raise Timeout(
                f"no complete result within {budget:g} s"
                + (f" (partial MeasCounter {partial.meas_counter})" if partial else "")
            ) from None
        exchange.result = found[0]
        return exchange
