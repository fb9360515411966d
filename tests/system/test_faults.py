"""Faults on the bench: each one puts the sensor in FAULT with its reason on CAN (status
bit, EMCY, failed result), the laser off and the motion stopped; recovery is by command.
Real vcan0 and real gpio-sim lines; the simulated hardware injects what a bench cannot
(a frame that never comes, a home switch that never closes)."""

from __future__ import annotations

import gpio_sim
import pytest
from sensor import Sensor


def _idle_and_homed(s: dict) -> bool:
    return str(s["State"]) == "IDLE" and s["Homed"] == 1


def _emcy(sensor: Sensor, reason: str) -> dict | None:
    return sensor.recv(lambda n, s: n == "EMCY" and str(s["EmcyReason"]) == reason, 10.0)


def _safe_outputs() -> None:
    assert gpio_sim.read_output("LASER") == 0
    assert gpio_sim.read_output("ENABLE") == 0


@pytest.fixture(autouse=True)
def _switches_at_normal_travel():
    gpio_sim.drive_input("HOME", 0)
    gpio_sim.drive_input("END", 0)
    yield
    gpio_sim.drive_input("END", 0)


def test_limit_switch_mid_move_then_recovery(tmp_path, alacsd):
    sensor = Sensor(alacsd, tmp_path)
    try:
        assert sensor.status(_idle_and_homed, 30) is not None, "never IDLE and homed"
        sensor.localize()
        assert str(sensor.ack("LOCALIZE")["AckResult"]) == "ACK"
        # The scan moves towards the target: the end switch closes under it.
        assert sensor.status(lambda s: str(s["State"]) == "SCANNING", 5) is not None
        gpio_sim.drive_input("END", 1)
        assert _emcy(sensor, "LIMIT_HIT") is not None
        header = sensor.recv(lambda n, s: n == "ALACS_ResultHeader", 10)
        assert header is not None and str(header["ResultStatus"]) == "FAILED"
        assert str(header["ResultReason"]) == "MOTION_FAULT", header
        st = sensor.status(lambda s: str(s["State"]) == "FAULT")
        assert st["FaultLimitHit"] == 1 and st["LaserOn"] == 0
        _safe_outputs()
        # Commands other than CLEAR_FAULT/STOP/GET_VERSION are refused with the reason.
        sensor.localize()
        nack = sensor.ack("LOCALIZE")
        assert str(nack["AckResult"]) == "NACK" and str(nack["NackReason"]) == "FAULT_ACTIVE"
        # Recovery: clear, re-home (the position was lost), localize again.
        gpio_sim.drive_input("END", 0)
        sensor.send("CLEAR_FAULT")
        assert str(sensor.ack("CLEAR_FAULT")["AckResult"]) == "ACK"
        st = sensor.status(lambda s: str(s["State"]) == "IDLE")
        assert st["FaultLimitHit"] == 0 and st["Homed"] == 0
        sensor.send("HOME")
        assert sensor.recv(lambda n, s: n == "ALACS_Ack" and str(s["AckOpcode"]) == "HOME"
                           and str(s["AckResult"]) == "DONE", 30) is not None
        sensor.localize()
        header = sensor.recv(lambda n, s: n == "ALACS_ResultHeader", 30)
        assert header is not None and str(header["ResultStatus"]) == "MEASURED"
    finally:
        assert sensor.stop() == 0, sensor.log
    _safe_outputs()


def test_homing_timeout(tmp_path, alacsd):
    sensor = Sensor(alacsd, tmp_path, "--sim-fault", "home-stuck", config={"motion": {"homing_timeout_ms": 800}})
    try:
        assert _emcy(sensor, "HOMING_TIMEOUT") is not None
        st = sensor.status(lambda s: str(s["State"]) == "FAULT")
        assert st["FaultHomingTimeout"] == 1 and st["Homed"] == 0
        _safe_outputs()
        sensor.send("CLEAR_FAULT")
        assert sensor.status(lambda s: str(s["State"]) == "IDLE") is not None
        sensor.localize()
        nack = sensor.ack("LOCALIZE")
        assert str(nack["AckResult"]) == "NACK" and str(nack["NackReason"]) == "NOT_HOMED"
    finally:
        assert sensor.stop() == 0, sensor.log


@pytest.mark.parametrize("fault,bit,reason", [("camera-timeout", "FaultCameraTimeout", "CAMERA_TIMEOUT"),
                                              ("camera-corrupt", "FaultCameraCorrupt", "CAMERA_CORRUPT")])
def test_camera_fault_after_retries(tmp_path, alacsd, fault, bit, reason):
    # The default configuration as shipped: its frame timeout (plus the exposure) stays
    # below laser.max_on_ms, so a camera that stops answering is CAMERA_TIMEOUT, never
    # LASER_OVERTIME hiding it (config validation refuses a combination that would).
    sensor = Sensor(alacsd, tmp_path, "--sim-fault", fault)
    try:
        assert sensor.status(_idle_and_homed, 30) is not None
        sensor.localize()
        assert str(sensor.ack("LOCALIZE")["AckResult"]) == "ACK"
        header = sensor.recv(lambda n, s: n == "ALACS_ResultHeader", 20)
        assert header is not None and str(header["ResultStatus"]) == "FAILED"
        assert str(header["ResultReason"]) == "CAMERA_FAULT", header
        assert not any(n == "EMCY" and str(s["EmcyReason"]) == "LASER_OVERTIME" for n, s in sensor.seen)
        assert _emcy(sensor, reason) is not None or any(
            n == "EMCY" and str(s["EmcyReason"]) == reason for n, s in sensor.seen)
        st = sensor.status(lambda s: str(s["State"]) == "FAULT")
        assert st[bit] == 1
        assert st["DroppedFrames"] == 3  # the first attempt and two retries
        _safe_outputs()
    finally:
        assert sensor.stop() == 0, sensor.log
    assert "attempt 3" in sensor.log
    assert "stopped by" not in sensor.log  # no command stopped it


def test_bad_configuration_is_refused_with_the_key(tmp_path, alacsd):
    """A refused configuration file leaves alacsd up on its defaults (issue 19): the log
    names the key, the status says CONFIG_INVALID, and HOME and LOCALIZE are NACKed
    FAULT_ACTIVE (the defaults need not fit the slide, so nothing moves)."""
    from sensor import Sensor
    sensor = Sensor(alacsd, tmp_path, config={"scan": {"stops": 40}})
    try:
        st = sensor.status(lambda s: s["FaultConfigInvalid"] == 1, 30)
        assert st is not None, "no status with FaultConfigInvalid"
        sensor.localize()
        ack = sensor.ack("LOCALIZE")
        assert ack is not None and (str(ack["AckResult"]), str(ack["NackReason"])) == ("NACK", "FAULT_ACTIVE"), ack
        assert sensor.proc.poll() is None, "alacsd ended"
    finally:
        assert sensor.stop() == 0, sensor.log
    assert "scan.stops" in sensor.log, sensor.log
    _safe_outputs()
