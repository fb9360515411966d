"""The process lifecycle on the bench (issue 15, findings 1.2, 2.3, 3 and 5.7), end to end
on real vcan0 and real gpio-sim lines: a calibration file that is a JSON bomb leaves the
sensor up and NACKing NOT_CALIBRATED; `alacsd --laser-off` (the unit's ExecStopPost)
drives the line the config names; SIGHUP exits non-zero for Restart=on-failure; STOP and
SIGTERM end a scan whose frame never comes within a stated bound, with its result."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import gpio_sim
import pytest
from sensor import Sensor

# How long STOP or SIGTERM may take to end a scan whose camera blocks for a frame: the
# frame timeout (camera.frame_timeout_ms, 150 ms as shipped) plus the laser-off, the
# result and the bench's scheduling (docs/daemon.md).
END_BOUND_S = 1.0


def _idle_and_homed(s: dict) -> bool:
    return str(s["State"]) == "IDLE" and s["Homed"] == 1


@pytest.fixture(autouse=True)
def _switches_at_normal_travel():
    gpio_sim.drive_input("HOME", 0)
    gpio_sim.drive_input("END", 0)
    yield


def test_a_json_bomb_as_calibration_leaves_the_sensor_up_and_not_calibrated(tmp_path, alacsd) -> None:
    bomb = tmp_path / "calibration.json"
    bomb.write_text("[" * 200_000 + "]" * 200_000)
    sensor = Sensor(alacsd, tmp_path, "--calibration", str(bomb))
    try:
        st = sensor.status(_idle_and_homed, 30)
        assert st is not None, "not up and homed with a JSON bomb as its calibration"
        assert st["Calibrated"] == 0
        sensor.localize()
        ack = sensor.ack("LOCALIZE")
        assert ack is not None and (str(ack["AckResult"]), str(ack["NackReason"])) == ("NACK", "NOT_CALIBRATED"), ack
        assert sensor.proc.poll() is None, "alacsd ended"
    finally:
        assert sensor.stop() == 0, sensor.log
    assert "nest" in sensor.log, sensor.log  # the reason: too deeply nested
    assert gpio_sim.read_output("LASER") == 0


def test_laser_off_drives_the_line_the_config_names(tmp_path, alacsd) -> None:
    def laser_off(line: str) -> subprocess.CompletedProcess:
        cfg = tmp_path / f"{line}.json"
        cfg.write_text(json.dumps({"gpio": {"chip": os.environ["ALACS_GPIO_CHIP"], "laser": line}}))
        return subprocess.run([str(alacsd), "--config", str(cfg), "--laser-off"], capture_output=True, text=True,
                              timeout=30)
    # The configured name is the one requested: a name the chip lacks is refused by name.
    bad = laser_off("LASER_RENAMED")
    assert bad.returncode == 1 and "LASER_RENAMED" in bad.stderr, bad.stderr
    ok = laser_off("SPARE6")
    assert ok.returncode == 0, ok.stderr
    assert "laser off: ok" in ok.stderr
    assert gpio_sim.read_output("SPARE6") == 0


def test_sighup_exits_non_zero_for_the_unit_to_restart(tmp_path, alacsd) -> None:
    sensor = Sensor(alacsd, tmp_path)
    assert sensor.status(timeout=30) is not None
    sensor.proc.send_signal(signal.SIGHUP)
    sensor.proc.wait(timeout=10)
    assert sensor.stop() == 1, sensor.log


@pytest.mark.parametrize("how", ["STOP", "SIGTERM"])
def test_a_frame_that_never_comes_does_not_hold_stop_or_sigterm(tmp_path, alacsd, how) -> None:
    sensor = Sensor(alacsd, tmp_path, "--sim-fault", "camera-timeout")
    try:
        assert sensor.status(_idle_and_homed, 30) is not None
        sensor.localize()
        assert str(sensor.ack("LOCALIZE")["AckResult"]) == "ACK"
        assert sensor.recv(lambda n, s: n == "ALACS_Progress" and str(s["ProgressPhase"]) == "EXPOSING", 20)
        sent = time.monotonic()
        if how == "STOP":
            sensor.send("STOP")
        else:
            sensor.proc.send_signal(signal.SIGTERM)
        header = sensor.recv(lambda n, s: n == "ALACS_ResultHeader", 10)
        took_s = time.monotonic() - sent
        assert header is not None, "no result:\n" + sensor.stop_and_log()
        assert str(header["ResultStatus"]) == "ABORTED", header
        if how == "SIGTERM":
            sensor.proc.wait(timeout=END_BOUND_S * 5)
            took_s = time.monotonic() - sent
            assert sensor.proc.returncode == 0
        print(f"\n{how} with a frame that never comes: ended in {took_s * 1000:.0f} ms")
        assert took_s < END_BOUND_S
        assert gpio_sim.read_output("LASER") == 0
    finally:
        sensor.stop()
