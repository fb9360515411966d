"""Show a running scan's ALACS_Progress frames: a ``rich`` bar on a terminal, one plain line
per change when piped, one JSON object per change with ``--json``."""

from __future__ import annotations

import json
from typing import Any, TextIO

import can
from cantools.database import Database
from cantools.database.errors import DecodeError

import alacs_can


class ProgressView:
    """Feed it every received frame; it shows those of the scan started with ``counter``."""

    def __init__(self, db: Database, out: TextIO, counter: int, mode: str,
                 json_lines: bool = False, tty: bool | None = None) -> None:
        self._db = db
        self._out = out
        self.counter = counter
        self._mode = mode
        self._json = json_lines
        self._id = db.get_message_by_name(alacs_can.MSG_PROGRESS).frame_id
        self._last: tuple[Any, ...] | None = None
        self.latest: dict[str, Any] | None = None
        self._bar: Any = None
        self._task: Any = None
        if not json_lines and (out.isatty() if tty is None else tty):
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                       TimeElapsedColumn)
            self._bar = Progress(TextColumn("{task.description}"), BarColumn(),
                                 MofNCompleteColumn(), TextColumn("stops"), TimeElapsedColumn(),
                                 console=Console(file=out), transient=True)
            self._task = self._bar.add_task(f"{mode} starting", total=None)
            self._bar.start()

    def push(self, frame: can.Message) -> dict[str, Any] | None:
        """The decoded progress if ``frame`` is one of this scan's, else None."""
        if frame.is_extended_id or frame.arbitration_id != self._id:
            return None
        try:
            p = alacs_can.decode(self._db, frame)
        except (DecodeError, ValueError):
            return None
        if p["ProgressCounter"] != self.counter or p["ProgressMode"] != self._mode:
            return None
        self.latest = p
        key = (p["ProgressPhase"], p["StopsDone"], p["StopsTotal"], p["ObjectsFound"])
        if key == self._last:
            return p
        self._last = key
        text = (f"{p['ProgressPhase']} objects {p['ObjectsFound']}")
        if self._bar is not None:
            self._bar.update(self._task, description=f"{self._mode} {text}",
                             total=max(int(p["StopsTotal"]), 1), completed=int(p["StopsDone"]))
        elif self._json:
            print(json.dumps({"type": "progress", **p}), file=self._out, flush=True)
        else:
            print(f"progress {self._mode} {p['ProgressPhase']} stop {p['StopsDone']}/"
                  f"{p['StopsTotal']} objects {p['ObjectsFound']} elapsed {p['ElapsedS']:g} s",
                  file=self._out, flush=True)
        return p

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None
