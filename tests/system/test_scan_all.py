"""SCAN_ALL on the bench: the sensor sweeps its whole stroke, finds the apples in view by
itself and publishes them as an object list (header + four pages per object)."""

from __future__ import annotations

import json
import math

import gpio_sim
import alacs_can as ac
from sensor import DB, Sensor

APPLES = [((-55.0, -40.0, 1150.0), 38.0), ((15.0, 60.0, 1250.0), 40.0), ((75.0, -10.0, 1100.0), 42.0)]


def test_scan_all_publishes_every_apple(tmp_path, alacsd):
    gpio_sim.drive_input("HOME", 0)
    gpio_sim.drive_input("END", 0)
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"apples": [{"center_mm": list(c), "radius_mm": r} for c, r in APPLES]}))
    sensor = Sensor(alacsd, tmp_path, "--sim-scene", str(scene))
    collector = ac.ResultCollector(DB)
    result = None
    try:
        assert sensor.status(lambda s: str(s["State"]) == "IDLE" and s["Homed"] == 1, 30) is not None
        sensor.send("SCAN_ALL", ScanAllMode="STOP_AND_GO")
        assert str(sensor.ack("SCAN_ALL")["AckResult"]) == "ACK"
        import time
        # 26 full simulated frames rendered inside UML: 100-130 s on a slow 2-core VM.
        end = time.monotonic() + 300
        while result is None and time.monotonic() < end:
            msg = sensor.bus.recv(0.5)
            if msg is not None:
                result = collector.push(msg)
    finally:
        assert sensor.stop() == 0, sensor.log
    assert result is not None, "no complete SCAN_ALL result:\n" + sensor.log
    assert int(result.mode) == int(ac.ResultMode.SCAN_ALL)
    assert int(result.status) == int(ac.ResultStatus.MEASURED)
    assert result.object_count == len(APPLES), sensor.log
    for center, radius in APPLES:
        best = min(result.objects, key=lambda o: math.dist(o.center_mm, center))
        assert math.dist(best.center_mm, center) < 5.0, (best.center_mm, center)
        assert abs(best.quality.diameter_mm - 2 * radius) < 5.0
    # Nearest first (the order the arm would pick them in).
    ranges = [math.dist(o.approach_mm, (0, 0, 0)) for o in result.objects]
    assert ranges == sorted(ranges)
