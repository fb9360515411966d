"""One localization exchange with a live ``alacsd --sim`` over real SocketCAN.

Used by the system test (tests/system/test_localize_e2e.py) and by the demo
(tools/demo/run.sh), both inside the UML bench (tests/hil/run_in_uml.sh), where
vcan0 and the gpio-sim chip are real kernel devices.

The harness: writes a scene (one apple at a seeded position), starts
``candump -L`` and ``alacsd``, waits for the boot-up heartbeat and a homed
status, sends LOCALIZE with python-can, collects the ack and the result frames,
decodes them with cantools against the committed DBC, stops everything and
returns what happened, with the truth beside it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import can
import cantools

import alacs_can as ac

ROOT = Path(__file__).resolve().parents[2]
DBC = ROOT / "can_protocol" / "alacs.dbc"


@dataclasses.dataclass
class Exchange:
    truth_center_mm: tuple[float, float, float]
    truth_approach_mm: tuple[float, float, float]
    truth_radius_mm: float
    rough_mm: tuple[float, float, float]
    result: ac.LocalizationResult | None
    decoded: list[tuple[float, str, dict]]
    candump_log: Path
    overlay_png: Path
    alacsd_exit: int | None
    alacsd_log: str
    center_error_mm: float = math.nan
    approach_error_mm: float = math.nan
    acks: list[dict] = dataclasses.field(default_factory=list)
    statuses: list[dict] = dataclasses.field(default_factory=list)


def make_scene(seed: int) -> dict:
    """One apple somewhere the five-stop scan can reach, 1.0-1.4 m away."""
    rng = random.Random(seed)
    z = rng.uniform(1000.0, 1400.0)
    # Keep the plane's centre stop inside the stroke (the laser sits 100..300 mm right of
    # the camera and crosses the optical axis near 1.2 m at mid-stroke).
    x = rng.uniform(-40.0, 40.0) + (1200.0 - z) * 0.167
    y = rng.uniform(-80.0, 80.0)
    r = rng.uniform(35.0, 45.0)
    return {"seed": seed, "apples": [{"id": 1, "center_mm": [x, y, z], "radius_mm": r}]}


def _wait(bus: can.BusABC, pred: Callable[[can.Message], bool], timeout_s: float) -> can.Message | None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        msg = bus.recv(timeout=max(0.0, end - time.monotonic()))
        if msg is not None and pred(msg):
            return msg
    return None


def run_exchange(
    workdir: Path,
    alacsd: Path,
    seed: int = 7,
    iface: str | None = None,
    gpio_chip: str | None = None,
    node_id: int = ac.DEFAULT_NODE_ID,
    say: Callable[[str], None] = lambda s: None,
    rough_error_mm: float = 15.0,
    mode: str = "STOP_AND_GO",
    extra_args: tuple[str, ...] = (),
    scene_extra: dict | None = None,
) -> Exchange:
    iface = iface or os.environ.get("ALACS_CAN_IFACE", "vcan0")
    gpio_chip = gpio_chip if gpio_chip is not None else os.environ.get("ALACS_GPIO_CHIP", "")
    workdir.mkdir(parents=True, exist_ok=True)
    scene = {**make_scene(seed), **(scene_extra or {})}  # e.g. the light and the laser
    scene_path = workdir / "scene.json"
    scene_path.write_text(json.dumps(scene, indent=2))
    apple = scene["apples"][0]
    c = apple["center_mm"]
    r = apple["radius_mm"]
    norm = math.sqrt(sum(v * v for v in c))
    approach = tuple(v - r * v / norm for v in c)
    rng = random.Random(seed + 1000)
    rough = tuple(v + rng.uniform(-rough_error_mm, rough_error_mm) for v in c)

    # Decode with the committed DBC, as an integrator would (other node ids: the DBC
    # that alacs_can writes for them).
    node_db = (cantools.database.load_file(str(DBC)) if node_id == ac.DEFAULT_NODE_ID
               else ac.load_database(node_id))
    log_path = workdir / "candump.log"
    dump = subprocess.Popen(["candump", "-L", iface], stdout=log_path.open("w"), stderr=subprocess.DEVNULL)
    cmd = [str(alacsd), "--sim", "--sim-scene", str(scene_path), "--can", iface,
           "--node-id", str(node_id), "--debug-dir", str(workdir)]
    if gpio_chip:
        cmd += ["--gpio-chip", gpio_chip]
    cmd += list(extra_args)
    say("$ " + " ".join(cmd))
    bus = can.Bus(interface="socketcan", channel=iface, receive_own_messages=False)
    daemon = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    decoded: list[tuple[float, str, dict]] = []
    collector = ac.ResultCollector(node_db)
    ex = Exchange(tuple(c), approach, r, rough, None, decoded, log_path, workdir / "overlay.png", None, "")
    failure = ""

    def note(msg: can.Message) -> None:
        name = ac.message_name(node_db, msg)
        if name is None:
            return
        sig = ac.decode(node_db, msg)
        decoded.append((msg.timestamp, name, sig))
        if name == ac.MSG_ACK:
            ex.acks.append(sig)
        if name == ac.MSG_STATUS:
            ex.statuses.append(sig)

    try:
        hb_id = ac.frame_id(ac.MSG_HEARTBEAT, node_id)
        seen: list[can.Message] = []

        def node_frame(m: can.Message) -> bool:
            # Everything the node sends until its first heartbeat, to report the first one.
            if m.is_extended_id or m.arbitration_id & 0x7F != node_id:
                return False
            seen.append(m)
            note(m)
            return m.arbitration_id == hb_id

        if _wait(bus, node_frame, 20.0) is None:
            raise RuntimeError("no heartbeat from alacsd within 20 s")
        say(describe_start(node_db, seen, node_id))
        status_id = ac.frame_id(ac.MSG_STATUS, node_id)

        def homed(m: can.Message) -> bool:
            if m.arbitration_id != status_id:
                return False
            note(m)
            s = ac.decode(node_db, m, choices=False)
            return bool(s["Homed"]) and int(s["State"]) == int(ac.SensorState.IDLE)

        if _wait(bus, homed, 30.0) is None:
            raise RuntimeError("alacsd did not report IDLE and homed within 30 s")
        say("sensor is IDLE and homed")
        cmd_msg = ac.encode_command(node_db, "LOCALIZE", counter=1, LocalizeMode=mode, TargetId=1,
                                    RoughX=round(rough[0]), RoughY=round(rough[1]), RoughZ=round(rough[2], -1))
        sent_at = time.monotonic()
        bus.send(cmd_msg)
        decoded.append((time.time(), ac.MSG_COMMAND, ac.decode(node_db, cmd_msg)))
        say(f"sent LOCALIZE rough=({rough[0]:.0f}, {rough[1]:.0f}, {rough[2]:.0f}) mm")
        ack_id = ac.frame_id(ac.MSG_ACK, node_id)
        done = False  # LOCALIZE: ACK, then one result
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and not done:
            msg = bus.recv(timeout=0.5)
            if msg is None:
                continue
            note(msg)
            res = collector.push(msg)
            if res is not None:
                ex.result = res
                done = True
            if msg.arbitration_id == ack_id and str(ac.decode(node_db, msg)["AckResult"]) == "NACK":
                done = True
        say(f"exchange took {time.monotonic() - sent_at:.2f} s")
    except RuntimeError as e:
        failure = str(e)
    finally:
        bus.shutdown()
        daemon.send_signal(signal.SIGTERM)
        try:
            out, _ = daemon.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            daemon.kill()
            out, _ = daemon.communicate()
        ex.alacsd_exit = daemon.returncode
        ex.alacsd_log = out
        time.sleep(0.2)
        dump.send_signal(signal.SIGINT)
        dump.wait(timeout=5)
    if failure:
        # What the daemon said is the first thing to read: say it with the failure.
        tail = "\n".join(ex.alacsd_log.splitlines()[-30:])
        raise RuntimeError(f"{failure} (alacsd `{' '.join(cmd)}` exited {ex.alacsd_exit}; its log ends:\n{tail})")
    if ex.result is not None and ex.result.objects and ex.result.objects[0].center_mm is not None:
        o = ex.result.objects[0]
        ex.center_error_mm = math.dist(o.center_mm, ex.truth_center_mm)
        if o.approach_mm is not None:
            ex.approach_error_mm = math.dist(o.approach_mm, ex.truth_approach_mm)
    return ex


def describe_start(db: cantools.database.Database, frames: list[can.Message],
                   node_id: int) -> str:
    """What the node sent first, truthfully: its first frame, and whether a boot-up
    (Heartbeat NmtState BOOTUP, 0x00) was among the frames up to its first heartbeat."""
    if not frames:
        return f"nothing seen from node 0x{node_id:02X}"
    first = frames[0]
    hb_id = ac.frame_id(ac.MSG_HEARTBEAT, node_id)
    if first.arbitration_id == hb_id and first.dlc >= 1 and first.data[0] == int(ac.NmtState.BOOTUP):
        return f"first frame from node 0x{node_id:02X}: its boot-up (Heartbeat NmtState BOOTUP 0x00)"
    name = ac.message_name(db, first) or f"id 0x{first.arbitration_id:03X}"
    try:
        body = ", ".join(f"{k}={v}" for k, v in ac.decode(db, first).items())
    except Exception:  # undecodable: show the bytes instead
        body = bytes(first.data).hex(" ").upper()
    text = f"first frame from node 0x{node_id:02X}: {name} ({body})"
    heartbeats = [m for m in frames if m.arbitration_id == hb_id and m.dlc >= 1]
    if any(m.data[0] == int(ac.NmtState.BOOTUP) for m in heartbeats):
        return text + "; boot-up (NmtState BOOTUP 0x00) seen"
    if heartbeats:
        state = heartbeats[0].data[0]
        try:
            state_name = ac.NmtState(state).name
        except ValueError:
            state_name = "unknown"
        return (text + f"; no boot-up (NmtState BOOTUP 0x00) seen: the first heartbeat was "
                f"NmtState {state_name} (0x{state:02X})")
    return text + "; no heartbeat yet"


def decode_log_with_cantools(log: Path) -> str:
    """`python -m cantools decode alacs.dbc < candump.log`, as an integrator runs it."""
    with log.open() as f:
        out = subprocess.run([sys.executable, "-m", "cantools", "decode", str(DBC)], stdin=f,
                             capture_output=True, text=True, check=True)
    return out.stdout
