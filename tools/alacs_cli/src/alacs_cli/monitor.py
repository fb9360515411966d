"""``alacs monitor --view table``: one row per message, the newest decoded values,
frame count and rate, redrawn in place. Pure: frames and times in, text out."""

from __future__ import annotations

from dataclasses import dataclass, field

import can
from cantools.database import Database
from cantools.database.errors import DecodeError

import alacs_can

_CLEAR = "\x1b[H\x1b[2J"
_RATE_WINDOW_S = 2.0


@dataclass
class _Row:
    ident: str
    name: str
    text: str = ""
    count: int = 0
    last_s: float = 0.0
    times: list[float] = field(default_factory=list)

    def rate(self, now: float) -> float:
        recent = [t for t in self.times if now - t <= _RATE_WINDOW_S]
        self.times = recent
        return len(recent) / _RATE_WINDOW_S


class MonitorTable:
    """Keeps the newest decoded content per (id, multiplexer page) and renders a table."""

    def __init__(self, db: Database) -> None:
        self.db = db
        self.rows: dict[tuple[int, bool, str], _Row] = {}
        self.total = 0
        self.bad_checksums = 0

    def push(self, frame: can.Message, now: float) -> None:
        self.total += 1
        ident = (f"{frame.arbitration_id:08X}" if frame.is_extended_id
                 else f"{frame.arbitration_id:03X}")
        name = alacs_can.message_name(self.db, frame)
        page = ""
        if name is None:
            text = f"[{frame.dlc}] " + bytes(frame.data).hex(" ").upper()
            name = "-"
        else:
            try:
                signals = alacs_can.decode(self.db, frame)
                # One row per multiplexer value, so result pages do not overwrite each other.
                for mux in ("CmdOpcode", "AckOpcode", "ObjPage"):
                    if mux in signals:
                        page = str(signals[mux])
                # Fault bits that are 0 would push everything else off the screen.
                text = " ".join(f"{k}={_short(v)}" for k, v in signals.items()
                                if not (k.startswith("Fault") and v == 0))
            except (DecodeError, ValueError) as exc:
                text = f"[{frame.dlc}] {bytes(frame.data).hex(' ').upper()} (undecodable: {exc})"
            if name == alacs_can.MSG_COMMAND and not alacs_can.check_command(frame.data):
                text += "  CHECKSUM-BAD"
                self.bad_checksums += 1
        key = (frame.arbitration_id, frame.is_extended_id, page)
        row = self.rows.setdefault(key, _Row(ident, name))
        row.text = text
        row.count += 1
        row.last_s = now
        row.times.append(now)

    def render(self, now: float, clear: bool = True, width: int | None = None) -> str:
        """The table; rows cut at ``width`` characters if given (a terminal's width)."""
        lines = [f"alacs monitor: {self.total} frames, {len(self.rows)} rows, "
                 f"{self.bad_checksums} bad command checksums",
                 f"{'id':>8}  {'message':<18} {'count':>7} {'rate/s':>7} {'age s':>6}  signals"]
        for key in sorted(self.rows):
            row = self.rows[key]
            line = (f"{row.ident:>8}  {row.name:<18} {row.count:>7} {row.rate(now):>7.1f} "
                    f"{now - row.last_s:>6.1f}  {row.text}")
            lines.append(line if width is None else line[:width])
        return (_CLEAR if clear else "") + "\n".join(lines) + "\n"


def _short(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4f}".rstrip("0").rstrip(".")
    return str(value)
