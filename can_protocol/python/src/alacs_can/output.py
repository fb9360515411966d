"""Where a generator's text goes: the file ``-o`` names, byte for byte, or stdout."""

from __future__ import annotations

import sys


def write_text(text: str, path: str | None) -> None:
    """ASCII, and no newline translation: the EDS keeps its CRLF, everything else its LF."""
    if path:
        with open(path, "w", encoding="ascii", newline="") as f:
            f.write(text)
    else:
        sys.stdout.write(text)
