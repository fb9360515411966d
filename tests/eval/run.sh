#!/usr/bin/env bash
# CI for the twin's evaluation and scan directories (issue 3). Called from tests/run:
#   tests/eval/run.sh [--junit-dir DIR]
# 1. builds alacsd, alacs-twin, alacs_calibrate, alacs_geometry_eval and alacs_cycle (build/release, as
#    tests/run builds the daemon);
# 2. host: the evaluation's unit tests and the small evaluation set end to end;
# 3. UML bench: twin scans replay through `alacsd --replay`, `alacsd --record` recordings
#    replay into the same result (real vcan0).
# Exit status: non-zero when any part failed.
set -uo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root"
junit=""
if [[ ${1:-} == --junit-dir ]]; then
  junit=$2
  mkdir -p "$junit"
fi
py="$root/.venv/bin/python"
build="$root/build/release"
status=0
cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null &&
  ninja -C "$build" -j "$(nproc)" alacsd alacs-twin alacs_calibrate alacs_geometry_eval alacs_cycle || exit 1
export ALACS_TWIN="$build/tools/twin/alacs-twin"
export ALACS_ALACSD="$build/edge/app/alacsd"
export ALACS_CYCLE="$build/tools/cycle/alacs_cycle"
export PYTHONPATH="$root/tools/eval/src${PYTHONPATH:+:$PYTHONPATH}"
"$py" -m pytest -q tests/eval --ignore=tests/eval/uml ${junit:+--junitxml="$junit/eval.xml"} || status=1
tests/hil/run_in_uml.sh --timeout 600 -- "$py" -m pytest -q tests/eval/uml \
  ${junit:+--junitxml="$junit/eval-uml.xml"} || status=1
exit $status
