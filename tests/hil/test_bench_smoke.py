"""The HIL bench is real: SocketCAN and GPIO work inside UML.

Runs inside the bench: ``tests/hil/run_in_uml.sh .venv/bin/python -m pytest
tests/hil/test_bench_smoke.py`` (tests/hil/smoke_test.sh does that). On the
host, the bench tests skip; with ALACS_HIL_REQUIRED=1 they fail instead, so a
bench that silently lost its environment cannot pass.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gpio_sim  # noqa: E402  (beside this file, not a package)

IN_BENCH = os.environ.get("ALACS_IN_UML") == "1"
if not IN_BENCH and os.environ.get("ALACS_HIL_REQUIRED") == "1":
    raise RuntimeError("ALACS_HIL_REQUIRED=1 but ALACS_IN_UML is not 1: not inside the bench")

bench = pytest.mark.skipif(
    not IN_BENCH, reason="needs the HIL bench: run through tests/hil/run_in_uml.sh"
)

CAN_IFACE = os.environ.get("ALACS_CAN_IFACE", "vcan0")
EXPECTED_LINES = {
    "STEP": 0, "DIR": 1, "ENABLE": 2, "LASER": 3,
    "HOME": 4, "END": 5, "SPARE6": 6, "SPARE7": 7,
}
FRAME = "123#DEADBEEF"
TIMEOUT_S = 5.0


def wait_for(predicate, what: str, timeout_s: float = TIMEOUT_S):
    """Polls predicate() until it returns a truthy value; fails the test
    after timeout_s seconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.02)


def candump_one_frame(iface: str) -> str:
    """Starts `candump -L -n 1`, sends FRAME with cansend until candump has
    bound its socket and seen it, and returns candump's log line."""
    with subprocess.Popen(
        ["candump", "-L", "-n", "1", iface], stdout=subprocess.PIPE, text=True
    ) as dump:
        def sent_and_seen() -> bool:
            subprocess.run(["cansend", iface, FRAME], check=True)
            return dump.poll() is not None

        try:
            wait_for(sent_and_seen, "candump to see the frame")
        finally:
            if dump.poll() is None:
                dump.kill()
        out, _ = dump.communicate(timeout=TIMEOUT_S)
    assert dump.returncode == 0, out
    return out


# -- environment -----------------------------------------------------------


@bench
def test_bench_environment_is_exported():
    assert os.environ["ALACS_CAN_IFACE"] == "vcan0"
    assert os.environ["ALACS_GPIO_CHIP_LABEL"] == "alacs-sim"
    assert re.fullmatch(r"/dev/gpiochip\d+", os.environ["ALACS_GPIO_CHIP"])
    assert Path(os.environ["ALACS_GPIO_CHIP"]).is_char_device()
    assert Path(os.environ["ALACS_GPIO_SIM_DIR"], "sim_gpio0", "value").is_file()


@bench
def test_can_interfaces_are_up():
    for iface, queue in (("vcan0", "1000"), ("vcan1", None)):
        base = Path("/sys/class/net", iface)
        assert (base / "operstate").exists(), iface
        assert int((base / "flags").read_text(), 16) & 0x1, f"{iface} is not up"
        if queue:
            assert (base / "tx_queue_len").read_text().strip() == queue


# -- CAN -------------------------------------------------------------------


@bench
def test_cansend_is_seen_by_candump():
    line = candump_one_frame(CAN_IFACE)
    assert re.fullmatch(r"\(\d+\.\d+\) vcan0 123#DEADBEEF\n", line), line


@bench
def test_cansend_is_seen_by_python_can():
    import can

    with can.Bus(interface="socketcan", channel=CAN_IFACE) as bus:
        subprocess.run(["cansend", CAN_IFACE, FRAME], check=True)
        msg = bus.recv(timeout=TIMEOUT_S)
    assert msg is not None, "python-can received nothing"
    assert msg.arbitration_id == 0x123
    assert not msg.is_extended_id
    assert bytes(msg.data) == bytes.fromhex("DEADBEEF")


@bench
def test_python_can_frame_is_seen_by_second_bus():
    import can

    with can.Bus(interface="socketcan", channel=CAN_IFACE) as rx, can.Bus(
        interface="socketcan", channel=CAN_IFACE
    ) as tx:
        tx.send(can.Message(arbitration_id=0x321, data=b"\x01\x02", is_extended_id=False))
        msg = rx.recv(timeout=TIMEOUT_S)
    assert msg is not None and msg.arbitration_id == 0x321
    assert bytes(msg.data) == b"\x01\x02"


DBC = """\
VERSION ""

NS_ :

BS_:

BU_: ALACS

BO_ 291 BenchProbe: 4 ALACS
 SG_ High : 7|16@0+ (1,0) [0|65535] "" Vector__XXX
 SG_ Low : 23|16@0+ (1,0) [0|65535] "" Vector__XXX
"""


@bench
def test_candump_log_decodes_with_cantools(tmp_path):
    dbc = tmp_path / "bench.dbc"
    dbc.write_text(DBC)
    log = tmp_path / "candump.log"
    log.write_text(candump_one_frame(CAN_IFACE))

    with log.open() as stdin:
        decoded = subprocess.run(
            [sys.executable, "-m", "cantools", "decode", str(dbc)],
            stdin=stdin, capture_output=True, text=True, check=True,
        ).stdout
    assert "BenchProbe(" in decoded, decoded
    assert f"High: {0xDEAD}" in decoded, decoded
    assert f"Low: {0xBEEF}" in decoded, decoded


# -- GPIO ------------------------------------------------------------------


def gpiofind(name: str) -> tuple[str, str]:
    chip, offset = subprocess.run(
        ["gpiofind", name], capture_output=True, text=True, check=True
    ).stdout.split()
    return chip, offset


@bench
def test_line_names_match_gpioinfo():
    assert gpio_sim.line_offsets() == EXPECTED_LINES
    info = subprocess.run(
        ["gpioinfo", os.environ["ALACS_GPIO_CHIP_LABEL"]],
        capture_output=True, text=True, check=True,
    ).stdout
    from_gpioinfo = {
        m.group(2): int(m.group(1))
        for m in re.finditer(r'line\s+(\d+):\s+"([^"]*)"', info)
    }
    assert from_gpioinfo == EXPECTED_LINES
    for name, offset in EXPECTED_LINES.items():
        assert gpiofind(name) == (Path(os.environ["ALACS_GPIO_CHIP"]).name, str(offset))


@bench
@pytest.mark.parametrize(
    ("line", "pull", "level"),
    [("STEP", 0, 1), ("DIR", 0, 1), ("ENABLE", 0, 1), ("LASER", 0, 1), ("LASER", 1, 0)],
)
def test_gpioset_output_is_read_back(line, pull, level):
    gpio_sim.drive_input(line, pull)   # the level the line idles at
    try:
        assert gpio_sim.read_output(line) == pull
        chip, offset = gpiofind(line)
        # --mode=wait, ended by a newline on stdin: a SIGTERM (--mode=signal) that came before
        # gpioset had set up its handler killed it (-15) on a loaded CI run.
        with subprocess.Popen(["gpioset", "--mode=wait", chip, f"{offset}={level}"],
                              stdin=subprocess.PIPE, text=True) as holder:
            try:
                wait_for(lambda: gpio_sim.read_output(line) == level, f"{line}={level}")
            finally:
                holder.communicate(input="\n", timeout=TIMEOUT_S)
        assert holder.returncode == 0
        # Released: gpio-sim falls back to the pull.
        wait_for(lambda: gpio_sim.read_output(line) == pull, f"{line} released")
    finally:
        # Back to idling low whatever happened: a LASER left pulled high failed every later
        # test that reads the laser off.
        gpio_sim.drive_input(line, 0)


def gpioget(name: str) -> int:
    chip, offset = gpiofind(name)
    out = subprocess.run(
        ["gpioget", chip, offset], capture_output=True, text=True, check=True
    ).stdout
    return int(out)


@bench
def test_limit_inputs_start_at_normal_travel():
    # Normally-closed switches to GND (docs/install.md): 0 until a switch is reached.
    assert gpioget("HOME") == 0
    assert gpioget("END") == 0


@bench
@pytest.mark.parametrize("line", ["HOME", "END"])
def test_drive_input_is_read_by_gpioget(line):
    try:
        gpio_sim.drive_input(line, 0)
        assert gpioget(line) == 0
        gpio_sim.drive_input(line, 1)
        assert gpioget(line) == 1
    finally:
        gpio_sim.drive_input(line, 1)


@bench
def test_unknown_line_is_a_clear_error():
    with pytest.raises(gpio_sim.GpioSimError, match="no line 'NOPE'"):
        gpio_sim.read_output("NOPE")
    with pytest.raises(ValueError):
        gpio_sim.drive_input("HOME", 2)


def test_gpio_sim_refuses_to_work_outside_the_bench(monkeypatch):
    monkeypatch.delenv("ALACS_IN_UML", raising=False)
    gpio_sim.line_offsets.cache_clear()
    try:
        with pytest.raises(gpio_sim.GpioSimError, match="run_in_uml.sh"):
            gpio_sim.read_output("LASER")
    finally:
        gpio_sim.line_offsets.cache_clear()


def test_tools_are_installed():
    for tool in ("candump", "cansend", "gpioset", "gpioget", "gpioinfo", "gpiofind"):
        assert shutil.which(tool), f"{tool} missing: apt-get install can-utils gpiod"


@bench
def test_vimc_camera_is_listed_by_cam():
    """The bench kernel has vimc built in; with udev started, libcamera's own `cam -l`
    lists its sensor (the one step that is easy to miss: without udev it lists none)."""
    assert Path("/dev/media0").exists(), "no /dev/media0: the bench kernel lacks CONFIG_VIDEO_VIMC"
    subprocess.run([str(Path(__file__).resolve().parent / "start_udev.sh")], check=True, timeout=60)
    out = subprocess.run(["cam", "-l"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert re.search(r"^\d+: .*\(platform/vimc\.0 Sensor B\)", out.stdout, re.M), out.stdout
