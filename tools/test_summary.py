"""Sums the JUnit reports of the test suites into one closing line:
``tests: N passed, N failed`` (a suite that failed before reporting counts as
one failure). Exit status 1 when anything failed."""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from pathlib import Path


def count(path: Path) -> tuple[int, int, int]:
    root = ET.parse(path).getroot()
    suites = [root] if root.tag == "testsuite" else list(root.iter("testsuite"))
    passed = failed = skipped = 0
    for s in suites:
        for case in s.iter("testcase"):
            if case.find("failure") is not None or case.find("error") is not None:
                failed += 1
            elif case.find("skipped") is not None:
                skipped += 1
            else:
                passed += 1
    return passed, failed, skipped


def main() -> int:
    reports = Path(sys.argv[1])
    failed_suites = sys.argv[2:]
    passed = failed = skipped = 0
    for xml in sorted(reports.glob("*.xml")):
        p, f, s = count(xml)
        print(f"  {xml.stem:10s} {p:4d} passed {f:4d} failed {s:4d} skipped")
        passed, failed, skipped = passed + p, failed + f, skipped + s
    reported = {x.stem for x in reports.glob("*.xml")}
    for suite in failed_suites:
        print(f"  suite '{suite}' failed")
        if suite not in reported:
            failed += 1  # it never produced a report: count the suite itself
    line = f"tests: {passed} passed, {failed} failed"
    if skipped:
        line += f", {skipped} skipped"
    print(line)
    return 1 if failed or failed_suites else 0


if __name__ == "__main__":
    sys.exit(main())
