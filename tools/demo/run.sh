#!/usr/bin/env bash
# The demo: installs what is missing, builds alacsd, boots the UML bench (real vcan0
# and gpio-sim) and runs one localization over CAN against the simulated scene.
# Output: the decoded CAN exchange, the apple beside the truth, out/demo/overlay.png.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root"
tools/bootstrap.sh
echo "demo: building alacsd (Release)" >&2
cmake -S . -B build/release -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
ninja -C build/release alacsd >/dev/null
echo "demo: preparing the UML bench kernel (built once, then cached)" >&2
tests/hil/uml_kernel.sh >/dev/null
exec tests/hil/run_in_uml.sh --timeout 300 -- .venv/bin/python tools/demo/demo.py "$@"
