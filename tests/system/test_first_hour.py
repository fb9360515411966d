"""The integrator's first hour, as docs/can-protocol.md writes it (issue 16, item 8).

The doc's "First hour" section is the script: every `$` line of its `console` blocks runs
here, in order, with bash (`alacsd` is the built daemon, `alacs` the CLI in .venv), and each
line shown under a command must appear in what that command printed (stdout and stderr
together), in the same order, `…` standing for anything. A command ending in `&` runs in
the background until the end. The `python` blocks run as written. So the doc and the
sensor cannot drift apart: change either and this test says where.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "can-protocol.md"


@dataclass
class Step:
    command: str
    expected: list[str] = field(default_factory=list)


@dataclass
class Block:
    kind: str  # "console" or "python"
    steps: list[Step] = field(default_factory=list)
    code: str = ""


def first_hour_blocks(text: str) -> list[Block]:
    """The fenced blocks of the '## First hour' section, indentation removed."""
    m = re.search(r"^## First hour\n(.*?)^## ", text, re.S | re.M)
    assert m, "docs/can-protocol.md has no '## First hour' section"
    blocks: list[Block] = []
    for fence in re.finditer(r"^( *)```(console|python)\n(.*?)^\1```", m.group(1), re.S | re.M):
        indent = len(fence.group(1))
        lines = [ln[indent:] if ln[:indent].strip() == "" else ln for ln in fence.group(3).splitlines()]
        if fence.group(2) == "python":
            blocks.append(Block("python", code="\n".join(lines) + "\n"))
            continue
        block = Block("console")
        for ln in lines:
            if ln.startswith("$ "):
                block.steps.append(Step(ln[2:]))
            elif ln.strip():
                assert block.steps, f"output before any command in a console block: {ln!r}"
                block.steps[-1].expected.append(ln.strip())
        blocks.append(block)
    return blocks


def pattern(expected: str) -> re.Pattern[str]:
    """`…` (and the spaces around it) stands for anything, nothing included."""
    return re.compile(".*".join(re.escape(part) for part in re.split(r"\s*…\s*", expected)))


def assert_shown(step: Step, output: str) -> None:
    """Each expected line matches a line of the output, in order."""
    lines = output.splitlines()
    at = 0
    for want in step.expected:
        rx = pattern(want)
        for i in range(at, len(lines)):
            if rx.search(lines[i]):
                at = i + 1
                break
        else:
            raise AssertionError(f"$ {step.command}\n  expected (in order): {want!r}\n"
                                 f"  after line {at} of what it printed:\n{output}")


def test_doc_parses_into_the_steps_we_rely_on() -> None:
    """The parser itself, on the doc: blocks found, and a line with … becomes a pattern."""
    blocks = first_hour_blocks(DOC.read_text())
    commands = [s.command for b in blocks for s in b.steps]
    assert any(c.startswith("alacsd ") and c.endswith("&") for c in commands), commands
    assert sum("alacs localize" in c for c in commands) >= 3, commands
    assert any(b.kind == "python" and "canopen" in b.code for b in blocks)
    assert pattern("State=IDLE … Homed=1").search("State=IDLE Mode=x Homed=1")
    assert pattern("State=IDLE … Homed=1").search("State=IDLE Homed=1")
    assert not pattern("State=IDLE … Homed=1").search("State=FAULT Homed=1")


def test_first_hour_as_documented(alacsd: Path, tmp_path: Path) -> None:
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    env["PATH"] = os.pathsep.join([str(alacsd.parent), str(Path(sys.executable).parent), env["PATH"]])
    background: list[tuple[str, subprocess.Popen[bytes], Path]] = []
    try:
        for block in first_hour_blocks(DOC.read_text()):
            if block.kind == "python":
                exec(compile(block.code, f"{DOC}:First hour", "exec"), {"__name__": "first_hour"})  # noqa: S102
                continue
            for step in block.steps:
                if step.command.endswith("&"):
                    log = tmp_path / f"background{len(background)}.log"
                    with log.open("wb") as out:
                        proc = subprocess.Popen(["bash", "-c", "exec " + step.command[:-1]], cwd=ROOT, env=env,
                                                stdout=out, stderr=subprocess.STDOUT)
                    background.append((step.command, proc, log))
                    continue
                # One stream, unbuffered: the order a user sees on a terminal.
                done = subprocess.run(["bash", "-c", step.command], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True, timeout=180, check=False)
                assert_shown(step, done.stdout)
    finally:
        for command, proc, log in background:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            try:
                rc = proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                rc = proc.wait()
            assert rc == 0, f"{command} ended with {rc}:\n{log.read_text()[-3000:]}"
