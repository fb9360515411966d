#!/usr/bin/env bash
# The demo: installs what is missing, builds alacsd, boots the UML bench (real vcan0
# and gpio-sim) and runs one localization over CAN against the simulated scene.
# Output: the decoded CAN exchange, the apple beside the truth, out/demo/overlay.png.
# The install, build and kernel steps print one line each; their output goes to
# out/demo-logs/*.log and is shown only when a step fails.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root"
source tools/demo/quiet.sh
logs=out/demo-logs
quiet_step "installing dependencies (tools/bootstrap.sh)" "$logs/install.log" tools/bootstrap.sh
quiet_step "configuring alacsd (Release)" "$logs/cmake.log" \
    cmake -S . -B build/release -G Ninja -DCMAKE_BUILD_TYPE=Release
quiet_step "building alacsd" "$logs/ninja.log" ninja -C build/release alacsd
quiet_step "preparing the UML bench kernel (built once, then cached)" "$logs/uml_kernel.log" \
    tests/hil/uml_kernel.sh
exec tests/hil/run_in_uml.sh --timeout 300 -- .venv/bin/python tools/demo/demo.py "$@"
