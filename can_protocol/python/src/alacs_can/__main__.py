"""``python -m alacs_can dbc|golden|eds|od-header|names-header|doc-tables ...``: write a generated artifact."""

from __future__ import annotations

import sys

from . import dbc, doctables, eds, golden, names


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    tools = {
        "dbc": dbc.main,
        "golden": golden.main,
        "eds": lambda a: eds.main(["eds", *a]),
        "od-header": lambda a: eds.main(["od-header", *a]),
        "names-header": names.main,
        "doc-tables": doctables.main,
    }
    if not args or args[0] not in tools:
        print("usage: python -m alacs_can {dbc,golden,eds,od-header,names-header,doc-tables} [options]  (--help for each)",
              file=sys.stderr)
        return 2
    return tools[args[0]](args[1:])


if __name__ == "__main__":
    raise SystemExit(main())
