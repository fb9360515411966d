"""tests/board: the board's tests, run inside the virtual board as the arm controller on can1.

Started by board-harness.service before alacsd.service: it brings can1 (its own
controller, the harness side of the emulated bus) up at 500 kbit/s, starts recording every
frame on can1, tells systemd it is ready, and only then does alacsd start. Each test ends
in one line on /dev/hvc0 (the host's results file, read by tests/board/run.sh):

    board: ok   NAME: detail
    board: FAIL NAME: detail
    board: info NAME: detail        (a measurement or a finding, not a pass/fail check)
    board: figure NAME=VALUE        (the measured figures docs/board.md quotes)

Everything here talks to the real parts: the shipped unit through systemctl, the daemon
through CAN frames on the emulated Kvaser controllers (python-can and the `alacs` CLI),
the LASER line through gpio-sim's sysfs value, the journal through journalctl.
"""

from __future__ import annotations

import functools
import glob
import json
import math
import os
import re
import socket
import subprocess
import sys
import threading
import time
import traceback

import can

NODE = 16
HEARTBEAT_ID = 0x700 + NODE
UNIT = "alacsd.service"
EXPECTED = "/usr/share/alacs-board/expected.json"
BOOTUP_LIMIT_S = float(os.environ.get("BOARD_BOOTUP_LIMIT_S", "120"))  # from power-on, emulated
RESTART_LIMIT_S = 60.0  # kill or watchdog to the new boot-up frame, emulated
LASER_LOW_LIMIT_S = 0.1  # "at once": the line polled after the kill
MAX_EXPOSURE = 1.3  # docs/appliance.md: `systemd-analyze security` 1.3 OK

_out = open("/dev/hvc0", "w", buffering=1) if os.path.exists("/dev/hvc0") else sys.stdout
results = {"passed": 0, "failed": 0}


def report(kind: str, name: str, detail: str = "") -> None:
    line = f"board: {kind:<4} {name}" + (f": {detail}" if detail else "")
    print(line, file=_out, flush=True)
    print(line, flush=True)


def figure(name: str, value: str) -> None:
    print(f"board: figure {name}={value}", file=_out, flush=True)
    print(f"board: figure {name}={value}", flush=True)


def boottime() -> float:
    return time.clock_gettime(time.CLOCK_BOOTTIME)


def sh(*cmd: str, check: bool = False, timeout: float = 120) -> str:
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)}: exit {p.returncode}: {p.stdout}{p.stderr}")
    return p.stdout + p.stderr


def notify(state: str) -> None:
    path = os.environ.get("NOTIFY_SOCKET")
    if not path:
        return
    if path.startswith("@"):
        path = "\0" + path[1:]
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
        s.connect(path)
        s.sendall(state.encode())


# ---------------------------------------------------------------- can1, recorded from the start
sh("ip", "link", "set", "can1", "type", "can", "bitrate", "500000", check=True)
sh("ip", "link", "set", "can1", "up", check=True)
bus = can.Bus(interface="socketcan", channel="can1", receive_own_messages=False)
frames: list[tuple[float, can.Message]] = []  # (CLOCK_BOOTTIME at receipt, frame)
_lock = threading.Lock()


def _reader() -> None:
    while True:
        m = bus.recv(timeout=1.0)
        if m is not None:
            with _lock:
                frames.append((boottime(), m))


threading.Thread(target=_reader, daemon=True).start()
READY_AT = boottime()
notify("READY=1")

# Only now the slow imports (cantools parses the DBC): alacsd is already starting.
import alacs_can as ac  # noqa: E402

DB = ac.load_database(NODE)
STATUS_ID = ac.frame_id(ac.MSG_STATUS, NODE)
ACK_ID = ac.frame_id(ac.MSG_ACK, NODE)
_counter = 0


def snapshot(start: int = 0) -> list[tuple[float, can.Message]]:
    with _lock:
        return frames[start:]


def mark() -> int:
    with _lock:
        return len(frames)


def wait_frame_at(pred, timeout: float, start: int = 0) -> tuple[float, can.Message, int] | None:
    """The first frame from index `start` on that `pred` accepts: (time, frame, index)."""
    end = time.monotonic() + timeout
    seen = start
    while True:
        for t, m in snapshot(seen):
            seen += 1
            if pred(m):
                return t, m, seen - 1
        if time.monotonic() > end:
            return None
        time.sleep(0.02)


def wait_frame(pred, timeout: float, start: int = 0) -> tuple[float, can.Message] | None:
    got = wait_frame_at(pred, timeout, start)
    return None if got is None else (got[0], got[1])


def is_bootup(m: can.Message) -> bool:
    return m.arbitration_id == HEARTBEAT_ID and bytes(m.data) == b"\x00"


def is_heartbeat(m: can.Message) -> bool:
    return m.arbitration_id == HEARTBEAT_ID and len(m.data) == 1 and m.data[0] != 0


def status(m: can.Message) -> dict:
    return ac.decode(DB, m)


def wait_status(pred, timeout: float, start: int | None = None) -> dict | None:
    got = wait_frame(lambda m: m.arbitration_id == STATUS_ID and pred(status(m)), timeout,
                     mark() if start is None else start)
    return None if got is None else status(got[1])


def idle_and_homed(s: dict) -> bool:
    return str(s["State"]) == "IDLE" and s["Homed"] == 1


def send(opcode: str, **signals) -> int:
    global _counter
    _counter = (_counter + 1) % 16
    start = mark()
    bus.send(ac.encode_command(DB, opcode, counter=_counter, **signals))
    return start


def wait_ack(opcode: str, start: int, timeout: float = 10.0) -> dict | None:
    got = wait_frame(lambda m: m.arbitration_id == ACK_ID and str(ac.decode(DB, m)["AckOpcode"]) == opcode,
                     timeout, start)
    return None if got is None else ac.decode(DB, got[1])


@functools.cache
def laser_value_path() -> str:
    for chip in glob.glob("/sys/devices/platform/gpio-sim.*/gpiochip*"):
        return f"{chip}/sim_gpio3/value"  # LASER is line 3 (board-gpio-sim)
    raise AssertionError("no gpio-sim chip")


def laser() -> int:
    with open(laser_value_path()) as f:
        return int(f.read())


def unit_prop(name: str) -> str:
    return sh("systemctl", "show", "-P", name, UNIT).strip()


def journal_since(cursor: str, unit: str | None = UNIT) -> str:
    cmd = ["journalctl", "--no-pager", "-o", "short-monotonic", f"--after-cursor={cursor}"]
    if unit:
        cmd += ["-u", unit]
    return sh(*cmd)


def journal_cursor() -> str:
    out = sh("journalctl", "--no-pager", "-n", "1", "-o", "cat", "--show-cursor")
    m = re.search(r"-- cursor: (\S+)", out)
    assert m, out
    return m.group(1)


def wait_up_again(start: int, timeout: float = RESTART_LIMIT_S) -> tuple[float, float]:
    """After `start`: the new boot-up frame's time, then IDLE-and-homed's."""
    got = wait_frame_at(is_bootup, timeout, start)
    assert got is not None, f"no new boot-up frame within {timeout:.0f} s"
    # From the new boot-up on: the old daemon's last status frames said IDLE too.
    idle = wait_frame(lambda m: m.arbitration_id == STATUS_ID and idle_and_homed(status(m)), 120, got[2])
    assert idle is not None, "not IDLE and homed after the restart"
    return got[0], idle[0]


def clean_restart() -> None:
    """Back to a freshly started, idle sensor, with the start-limit counter reset."""
    sh("systemctl", "reset-failed", UNIT)
    start = mark()
    sh("systemctl", "restart", UNIT, check=True, timeout=180)
    wait_up_again(start)


TESTS = []


def test(fn):
    TESTS.append(fn)
    return fn


# ---------------------------------------------------------------- the tests
@test
def bootup_is_the_first_frame() -> str:
    first = wait_frame(lambda m: True, BOOTUP_LIMIT_S)
    assert first is not None, f"no frame on can1 within {BOOTUP_LIMIT_S:.0f} s"
    t, m = first
    assert is_bootup(m), f"first frame is 0x{m.arbitration_id:03x} {bytes(m.data).hex()}, not the boot-up 0x{HEARTBEAT_ID:03x} 00"
    assert t < BOOTUP_LIMIT_S, f"boot-up at {t:.1f} s after power-on (limit {BOOTUP_LIMIT_S:.0f} s)"
    figure("bootup_s", f"{t:.1f}")
    hb = wait_frame(is_heartbeat, 30)
    assert hb is not None, "no heartbeat after the boot-up frame"
    figure("first_heartbeat_s", f"{hb[0]:.1f}")
    figure("harness_ready_s", f"{READY_AT:.1f}")
    return f"0x{HEARTBEAT_ID:03x} 00 at {t:.1f} s after power-on (emulated; limit {BOOTUP_LIMIT_S:.0f} s), first heartbeat at {hb[0]:.1f} s"


@test
def can0_brought_up_by_networkd() -> str:
    link = sh("ip", "-details", "link", "show", "can0")
    assert "bitrate 500000" in link, link
    assert "state UP" in link or "<NOARP,UP,LOWER_UP" in link, link
    ifindex = int(open("/sys/class/net/can0/ifindex").read())
    state = open(f"/run/systemd/netif/links/{ifindex}").read()
    assert "ADMIN_STATE=configured" in state, state
    assert "NETWORK_FILE=/usr/lib/systemd/network/80-can0.network" in state, state
    return "can0 at 500000 bit/s, configured by systemd-networkd from /usr/lib/systemd/network/80-can0.network"


@test
def heartbeat_period() -> str:
    period = json.load(open("/etc/alacs/alacsd.json"))["can"]["heartbeat_ms"] / 1000.0
    start = mark()
    time.sleep(8 * period + 0.5)
    ts = [t for t, m in snapshot(start) if is_heartbeat(m)]
    assert len(ts) >= 6, f"{len(ts)} heartbeats in {8 * period + 0.5:.1f} s"
    gaps = [b - a for a, b in zip(ts, ts[1:])]
    mean = sum(gaps) / len(gaps)
    assert abs(mean - period) < 0.05 * period, f"mean period {mean * 1000:.0f} ms, configured {period * 1000:.0f} ms"
    assert all(abs(g - period) < 0.3 * period for g in gaps), f"gaps {[round(g * 1000) for g in gaps]} ms"
    return f"{len(gaps)} gaps, mean {mean * 1000:.0f} ms (configured {period * 1000:.0f} ms), range {min(gaps) * 1000:.0f}..{max(gaps) * 1000:.0f} ms"


@test
def cli_version_and_status() -> str:
    out = sh("alacs", "--channel", "can1", "--json", "version", timeout=60)
    assert '"type"' in out and "version" in out.lower(), out
    st = sh("alacs", "--channel", "can1", "--json", "status", timeout=60)
    assert '"State"' in st or '"state"' in st, st
    return "alacs version / status answered: " + out.strip().splitlines()[-1][:160]


@test
def localize_matches_x86() -> str:
    exp = json.load(open(EXPECTED))
    rough = exp["rough_mm"]
    assert wait_status(idle_and_homed, 60) is not None, "not IDLE and homed"
    x, y, z = (str(round(v)) for v in rough)  # whole mm, as the command carries them
    p = subprocess.run(["alacs", "--channel", "can1", "--json", "localize", "--x", x, "--y", y, "--z", z,
                        "--timeout", "400"], capture_output=True, text=True, timeout=500)
    res = [json.loads(ln) for ln in p.stdout.splitlines() if ln.startswith("{") and '"result"' in ln]
    assert res, f"no result (exit {p.returncode}): {p.stdout[-1500:]} {p.stderr[-1500:]}"
    r = res[-1]
    assert r["status"] == "MEASURED", r
    obj = r["objects"][0]
    d = math.dist(obj["center_mm"], exp["center_mm"])
    figure("localize_cycle_ms", f"{r['cycle_time_ms']:g}")
    # Same frames, same recorded positions, same code: equal to the CAN encoding's resolution.
    assert d < 0.6, f"board centre {obj['center_mm']} vs x86 {exp['center_mm']}: {d:.2f} mm apart"
    dd = abs(obj["quality"]["diameter_mm"] - exp["diameter_mm"])
    assert dd < 1.0, f"diameter {obj['quality']['diameter_mm']} vs x86 {exp['diameter_mm']}"
    return (f"centre {[round(v, 1) for v in obj['center_mm']]} mm vs x86 {[round(v, 1) for v in exp['center_mm']]} "
            f"({d:.2f} mm apart), diameter {obj['quality']['diameter_mm']} vs {exp['diameter_mm']:.1f} mm, "
            f"cycle {r['cycle_time_ms']:g} ms emulated")


@test
def security_exposure() -> str:
    out = sh("systemd-analyze", "security", "--no-pager", UNIT)
    m = re.search(r"Overall exposure level for alacsd\.service: ([0-9.]+)", out)
    assert m, out[-2000:]
    score = float(m.group(1))
    figure("security_exposure", f"{score}")
    assert score <= MAX_EXPOSURE, f"exposure {score} > {MAX_EXPOSURE} (docs/appliance.md)"
    return f"{score} on the running board (docs: {MAX_EXPOSURE})"


@test
def own_unprivileged_user_and_devices() -> str:
    pid = int(unit_prop("MainPID"))
    assert pid > 0, "alacsd not running"
    st = open(f"/proc/{pid}/status").read()
    uid = int(re.search(r"^Uid:\s+(\d+)", st, re.M).group(1))
    groups = set(re.search(r"^Groups:\s*(.*)$", st, re.M).group(1).split())
    caps = {k: v for k, v in re.findall(r"^(Cap(?:Inh|Prm|Eff|Bnd|Amb)):\s+(\S+)", st, re.M)}
    assert 61184 <= uid <= 65519, f"uid {uid} is not a DynamicUser uid"
    user = sh("id", "-nu", str(uid)).strip()
    gpio = sh("getent", "group", "gpio").split(":")[2]
    video = sh("getent", "group", "video").split(":")[2]
    assert {gpio, video} <= groups, f"groups {groups}, want gpio {gpio} and video {video}"
    assert all(int(v, 16) == 0 for v in caps.values()), caps
    # The devices it holds: only the GPIO chip (through the udev rule's group), and its CAN
    # socket bound to can0 (each socket fd duplicated here with pidfd_getfd and asked).
    devs, can_ifaces = set(), set()
    pids = [pid] + [int(p) for p in sh("pgrep", "-P", str(pid)).split()]
    for p in pids:
        pidfd = os.pidfd_open(p)
        try:
            for fd in glob.glob(f"/proc/{p}/fd/*"):
                try:
                    target = os.readlink(fd)
                except OSError:
                    continue
                if target.startswith("/dev/"):
                    devs.add(target)
                if target.startswith("socket:"):
                    family, name = _socket_of(pidfd, int(fd.rsplit("/", 1)[1]))
                    if family == socket.AF_CAN:
                        can_ifaces.add(name)
        finally:
            os.close(pidfd)
    # The pseudo-devices DevicePolicy=closed always allows (stdin is /dev/null) aside, only
    # GPIO chips.
    chips = devs - {"/dev/null", "/dev/zero", "/dev/full", "/dev/random", "/dev/urandom"}
    assert chips and all(re.fullmatch(r"/dev/gpiochip\d+", d) for d in chips), f"devices open: {devs}"
    devs = chips
    for d in devs:
        s = os.stat(d)
        assert s.st_gid == int(gpio) and (s.st_mode & 0o777) == 0o660, f"{d}: gid {s.st_gid} mode {oct(s.st_mode)}"
    assert "can0" in can_ifaces, f"CAN sockets bound to {can_ifaces or 'nothing'}"
    return (f"uid {uid} ({user}), groups gpio {gpio} + video {video}, all capability sets 0, devices open "
            f"{sorted(devs)} (group gpio, 0660, the udev rule), CAN raw socket bound to can0")


def _socket_of(pidfd: int, fd: int) -> tuple[int, str]:
    """(address family, interface name for AF_CAN) of another process's socket fd: the fd
    duplicated with pidfd_getfd(2), then getsockname(2) on the copy."""
    import ctypes
    libc = ctypes.CDLL(None, use_errno=True)
    SYS_pidfd_getfd = 438  # the same number on arm64 and x86-64 (the generic table)
    mine = libc.syscall(SYS_pidfd_getfd, pidfd, fd, 0)
    if mine < 0:
        raise AssertionError(f"pidfd_getfd: errno {ctypes.get_errno()}")
    try:
        buf = ctypes.create_string_buffer(128)
        size = ctypes.c_uint32(128)
        if libc.getsockname(mine, buf, ctypes.byref(size)) != 0:
            return -1, f"getsockname errno {ctypes.get_errno()}"
        family = int.from_bytes(buf.raw[0:2], "little")
        if family != socket.AF_CAN:
            return family, ""
        # struct sockaddr_can: sa_family_t can_family; int can_ifindex; ...
        ifindex = int.from_bytes(buf.raw[4:8], "little", signed=True)
        return family, socket.if_indextoname(ifindex) if ifindex > 0 else "any"
    finally:
        os.close(mine)


@test
def kill_mid_scan_laser_low_restart_bootup() -> str:
    exp = json.load(open(EXPECTED))
    rough = exp["rough_mm"]
    assert wait_status(idle_and_homed, 60) is not None, "not IDLE and homed"
    restarts = int(unit_prop("NRestarts"))
    cursor = journal_cursor()
    send("LOCALIZE", LocalizeMode="STOP_AND_GO", TargetId=1, RoughX=round(rough[0]), RoughY=round(rough[1]),
         RoughZ=round(rough[2], -1))
    # Mid-scan: the kill goes out as soon as the LASER line is seen high (polled without
    # sleeping). A replayed exposure is over at once (replay_source.cpp), so the line may
    # already be low again when systemctl's SIGKILL lands; the level read just before is
    # reported.
    end = time.monotonic() + 120
    while laser() != 1:
        assert time.monotonic() < end, "the laser never came on during the scan"
    high_before = laser()
    start = mark()
    sh("systemctl", "kill", "-s", "KILL", UNIT, check=True)
    # systemctl returns once systemd has sent the signals: from here the line must be low.
    t0 = time.monotonic()
    high_after_kill = laser()
    while laser() != 0:
        assert time.monotonic() - t0 < 5, "LASER still high 5 s after the kill"
        time.sleep(0.001)
    low_s = time.monotonic() - t0
    assert low_s < LASER_LOW_LIMIT_S, f"LASER low only {low_s * 1000:.0f} ms after the kill"
    tb0 = boottime()
    t_boot, t_idle = wait_up_again(start)
    assert int(unit_prop("NRestarts")) == restarts + 1, f"NRestarts {unit_prop('NRestarts')}, was {restarts}"
    figure("kill_to_bootup_s", f"{t_boot - tb0:.1f}")
    figure("kill_to_idle_s", f"{t_idle - tb0:.1f}")
    # ExecStopPost=alacsd --laser-off ran after the kill (its output is the unit's).
    log = journal_since(cursor)
    global _kill_log
    _kill_log = log
    return (f"LASER high seen mid-scan (level {high_before} just before systemctl kill, {high_after_kill} when it "
            f"returned), low {low_s * 1000:.0f} ms after (limit {LASER_LOW_LIMIT_S * 1000:.0f} ms), "
            f"restarted by systemd (NRestarts {restarts}->{restarts + 1}), new boot-up {t_boot - tb0:.1f} s after the kill")


_kill_log = ""


@test
def execstoppost_laser_off_after_kill() -> str:
    assert _kill_log, "the kill test did not run"
    assert "laser off: ok" in _kill_log, "no 'laser off: ok' from ExecStopPost after the kill:\n" + _kill_log[-2500:]
    line = next(ln for ln in _kill_log.splitlines() if "laser off: ok" in ln)
    return "journal: " + line.strip()[:200]


@test
def sigstop_watchdog_restart() -> str:
    assert wait_status(idle_and_homed, 60) is not None, "not IDLE and homed"
    restarts = int(unit_prop("NRestarts"))
    cursor = journal_cursor()
    start = mark()
    tb0 = boottime()
    sh("systemctl", "kill", "--kill-who=main", "-s", "STOP", UNIT, check=True)
    t_boot, _ = wait_up_again(start, timeout=5 + 10 + 2 + RESTART_LIMIT_S)
    log = journal_since(cursor)
    assert re.search(r"alacsd\.service: Watchdog timeout", log), "no watchdog timeout in the journal:\n" + log[-2500:]
    assert "Scheduled restart job" in log, log[-2500:]
    assert int(unit_prop("NRestarts")) == restarts + 1
    figure("sigstop_to_bootup_s", f"{t_boot - tb0:.1f}")
    wd = next(ln for ln in log.splitlines() if "Watchdog timeout" in ln)
    return f"new boot-up {t_boot - tb0:.1f} s after SIGSTOP (WatchdogSec=5s); journal: {wd.strip()[:160]}"


@test
def corrupt_calibration_stays_up_nacks_and_says_why() -> str:
    path = "/var/lib/alacs/calibration.json"
    good = open(path).read()
    cursor = journal_cursor()
    try:
        with open(path, "w") as f:
            f.write('{"format": "alacs-calibration/1", "camera": ')  # truncated: a parse error
        clean_restart()
        st = wait_status(lambda s: True, 10)
        assert st is not None
        assert st["Calibrated"] == 0 and st["FaultNotCalibrated"] == 1, {k: st[k] for k in ("Calibrated", "FaultNotCalibrated")}
        start = send("LOCALIZE", LocalizeMode="STOP_AND_GO", TargetId=1, RoughX=0, RoughY=0, RoughZ=1200)
        ack = wait_ack("LOCALIZE", start)
        assert ack is not None, "no ack to LOCALIZE"
        assert (str(ack["AckResult"]), str(ack["NackReason"])) == ("NACK", "NOT_CALIBRATED"), ack
        assert unit_prop("ActiveState") == "active", unit_prop("ActiveState")
        time.sleep(2)
        assert unit_prop("ActiveState") == "active" and int(unit_prop("MainPID")) > 0
        log = journal_since(cursor)
        reason = [ln for ln in log.splitlines() if "calibration" in ln.lower()]
        assert reason, log[-2000:]
    finally:
        with open(path, "w") as f:
            f.write(good)
        clean_restart()
    return f"active, Status Calibrated=0 FaultNotCalibrated=1, LOCALIZE NACK NOT_CALIBRATED; journal: {reason[0].strip()[:160]}"


@test
def corrupt_config_stays_up_nacks_and_says_why() -> str:
    # docs/daemon.md: a refused configuration file leaves alacsd up on its built-in defaults,
    # CONFIG_INVALID in its status, HOME and scans NACKed FAULT_ACTIVE, the key in the journal.
    path = "/etc/alacs/alacsd.json"
    good = open(path).read()
    cfg = json.loads(good)
    cfg["scan"]["stops"] = 40
    cursor = journal_cursor()
    try:
        with open(path, "w") as f:
            json.dump(cfg, f)
        # Not clean_restart(): that waits for an idle, homed sensor, and this one must not home.
        sh("systemctl", "reset-failed", UNIT)
        sh("systemctl", "restart", UNIT, check=True, timeout=180)
        st = wait_status(lambda s: s["FaultConfigInvalid"] == 1, 60)
        assert st is not None, "no status with FaultConfigInvalid"
        start = send("LOCALIZE", LocalizeMode="STOP_AND_GO", TargetId=1, RoughX=0, RoughY=0, RoughZ=1200)
        ack = wait_ack("LOCALIZE", start)
        assert ack is not None, "no ack to LOCALIZE"
        assert (str(ack["AckResult"]), str(ack["NackReason"])) == ("NACK", "FAULT_ACTIVE"), ack
        time.sleep(2)
        assert unit_prop("ActiveState") == "active" and int(unit_prop("MainPID")) > 0
        assert laser() == 0
        log = journal_since(cursor)
        assert "scan.stops" in log, log[-2000:]
        line = next(ln for ln in log.splitlines() if "scan.stops" in ln)
    finally:
        with open(path, "w") as f:
            f.write(good)
        clean_restart()
    return f"active, Status FaultConfigInvalid=1, LOCALIZE NACK FAULT_ACTIVE; journal: {line.strip()[:160]}"


@test
def fifo_dropin_under_shipped_filter() -> str:
    """Issue 15: does a CPUSchedulingPolicy=fifo drop-in work under the shipped unit's
    SystemCallFilter (and RestrictRealtime=yes)? Reported as found, not a pass/fail check
    of the product: the drop-in is not shipped."""
    dropin = "/run/systemd/system/alacsd.service.d"
    os.makedirs(dropin, exist_ok=True)
    with open(f"{dropin}/90-fifo.conf", "w") as f:
        f.write("[Service]\nCPUSchedulingPolicy=fifo\nCPUSchedulingPriority=50\n")
    cursor = journal_cursor()
    try:
        sh("systemctl", "daemon-reload", check=True)
        sh("systemctl", "reset-failed", UNIT)
        start = mark()
        sh("systemctl", "restart", UNIT, timeout=180)
        got = wait_frame(is_bootup, RESTART_LIMIT_S, start)
        pid = int(unit_prop("MainPID") or 0)
        policy = sh("chrt", "-p", str(pid)) if pid else "no MainPID"
        guard = sh("pgrep", "-P", str(pid)).split() if pid else []
        gpolicy = sh("chrt", "-p", guard[0]) if guard else "no guard process"
        log = journal_since(cursor)
        found = (f"unit {unit_prop('ActiveState')}/{unit_prop('SubState')}, boot-up {'seen' if got else 'NOT seen'}; "
                 f"main: {' '.join(policy.split())}; guard: {' '.join(gpolicy.split())}")
        errs = [ln.strip() for ln in log.splitlines() if re.search(r"sched|realtime|fifo|priorit|EPERM|Operation not permitted", ln, re.I)]
        report("info", "fifo_dropin", found + ("; journal: " + " | ".join(errs[:4]) if errs else ""))
    finally:
        os.remove(f"{dropin}/90-fifo.conf")
        sh("systemctl", "daemon-reload", check=True)
        clean_restart()
    return "reported above (info fifo_dropin); the shipped unit restored"


def main() -> int:
    only = os.environ.get("BOARD_TESTS", "")
    for fn in TESTS:
        if only and fn.__name__ not in only.split(","):
            continue
        t = time.monotonic()
        try:
            detail = fn()
            results["passed"] += 1
            report("ok", fn.__name__, f"{detail} [{time.monotonic() - t:.1f} s]")
        except Exception as e:  # noqa: BLE001 - every failure is reported, then the next test runs
            results["failed"] += 1
            msg = str(e) if isinstance(e, AssertionError) else "".join(traceback.format_exception(e))[-1500:]
            report("FAIL", fn.__name__, msg.replace("\n", "\n    ") + f" [{time.monotonic() - t:.1f} s]")
    print(f"board: done {results['passed']} passed, {results['failed']} failed", file=_out, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
