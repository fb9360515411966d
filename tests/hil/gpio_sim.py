"""The far side of the bench's simulated GPIO chip, for tests inside UML.

run_in_uml.sh sets up a gpio-sim chip (label ``alacs-sim``) whose lines the
program under test requests through the GPIO character device like real pins.
This module plays the wiring on the other side: it drives the program's
inputs (limit switches) and reads the levels the program drives on its
outputs (step, direction, enable, laser). Standard library only.

Lines are found by name. The names are read from the chip itself through the
GPIO character device, so the table in uml_init.sh stays the only copy.

Usage, in a test run by ``tests/hil/run_in_uml.sh``::

    from tests.hil import gpio_sim        # or: sys.path has tests/hil
    gpio_sim.drive_input("HOME", 0)       # home switch pressed (active low)
    assert gpio_sim.read_output("LASER") == 0
"""

from __future__ import annotations

import fcntl
import functools
import os
import struct
from pathlib import Path

__all__ = [
    "GpioSimError",
    "chip_path",
    "drive_input",
    "line_offsets",
    "read_output",
    "sim_dir",
]

# <linux/gpio.h>: _IOR(0xB4, 0x01, struct gpiochip_info) and
# _IOWR(0xB4, 0x05, struct gpio_v2_line_info).
_NAME_SIZE = 32
_CHIPINFO_FORMAT = f"={_NAME_SIZE}s{_NAME_SIZE}sI"
_LINEINFO_SIZE = 256
_GPIO_GET_CHIPINFO_IOCTL = (2 << 30) | (struct.calcsize(_CHIPINFO_FORMAT) << 16) | (0xB4 << 8) | 0x01
_GPIO_V2_GET_LINEINFO_IOCTL = (3 << 30) | (_LINEINFO_SIZE << 16) | (0xB4 << 8) | 0x05


class GpioSimError(RuntimeError):
    """The bench's gpio-sim chip is not there or not as expected."""


def _env(name: str) -> str:
    value = os.environ.get(name, "")
    if os.environ.get("ALACS_IN_UML") != "1" or not value:
        raise GpioSimError(
            f"{name} is not set: gpio_sim only works inside the HIL bench "
            "(run the test through tests/hil/run_in_uml.sh)"
        )
    return value


def sim_dir() -> Path:
    """The sysfs directory holding ``sim_gpioK/{pull,value}`` of the chip."""
    path = Path(_env("ALACS_GPIO_SIM_DIR"))
    if not path.is_dir():
        raise GpioSimError(f"ALACS_GPIO_SIM_DIR={path} is not a directory")
    return path


def chip_path() -> Path:
    """The character device of the chip, e.g. ``/dev/gpiochip0``."""
    return Path(_env("ALACS_GPIO_CHIP"))


@functools.lru_cache(maxsize=None)
def line_offsets() -> dict[str, int]:
    """Line name -> offset, as the kernel reports them for the sim chip.

    Raises GpioSimError outside the bench, if the chip's label is not
    ``$ALACS_GPIO_CHIP_LABEL``, if a name is missing or repeated, or if the
    sysfs side does not have one ``sim_gpioK`` per line.
    """
    label = _env("ALACS_GPIO_CHIP_LABEL")
    directory = sim_dir()
    with open(chip_path(), "rb", buffering=0) as chip:
        info = bytearray(struct.calcsize(_CHIPINFO_FORMAT))
        fcntl.ioctl(chip, _GPIO_GET_CHIPINFO_IOCTL, info)
        _, raw_label, num_lines = struct.unpack(_CHIPINFO_FORMAT, info)
        if _c_string(raw_label) != label:
            raise GpioSimError(
                f"{chip_path()} is labelled {_c_string(raw_label)!r}, not {label!r}"
            )
        offsets: dict[str, int] = {}
        for offset in range(num_lines):
            line = bytearray(_LINEINFO_SIZE)
            struct.pack_into("=I", line, 2 * _NAME_SIZE, offset)
            fcntl.ioctl(chip, _GPIO_V2_GET_LINEINFO_IOCTL, line)
            name = _c_string(bytes(line[:_NAME_SIZE]))
            if not name or name in offsets:
                raise GpioSimError(f"line {offset} of {label} has no unique name: {name!r}")
            offsets[name] = offset
    for offset in offsets.values():
        if not (directory / f"sim_gpio{offset}").is_dir():
            raise GpioSimError(f"{directory}/sim_gpio{offset} missing")
    return offsets


def _line_dir(name: str) -> Path:
    offsets = line_offsets()
    if name not in offsets:
        raise GpioSimError(f"no line {name!r} on the sim chip; it has {sorted(offsets)}")
    return sim_dir() / f"sim_gpio{offsets[name]}"


def drive_input(name: str, level: int) -> None:
    """Drive the input line `name` to `level` (0 or 1) from outside.

    Sets the simulated pull (pull-up for 1, pull-down for 0): a program that
    requested the line as an input reads that level, with an edge event if it
    changed. Has no effect on a line the program drives as an output.
    """
    if level not in (0, 1):
        raise ValueError(f"level must be 0 or 1, not {level!r}")
    (_line_dir(name) / "pull").write_text("pull-up" if level else "pull-down")


def read_output(name: str) -> int:
    """The level (0 or 1) on line `name`: what the program drives on it if it
    requested it as an output, otherwise the simulated pull."""
    return int((_line_dir(name) / "value").read_text().strip())


def _c_string(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode()
