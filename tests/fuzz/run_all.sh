#!/usr/bin/env bash
# Every fuzz target of tests/run's fuzz step with CI's bounds: 30 s for the CAN node, the
# LLE entry point and the PNG reader, 10 s for each JSON reader (longer runs by hand with
# the scripts themselves). Writes one line per script to STATUS_FILE ("fuzz-can 0": its
# exit status) as each ends, then an empty STATUS_FILE.done; exits non-zero when any failed.
#
# Usage: tests/fuzz/run_all.sh STATUS_FILE
# tests/run starts it in the background beside the system tests (UML runs on one core;
# these compiles and runs are single-threaded) and reads the status in its fuzz step.
set -uo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
status_file=${1:?usage: tests/fuzz/run_all.sh STATUS_FILE}
: >"$status_file"
rm -f "$status_file.done"
rc=0
for spec in "can 30" "lle 30" "png 30" "json 10"; do
  read -r name seconds <<<"$spec"
  "$root/tests/fuzz/$name/run.sh" "$seconds"
  s=$?
  echo "fuzz-$name $s" >>"$status_file"
  ((s == 0)) || rc=1
done
: >"$status_file.done"
exit $rc
