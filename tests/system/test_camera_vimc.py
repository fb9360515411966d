"""The camera path through a real libcamera pipeline (issue 18): the kernel's vimc camera
inside the UML bench, libcamera 0.0.3's vimc pipeline handler and IPA, and the daemon's own
libcamera source (edge/drivers/libcamera), first alone (alacs_camera_probe) and then in
alacsd on the hardware platform (real gpio-sim lines, real vcan0, the vimc camera).

vimc shows a test pattern, not our scene: these tests check the pipeline's mechanics
(format, size, buffers, controls, timestamps, cancellation, unbind and recovery, memory).
Accuracy stays with the replay and simulator tests.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import time
from pathlib import Path

import alacs_can as ac
import gpio_sim
import pytest
from sensor import Sensor

ROOT = Path(__file__).resolve().parents[2]
START_UDEV = ROOT / "tests" / "hil" / "start_udev.sh"
VIMC_DEVICE = "vimc.0"
VIMC_DRIVER = Path("/sys/bus/platform/drivers/vimc")
# The size asked of vimc. Small enough for the bench's software-rendered test pattern to
# keep a useful frame rate under UML; the calibration below is scaled to it. Both sides
# are multiples of 3: libcamera 0.0.3 drives the vimc scaler at 3x (the sensor at 256x192).
WIDTH_PX, HEIGHT_PX = 768, 576


@pytest.fixture(scope="module")
def vimc() -> str:
    """Starts udev (libcamera's enumerator needs it) and returns the camera's id."""
    if not Path("/dev/media0").exists():
        pytest.fail("no /dev/media0: the bench kernel lacks CONFIG_VIDEO_VIMC (tests/hil/uml_kernel.sh)")
    subprocess.run([str(START_UDEV)], check=True, timeout=60)
    out = subprocess.run(["cam", "-l"], capture_output=True, text=True, timeout=60)
    m = re.search(r"^\d+: .*\((\S+ Sensor B)\)", out.stdout, re.M)
    assert m, f"cam -l lists no vimc camera:\n{out.stdout}\n{out.stderr}"
    return m.group(1)


@pytest.fixture(scope="module")
def probe() -> Path:
    default = ROOT / "build" / "release" / "tools" / "camera_probe" / "alacs_camera_probe"
    path = Path(os.environ.get("ALACS_CAMERA_PROBE", default))
    if not path.exists():
        pytest.fail(f"alacs_camera_probe not built at {path} (set ALACS_CAMERA_PROBE)")
    return path


def run_probe(probe: Path, *args: str, timeout: float = 300) -> tuple[int, dict | None, str]:
    r = subprocess.run([str(probe), "--width", str(WIDTH_PX), "--height", str(HEIGHT_PX), *args],
                       capture_output=True, text=True, timeout=timeout)
    try:
        report = json.loads(r.stdout)
    except json.JSONDecodeError:
        report = None
    return r.returncode, report, r.stderr


def cam_controls(camera_id: str) -> str:
    """libcamera's own view of the camera's controls (`cam --list-controls`)."""
    r = subprocess.run(["cam", "-c", camera_id, "--list-controls"], capture_output=True, text=True, timeout=60)
    return r.stdout


def test_1000_frames_format_exposure_timestamps_memory(vimc, probe) -> None:
    rc, rep, err = run_probe(probe, "--frames", "1000", "--exposure-us", "3000", "--timeout-ms", "2000")
    assert rc == 0 and rep is not None, err
    print("\nvimc probe: " + json.dumps({k: rep[k] for k in (
        "camera_id", "pixel_format", "width_px", "height_px", "stride_bytes", "buffers", "frames_captured",
        "exposure_control", "exposure_requested_us", "exposure_applied_us", "sensor_timestamp",
        "frame_interval_median_ms", "timeouts", "failed_frames", "stale_frames_skipped",
        "rss_after_first_mb", "rss_end_mb")}))
    # A format the LLE reads, at exactly the size asked for.
    assert rep["camera_id"] == vimc
    assert rep["pixel_format"] in ("RGB888", "BGR888")
    assert (rep["width_px"], rep["height_px"]) == (WIDTH_PX, HEIGHT_PX)
    assert rep["stride_bytes"] >= 3 * WIDTH_PX
    # Every frame, none dropped or failed; every capture ended the laser, and every time the
    # laser went on it went off (more than once a capture when a frame came off the clock).
    assert rep["frames_captured"] == 1000 and rep["capture_failures"] == []
    assert rep["timeouts"] == 0 and rep["failed_frames"] == 0
    assert rep["exposure_end_callbacks"] >= 1000
    assert rep["laser_switched_on"] >= 1000 and rep["laser_switched_off"] == rep["laser_switched_on"]
    # The sensor's timestamps: strictly increasing, spaced by its frame period.
    assert rep["timestamps_increasing"]
    assert rep["frame_interval_median_ms"] > 1.0
    # The exposure: applied through the control when the camera has it (and read back from
    # the metadata), reported as not applied when it has not. libcamera's own tool decides.
    has_exposure = "ExposureTime" in cam_controls(vimc)
    assert rep["exposure_control"] == has_exposure
    assert rep["exposure_requested_us"] == 3000
    if has_exposure:
        assert rep["exposure_applied_us"] is not None and abs(rep["exposure_applied_us"] - 3000) <= 100
    else:
        assert rep["exposure_applied_us"] is None
    # Buffers reused: resident memory flat from frame 100 to frame 1000 (one 640x480 frame
    # is 1.3 MB; a leak of one buffer per frame would add 800 MB).
    assert rep["rss_end_mb"] - rep["rss_after_first_mb"] < 1.0, rep


def test_a_size_the_camera_cannot_give_is_refused_with_what_it_offers(vimc, probe) -> None:
    r = subprocess.run([str(probe), "--width", "9000", "--height", "7000", "--frames", "1"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    assert "unsupported" in r.stderr and "9000x7000" in r.stderr and "offers" in r.stderr, r.stderr


def test_interrupt_cancels_the_request_in_flight(vimc, probe) -> None:
    # Every second capture is interrupted 2 ms after it starts, with a 5 s timeout: one that
    # ends by the interruption must return at once, and the next capture must work.
    rc, rep, err = run_probe(probe, "--frames", "40", "--interrupt-every", "2", "--interrupt-delay-us", "2000",
                             "--timeout-ms", "5000")
    assert rc == 0 and rep is not None, err
    it = rep["interrupts"]
    print(f"\nvimc interrupts: {it}")
    assert it["landed_in_flight"] >= 1, it
    assert it["landed_in_flight"] == rep["interrupted"]
    assert it["median_return_ms"] < 500, it
    assert it["next_capture_failed"] == 0


# The laser on the frame clock (docs/daemon.md "The laser and the frame clock"). vimc makes
# its frames in a kernel thread that holds the bench's only CPU while it does (about 10 ms
# a frame at 768x576, under UML): a thread that must wake just before a frame starts waits
# for it. So this test asks for a smaller frame, and a lead and a jitter tolerance that the
# bench can keep; the shipped 1 ms and 300 us are for a board's sensor.
LASER_SIZE = ("--width", "384", "--height", "288", "--window-rows", "60")
LASER_BENCH = ("--laser-lead-us", "4000", "--frame-clock-jitter-us", "1000")


def assert_clock_misses_bounded(rep: dict) -> None:
    """A clock the frames do not keep to costs a capture one miss, then the laser is on from
    the request: at most two pulses a capture (docs/daemon.md). Unbounded, a CI run's clock
    that missed every frame pulsed the laser 919 times for 59 frames and timed a capture
    out after 2 s."""
    assert rep["frame_clock_misses"] <= rep["frames_asked"], rep
    assert rep["laser_switched_on"] <= 2 * rep["frames_asked"] + rep["reopens"], rep


def test_the_laser_is_switched_on_the_sensors_frame_clock(vimc, probe) -> None:
    """The frame clock learnt from vimc's real timestamps through libcamera: the laser goes on
    just before the predicted frame and off once it is exposed, instead of from the request
    to the delivery; every frame delivered began exposing with the laser on."""
    common = ("--frames", "100", "--exposure-us", "3000", "--timeout-ms", "2000", *LASER_SIZE)
    r = subprocess.run([str(probe), *common, "--laser-timing", "request"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    request = json.loads(r.stdout)
    r = subprocess.run([str(probe), *common, "--laser-timing", "frame-clock", *LASER_BENCH], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    clocked = json.loads(r.stdout)
    keys = ("frames_captured", "frame_interval_median_ms", "frame_period_us", "frame_jitter_us",
            "frames_on_frame_clock", "frame_clock_misses", "frame_clock_finer_grids", "laser_on_per_frame_median_ms",
            "laser_on_per_frame_on_clock_median_ms", "prediction_error_median_us", "prediction_error_max_us",
            "frames_laser_did_not_cover")
    print("\nvimc laser from the request: " + json.dumps({k: request[k] for k in keys}))
    print("vimc laser on the frame clock: " + json.dumps({k: clocked[k] for k in keys}))
    for rep in (request, clocked):
        assert rep["frames_captured"] == 100 and rep["capture_failures"] == [], rep
        assert rep["frames_laser_did_not_cover"] == 0, rep
        assert_clock_misses_bounded(rep)
    assert request["frames_on_frame_clock"] == 0
    # The clock is learnt from the pipeline's timestamps and used for many frames. How many
    # depends on the bench's load, not on the product: the rest are frames after the
    # capturing thread woke late, or while the clock learns again after vimc's kernel thread
    # stamped two frames in a row late (82-95 of 100 on a quiet machine, 48 on a loaded CI
    # runner before one late frame was tolerated; since, 88-93 half-loaded, 34 beside a
    # two-job build). Without the clock it is 0.
    assert clocked["frames_on_frame_clock"] >= 20, clocked
    # The frame delivered is the one predicted: typically well within the lead (20-40 us
    # quiet, 230 us loaded). Every frame accepted was lit throughout (checked above), which
    # is what a late one must not break.
    assert clocked["prediction_error_median_us"] <= 1000, clocked
    # The laser is on for a fraction of what it was: 7.1-7.7 ms against 19.7-19.9 in quiet
    # and half-loaded runs; 11.0 against 19.8 beside a two-job build, where vimc completes
    # frames late (on vimc the laser goes off at the frame's completion, just after its
    # timestamp) and more captures re-arm after a late frame.
    assert clocked["laser_on_per_frame_on_clock_median_ms"] < 0.75 * request["laser_on_per_frame_median_ms"], clocked


def test_a_frame_duration_is_asked_and_the_rate_reported(vimc, probe) -> None:
    """camera.frame_duration_us through libcamera: asked as FrameDurationLimits when the camera
    has the control, and the rate the camera runs at reported either way."""
    # (A capture's timeout of 2 s, as the 1000 frames' test: a stall of the bench's guest
    # is not what this test is about; docs/hil.md.)
    r = subprocess.run([str(probe), "--frames", "60", "--frame-duration-us", "33333", "--frame-clock-jitter-us", "3000",
                        "--timeout-ms", "2000", *LASER_SIZE],
                       capture_output=True, text=True, timeout=300)
    # The probe prints its report (capture_failures: each failed capture's error) either way.
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    rep = json.loads(r.stdout)
    print(f"\nvimc frame duration: control {rep['frame_duration_control']}, reported "
          f"{rep['frame_duration_reported_us']}, interval {rep['frame_interval_median_ms']} ms: "
          f"{rep['frame_rate_note']}")
    assert rep["frames_captured"] == 60 and rep["capture_failures"] == [], rep
    assert_clock_misses_bounded(rep)
    period_us = rep["frame_period_us"]
    assert period_us > 0, rep
    if rep["frame_duration_control"]:
        assert rep["frame_duration_asked_us"] == 33333
        # A camera that has the control and a mode that can run at 30 fps runs at it.
        assert abs(period_us - 33333) < 0.02 * 33333, rep["frame_rate_note"]
        assert "as asked" in rep["frame_rate_note"], rep["frame_rate_note"]
    else:
        # vimc (libcamera 0.0.3) has no such control: it keeps its own rate, and the note
        # says the value was not applied, with the period learnt.
        assert rep["frame_duration_asked_us"] == 0
        assert "not applied" in rep["frame_rate_note"], rep["frame_rate_note"]
        assert f"frames every {math.floor(period_us + 0.5)} us" in rep["frame_rate_note"], rep["frame_rate_note"]
    # A value no sensor runs at is refused by the command line with the accepted range.
    r = subprocess.run([str(probe), "--frame-duration-us", "60"], capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "0, or 1000 to 1000000" in r.stderr, r.stderr


def _calibration(tmp: Path) -> Path:
    """The fuzz corpus's valid calibration, its camera scaled to the vimc frame size."""
    cal = json.loads((ROOT / "tests/fuzz/json/corpus/calibration/valid.json").read_text())
    cam = cal["camera"]
    s = WIDTH_PX / cam["width_px"]
    cam.update(width_px=WIDTH_PX, height_px=HEIGHT_PX, fx_px=cam["fx_px"] * s, fy_px=cam["fy_px"] * s,
               cx_px=WIDTH_PX / 2, cy_px=HEIGHT_PX / 2)
    path = tmp / "calibration.json"
    path.write_text(json.dumps(cal))
    return path


def _config(tmp: Path, camera_id: str) -> dict:
    cfg = json.loads((ROOT / "firmware/config/alacsd.json").read_text())
    cfg["calibration"] = str(_calibration(tmp))
    cfg["camera"]["id"] = camera_id
    # vimc is a software camera inside the bench's guest, whose frames stall for up to
    # about a second while the host is busy (docs/hil.md, "Stalls of the bench's camera"):
    # the most retries the daemon takes (11 tries of camera.frame_timeout_ms, 1.65 s), so
    # that a stall costs retries (each counted as a dropped frame), not the scan. The
    # shipped timeout and laser guard are kept.
    cfg["camera"]["retries"] = 10
    return cfg


def _home(sensor: Sensor) -> None:
    """Homing on real lines with no slide: the test closes the HOME switch, then opens it
    once the sensor reports itself homed (normal travel)."""
    gpio_sim.drive_input("END", 0)
    gpio_sim.drive_input("HOME", 1)
    homed = sensor.status(lambda s: s["Homed"] == 1, 60)
    gpio_sim.drive_input("HOME", 0)
    assert homed is not None, "never homed:\n" + sensor.stop_and_log()


def _result(sensor: Sensor, timeout: float) -> dict | None:
    return sensor.recv(lambda n, s: n == ac.MSG_RESULT_HEADER, timeout)


def _unbind(device: str) -> None:
    (VIMC_DRIVER / "unbind").write_text(device)


def _bind(device: str) -> None:
    (VIMC_DRIVER / "bind").write_text(device)
    subprocess.run(["udevadm", "settle", "-t", "30"], check=False, timeout=60)


def test_alacsd_localizes_through_vimc_honestly(tmp_path, alacsd, vimc) -> None:
    cfg = _config(tmp_path, vimc)
    # A frame duration vimc cannot take (it has no FrameDurationLimits): the daemon runs at
    # the camera's rate and says so once it has learnt it.
    cfg["camera"]["frame_duration_us"] = 33333
    # A tolerance for vimc's timestamps on a loaded bench (they scatter by up to a few ms
    # while the host is busy; see LASER_BENCH), so that the clock is learnt within the
    # scan's 8 captures.
    cfg["camera"]["frame_clock_jitter_us"] = 3000
    sensor = Sensor(alacsd, tmp_path, "--debug-dir", str(tmp_path), config=cfg, sim=False)
    try:
        _home(sensor)
        assert sensor.status(lambda s: str(s["State"]) == "IDLE", 30) is not None
        sensor.localize(x=10, y=-20, z=1200)
        ack = sensor.ack("LOCALIZE", 10)
        assert ack is not None and str(ack["AckResult"]) == "ACK", sensor.seen[-5:]
        header = _result(sensor, 120)
        assert header is not None, "no result:\n" + sensor.stop_and_log()
        # A test pattern holds no apple: an honest "not found", never a measurement.
        assert str(header["ResultStatus"]) != "MEASURED", header
        assert header["ObjectCount"] == 0
        print(f"\nalacsd on vimc: {header['ResultStatus']} / {header['ResultReason']}, "
              f"cycle {header['CycleTime']} ms")
        # The full scan ran: each exposure's sensor timestamp (vimc stamps a frame as it is
        # produced) inside one laser pulse, every pulse within laser.max_on_ms. A pulse may
        # hold no exposure: on the frame clock, a frame that came later than predicted (the
        # laser off again for it, and on for the next).
        timeline = json.loads((tmp_path / "laser_timeline.json").read_text())
        edges, exposures = timeline["edges"], timeline["exposures"]
        assert len(exposures) == 7, exposures
        assert [lvl for _, lvl in edges] == [1, 0] * (len(edges) // 2), edges
        pulses = list(zip((t for t, _ in edges[0::2]), (t for t, _ in edges[1::2])))
        assert len(pulses) >= len(exposures)
        for start, _end in exposures:
            assert sum(on <= start <= off for on, off in pulses) == 1, (start, pulses)
        for on, off in pulses:
            assert off - on <= timeline["laser_max_on_ms"] * 1_000_000
        assert gpio_sim.read_output("LASER") == 0
        status = sensor.status(timeout=5)
        assert status is not None and status["DroppedFrames"] == 0, status
    finally:
        assert sensor.stop() == 0, sensor.log
    # Once, when the clock is learnt.
    lines = sensor.log.splitlines()
    rate = [line for line in lines if "frames every" in line]
    print("alacsd on vimc: " + (rate[0] if rate else "no rate logged"))
    assert len(rate) == 1 and "camera.frame_duration_us 33333 not applied" in rate[0], sensor.log
    # Homing learnt the camera's pace from laser-off frames of the real pipeline (a camera
    # that runs free: docs/daemon.md "The camera's pace, learnt at homing"), before the
    # first scan metered; at most CaptureTimes::kFrames of them.
    homing = [i for i, line in enumerate(lines) if "after homing:" in line]
    metering = [i for i, line in enumerate(lines) if "metering:" in line]
    assert len(homing) == 1 and metering and homing[0] < metering[0], sensor.log
    taken = int(re.search(r"after homing: (\d+) laser-off frames", lines[homing[0]]).group(1))
    assert 1 <= taken <= 8, lines[homing[0]]
    learnt_at = "homing" if lines.index(rate[0]) < metering[0] else "the first scan"
    print(f"alacsd on vimc: {lines[homing[0]].split('after homing: ', 1)[1]}; the clock learnt at {learnt_at}")


def test_stop_mid_scan_aborts_at_once_with_the_laser_off(tmp_path, alacsd, vimc) -> None:
    """STOP while the scan exposes through the real pipeline: the capture is interrupted
    (the requests in flight cancelled, not waited for), the result is ABORTED / STOPPED
    within a fraction of a second, the laser is off, and the next scan runs."""
    sensor = Sensor(alacsd, tmp_path, config=_config(tmp_path, vimc), sim=False)
    try:
        _home(sensor)
        sensor.localize(x=10, y=-20, z=1200)
        # The job starts as MOVING, meters (EXPOSING with the laser off, before any move),
        # then moves to its first stop and exposes there: STOP in that exposure, not in a
        # move (a move cut short leaves the slide unhomed, docs/daemon.md). Progress goes
        # out on every change of phase.
        for phase in ("EXPOSING", "MOVING", "EXPOSING"):
            assert sensor.recv(lambda n, s, p=phase: n == ac.MSG_PROGRESS and str(s["ProgressPhase"]) == p, 60), phase
        sent = time.monotonic()
        sensor.send("STOP")
        header = _result(sensor, 10)
        took_ms = (time.monotonic() - sent) * 1000
        assert header is not None, "no result after STOP:\n" + sensor.stop_and_log()
        assert (str(header["ResultStatus"]), str(header["ResultReason"])) == ("ABORTED", "STOPPED"), header
        print(f"\nSTOP to ABORTED result through vimc: {took_ms:.0f} ms")
        assert took_ms < 1000
        assert gpio_sim.read_output("LASER") == 0
        status = sensor.status(timeout=5)
        assert status is not None and status["DroppedFrames"] == 0, status  # an interrupted capture is no drop
        sensor.send("CLEAR_FAULT")
        assert sensor.status(lambda s: str(s["State"]) == "IDLE", 10) is not None
        sensor.localize(x=10, y=-20, z=1200)
        ack = sensor.ack("LOCALIZE", 10)
        assert ack is not None and str(ack["AckResult"]) == "ACK", sensor.seen[-8:]
        again = _result(sensor, 120)
        assert again is not None, f"no result for the scan after STOP ({sensor.seen[-8:]}):\n" + sensor.stop_and_log()
        assert str(again["ResultReason"]) not in ("CAMERA_FAULT", "STOPPED"), again
    finally:
        assert sensor.stop() == 0, sensor.log


def test_camera_unbound_mid_scan_faults_then_recovers(tmp_path, alacsd, vimc) -> None:
    """vimc unbound through sysfs mid-scan: CAMERA_TIMEOUT, FAULT, a FAILED result with
    reason CAMERA_FAULT, laser off. libcamera 0.0.3 cannot take the camera back in the same
    process (it never sees the removal and aborts when the camera returns), so alacsd then
    ends with status 75 for its unit to restart it. Restarted (as systemd would) while the
    camera is still away, it runs and fails scans as camera faults; once the camera is
    back, CLEAR_FAULT and a LOCALIZE run through it again."""
    sensor = Sensor(alacsd, tmp_path, config=_config(tmp_path, vimc), sim=False)
    unbound = False
    try:
        _home(sensor)
        sensor.localize(x=10, y=-20, z=1200)
        # The first exposure, then the camera goes away under the scan.
        first = sensor.recv(lambda n, s: n == ac.MSG_PROGRESS and s["StopsDone"] >= 1, 60)
        assert first is not None, f"no first stop ({sensor.seen[-8:]}):\n" + sensor.stop_and_log()
        _unbind(VIMC_DEVICE)
        unbound = True
        header = _result(sensor, 60)
        assert header is not None, "no result after the unbind:\n" + sensor.stop_and_log()
        assert str(header["ResultStatus"]) == "FAILED" and str(header["ResultReason"]) == "CAMERA_FAULT", header
        fault = sensor.status(lambda s: str(s["State"]) == "FAULT", 10)
        assert fault is not None and fault["FaultCameraTimeout"] == 1, fault
        assert fault["DroppedFrames"] >= 1, fault
        assert gpio_sim.read_output("LASER") == 0
        emcy = [s for n, s in sensor.seen if n == ac.MSG_EMCY]
        assert emcy and any(s["EmcyReason"] != 0 for s in emcy), emcy
        # Then the deliberate exit for a restart, with the reason in the log.
        sensor.proc.wait(timeout=30)
        assert sensor.stop() == 75, sensor.log
        assert "lost (its device was removed)" in sensor.log, sensor.log
        assert gpio_sim.read_output("LASER") == 0
        # The unit's restart, the camera still away: up, homed, scans fail as camera faults.
        again = Sensor(alacsd, tmp_path, config=_config(tmp_path, vimc), sim=False)
        try:
            _home(again)
            again.localize(x=10, y=-20, z=1200)
            header = _result(again, 60)
            assert header is not None and str(header["ResultReason"]) == "CAMERA_FAULT", header
            # The camera comes back; CLEAR_FAULT; the next LOCALIZE runs through it.
            _bind(VIMC_DEVICE)
            unbound = False
            # libcamera inside alacsd learns of the camera from udev's event, on its own
            # thread: wait for that (a scan that opens it), not for a fixed time. Each try is
            # CLEAR_FAULT, then a LOCALIZE whose result says whether the camera opened.
            deadline = time.monotonic() + 30
            while True:
                again.send("CLEAR_FAULT")
                assert again.status(lambda s: str(s["State"]) == "IDLE", 10) is not None
                again.localize(x=10, y=-20, z=1200)
                header = _result(again, 120)
                assert header is not None, "no result:\n" + again.stop_and_log()
                if str(header["ResultReason"]) != "CAMERA_FAULT" or time.monotonic() > deadline:
                    break
            assert str(header["ResultReason"]) != "CAMERA_FAULT", header
            assert gpio_sim.read_output("LASER") == 0
        finally:
            assert again.stop() == 0, again.log
        assert "camera opened" in again.log, again.log
    finally:
        if unbound:
            _bind(VIMC_DEVICE)
        sensor.stop()


def test_a_size_vimc_cannot_give_is_refused_at_start_and_faults_the_scan(tmp_path, alacsd, vimc) -> None:
    """A calibration for a size this camera cannot give (vimc's sides are multiples of 3):
    the camera is refused at start with the reason in the log, and the daemon stays up
    (no restart loop): a LOCALIZE is ACKed and fails as a camera fault, laser off."""
    cfg = _config(tmp_path, vimc)
    cal = json.loads(Path(cfg["calibration"]).read_text())
    cal["camera"].update(width_px=1000, height_px=750, cx_px=500, cy_px=375)
    Path(cfg["calibration"]).write_text(json.dumps(cal))
    sensor = Sensor(alacsd, tmp_path, config=cfg, sim=False)
    try:
        _home(sensor)
        sensor.localize(x=10, y=-20, z=1200)
        ack = sensor.ack("LOCALIZE", 10)
        assert ack is not None and str(ack["AckResult"]) == "ACK", sensor.seen[-5:]
        header = _result(sensor, 60)
        assert header is not None, "no result:\n" + sensor.stop_and_log()
        assert str(header["ResultStatus"]) == "FAILED" and str(header["ResultReason"]) == "CAMERA_FAULT", header
        fault = sensor.status(lambda s: str(s["State"]) == "FAULT", 10)
        assert fault is not None and fault["FaultCameraTimeout"] == 1, fault
        assert gpio_sim.read_output("LASER") == 0
    finally:
        assert sensor.stop() == 0, sensor.log
    assert re.search(r"cannot give RGB888 or BGR888 at 1000x750 \(it offers .*RGB888", sensor.log), sensor.log
