#!/usr/bin/env bash
# Inside the UML bench: start udev and initialise the devices the kernel has made, so that
# libcamera's device enumerator (which asks libudev) sees the vimc camera. Without it
# libcamera lists no camera although /dev/media0 and /dev/video* exist
# (../shared/notes/vimc-uml.md). Idempotent; for tests that need the camera
# (tests/system/test_camera_vimc.py, tests/hil/test_bench_smoke.py).
#
# Usage: tests/hil/start_udev.sh      Exit 0 once udev has settled; 1 otherwise.
set -euo pipefail

[[ ${ALACS_IN_UML:-} == 1 ]] || {
    echo "start_udev.sh: only inside the bench (tests/hil/run_in_uml.sh)" >&2
    exit 1
}
udevd=/lib/systemd/systemd-udevd
[[ -x $udevd ]] || {
    echo "start_udev.sh: $udevd missing: apt-get install udev" >&2
    exit 1
}
if ! udevadm control --ping -t 2 >/dev/null 2>&1; then
    # The host's rules, but /run (udev's database) is the bench's own tmpfs.
    "$udevd" --daemon
    for _ in $(seq 50); do
        udevadm control --ping -t 1 >/dev/null 2>&1 && break
        sleep 0.1
    done
fi
udevadm trigger --action=add
udevadm settle -t 30
