#!/usr/bin/env bash
# Prove that the HIL bench is real; exits non-zero if any part of it is not.
#
# Usage: tests/hil/smoke_test.sh    (from anywhere; builds the kernel on first use)
#
# Checks, through run_in_uml.sh:
#  - exit statuses come back: 0, 42, and a run whose status never got written
#    (guest powered off under the command) is an error, not a success;
#  - tests/hil/test_bench_smoke.py inside UML: cansend seen by candump -L and
#    by python-can, a candump log decoded by cantools, gpioset/gpioget on the
#    gpio-sim chip by line name against gpio_sim.py, and `cam -l` listing the
#    vimc camera once udev has run (tests/hil/start_udev.sh).
# ALACS_PYTHON picks the interpreter (default: the repo's .venv).
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
root=$(cd "$here/../.." && pwd -P)
python=${ALACS_PYTHON:-$root/.venv/bin/python}
run_in_uml=$here/run_in_uml.sh

fail() {
    echo "smoke_test.sh: FAIL: $*" >&2
    exit 1
}

# Runs run_in_uml.sh with the given arguments; sets `rc` to its exit status.
run_status() {
    rc=0
    "$run_in_uml" --timeout 120 "$@" || rc=$?
}

[[ -x $python ]] || fail "no python at $python (set ALACS_PYTHON or create .venv)"
cd "$root"

echo "smoke_test.sh: exit status propagation" >&2
run_status -- true
((rc == 0)) || fail "'true' inside UML gave $rc, not 0"
run_status -- sh -c 'exit 42'
((rc == 42)) || fail "'exit 42' inside UML gave $rc, not 42"
run_status -- sh -c 'echo o >/proc/sysrq-trigger; sleep 30' 2>/dev/null
((rc == 125)) || fail "a run that lost its status gave $rc, not 125"
# shellcheck disable=SC2016 # expanded inside UML
out=$("$run_in_uml" -- sh -c 'echo "$ALACS_IN_UML:$ALACS_CAN_IFACE:$PWD"')
[[ $out == "1:vcan0:$root" ]] || fail "stdout/env/cwd inside UML: '$out'"

echo "smoke_test.sh: CAN and GPIO inside UML" >&2
# ALACS_HIL_REQUIRED: the bench tests fail rather than skip if the bench's
# environment did not make it in.
ALACS_HIL_REQUIRED=1 run_status --timeout 300 -- \
    "$python" -m pytest -p no:cacheprovider -q "$here/test_bench_smoke.py"
((rc == 0)) || fail "bench tests inside UML gave $rc"

echo "smoke_test.sh: PASS" >&2
