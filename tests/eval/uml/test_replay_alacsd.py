"""Scan directories through the real daemon, inside the UML bench (real vcan0):

* a scan exported by the twin replays through `alacsd --replay`: the daemon plans its
  stops from the LOCALIZE command, the replay source serves the frame recorded nearest
  each stop and its recorded position (the twin's five frames for the daemon's seven
  stops: the repeats count once), and the result on the bus matches the pipeline run
  offline on the same scan (`alacs-twin process`) and the truth;
* `alacsd --sim --record` writes each scan as a scan directory, and that recording
  replays through `alacsd --replay` into the same result.

Needs ALACS_ALACSD (the daemon) and ALACS_TWIN (alacs-twin); tests/eval/run.sh sets both.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tools" / "eval" / "src"))

import can  # noqa: E402

import alacs_can as ac  # noqa: E402
from alacs_eval.scans import Scan, target_truth  # noqa: E402


@pytest.fixture(scope="module")
def binaries() -> tuple[Path, Path]:
    if os.environ.get("ALACS_IN_UML") != "1":
        pytest.fail("runs inside the HIL bench: tests/hil/run_in_uml.sh -- pytest tests/eval/uml")
    alacsd = Path(os.environ.get("ALACS_ALACSD", ROOT / "build" / "release" / "edge" / "app" / "alacsd"))
    twin = Path(os.environ.get("ALACS_TWIN", ROOT / "build" / "release" / "tools" / "twin" / "alacs-twin"))
    for p in (alacsd, twin):
        if not p.exists():
            pytest.fail(f"{p} is not built")
    return alacsd, twin


def _wait(bus: can.BusABC, pred, timeout_s: float) -> can.Message | None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        msg = bus.recv(timeout=max(0.0, end - time.monotonic()))
        if msg is not None and pred(msg):
            return msg
    return None


def localize(alacsd: Path, args: list[str], rough: tuple[float, float, float]) -> tuple[ac.LocalizationResult | None, str]:
    """Starts alacsd with `args`, waits until it is homed, sends one LOCALIZE, returns the result."""
    iface = os.environ.get("ALACS_CAN_IFACE", "vcan0")
    db = ac.load_database()
    bus = can.Bus(interface="socketcan", channel=iface, receive_own_messages=False)
    proc = subprocess.Popen([str(alacsd), "--can", iface, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    result = None
    try:
        status_id = ac.frame_id(ac.MSG_STATUS)

        def homed(m: can.Message) -> bool:
            if m.arbitration_id != status_id:
                return False
            s = ac.decode(db, m, choices=False)
            return bool(s["Homed"]) and int(s["State"]) == int(ac.SensorState.IDLE)

        assert _wait(bus, homed, 30.0) is not None, "alacsd did not become IDLE and homed"
        bus.send(ac.encode_command(db, "LOCALIZE", counter=1, LocalizeMode="STOP_AND_GO", TargetId=1,
                                   RoughX=round(rough[0]), RoughY=round(rough[1]), RoughZ=round(rough[2], -1)))
        collector = ac.ResultCollector(db)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and result is None:
            m = bus.recv(timeout=0.5)
            if m is not None:
                result = collector.push(m)
    finally:
        bus.shutdown()
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=15)
    return result, out


@pytest.fixture(scope="module")
def twin_scan(tmp_path_factory, binaries) -> Path:
    _, twin = binaries
    out = tmp_path_factory.mktemp("twin")
    subprocess.run([str(twin), "generate", "--set", "loc", "--out", str(out), "--count", "1", "--distance-mm", "1200",
                    "--occluded", "0", "--seed", "5", "--jobs", "1"], check=True, capture_output=True)
    return out / "d1200_occ0_0000"


def test_twin_scan_replays_through_alacsd(twin_scan, binaries):
    alacsd, twin = binaries
    scan = Scan.load(twin_scan)
    # The command carries the rough position at CAN resolution (mm, z in 10 mm).
    rough = (round(scan.rough_mm[0]), round(scan.rough_mm[1]), round(scan.rough_mm[2], -1))
    result, log = localize(alacsd, ["--replay", str(twin_scan)], rough)
    assert result is not None, log[-3000:]
    assert result.status.name == "MEASURED", log[-3000:]
    assert "replay" in log and "camera:" in log
    obj = result.objects[0]
    # Offline, the same pipeline on the same scan, planned from the same rounded position.
    manifest = json.loads((twin_scan / "manifest.json").read_text())
    manifest["scan"]["rough_mm"] = list(rough)
    (twin_scan / "manifest.json").write_text(json.dumps(manifest))
    line = subprocess.run([str(twin), "process", str(twin_scan)], check=True, capture_output=True, text=True).stdout
    offline = json.loads(line)["multi"]
    assert offline["ok"]
    # Same frames, same recorded positions, same code: equal to the CAN encoding's resolution.
    assert math.dist(obj.center_mm, offline["center_mm"]) < 0.6, (obj.center_mm, offline["center_mm"])
    centre, radius, approach = target_truth(scan)
    assert math.dist(obj.center_mm, centre) < 8.0
    assert math.dist(obj.approach_mm, approach) < 8.0


def test_record_then_replay_gives_the_same_result(tmp_path, binaries):
    alacsd, _ = binaries
    scene = {"seed": 3, "apples": [{"id": 1, "center_mm": [20.0, -10.0, 1150.0], "radius_mm": 38.0}]}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    rec = tmp_path / "rec"
    rough = (26.0, -3.0, 1170.0)
    live, log = localize(alacsd, ["--sim", "--sim-scene", str(tmp_path / "scene.json"), "--record", str(rec)], rough)
    assert live is not None, log[-3000:]
    recorded = rec / "scan_0001"
    scan = Scan.load(recorded)
    # The laser-off frames the exposure was metered on (metering.*, docs/daemon.md), then the
    # default first pass's stops, every one at the metered exposure.
    off = [f for f in scan.frames if not f.laser_on]
    stops = [f for f in scan.frames if f.laser_on]
    assert scan.kind == "localize" and len(stops) == 7
    assert 1 <= len(off) <= 4 and scan.frames[:len(off)] == off
    assert len({f.exposure_us for f in stops}) == 1
    assert scan.rough_mm is not None and math.dist(scan.rough_mm, rough) < 1.0
    replayed, log2 = localize(alacsd, ["--replay", str(recorded)], rough)
    assert replayed is not None, log2[-3000:]
    # The recording holds the very frames and positions the live scan used.
    assert math.dist(replayed.objects[0].center_mm, live.objects[0].center_mm) < 0.2
    assert abs(replayed.objects[0].quality.diameter_mm - live.objects[0].quality.diameter_mm) < 0.2
