#!/usr/bin/env bash
# libFuzzer on the CAN node (decoder, SDO server, NMT, counters, bus-off and back-off
# paths) under AddressSanitizer + UndefinedBehaviorSanitizer, for a bounded time.
#
# Usage: tests/fuzz/can/run.sh [SECONDS]      (default 60; env FUZZ_SECONDS too)
# Builds with clang into build/fuzz-can/, seeds the corpus from the golden vectors
# (can_protocol/vectors/golden.json), runs, and fails on any crash, sanitizer report or
# broken invariant (the reproducer is left in build/fuzz-can/). Prints the executions
# and the coverage reached. Needs clang and libclang-rt-14-dev.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd -P)
seconds=${1:-${FUZZ_SECONDS:-60}}
out="$root/build/fuzz-can"
py="${PYTHON:-$root/.venv/bin/python}"
[[ -x $py ]] || py=python3
mkdir -p "$out/obj" "$out/corpus" "$out/seeds"
CLANG=${CLANG:-clang}
CLANGXX=${CLANGXX:-clang++}
san=(-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer)
inc=(-I"$root/edge" -I"$root/can_protocol/generated" -I"$root/can_protocol/c" -isystem /usr/include/eigen3)
warn=(-Wall -Wextra -Werror -Wno-unused-parameter)

objs=()
"$CLANG" -std=c11 -O1 -g "${san[@]}" "${inc[@]}" -c "$root/can_protocol/generated/alacs.c" -o "$out/obj/alacs.o"
objs+=("$out/obj/alacs.o")
for src in codec node sdo; do
  "$CLANGXX" -std=c++20 -O1 -g "${san[@]}" "${inc[@]}" "${warn[@]}" -c "$root/edge/protocol/$src.cpp" \
    -o "$out/obj/$src.o"
  objs+=("$out/obj/$src.o")
done
"$CLANGXX" -std=c++20 -O1 -g "${san[@]}" "${inc[@]}" "${warn[@]}" -c "$root/tests/fuzz/can/fuzz_node.cpp" \
  -o "$out/obj/fuzz_node.o"
"$CLANGXX" -fsanitize=fuzzer,address,undefined "$out/obj/fuzz_node.o" "${objs[@]}" -lm -o "$out/fuzz_can"

# Seeds: every golden command and SDO request as one record, and all of them in a row.
"$py" - "$root/can_protocol/vectors/golden.json" "$out/seeds" <<'PY'
import json, sys, pathlib
golden = json.loads(pathlib.Path(sys.argv[1]).read_text())
out = pathlib.Path(sys.argv[2])
def record(can_id, data, dt=5):
    data = bytes.fromhex(data)
    return bytes([can_id & 0xFF, can_id >> 8, len(data), dt]) + data.ljust(8, b"\0")
records = []
for v in golden["vectors"]:
    records.append(record(v["frame_id"], v["data"]))
for c in golden["command_checks"]:
    records.append(record(c["frame_id"], c["data"]))
for s in golden["sdo_exchanges"]:
    records.append(record(0x610, s["request"]))
records.append(record(0x000, "0110"))       # NMT start
records.append(record(0x2040, "4000000000000000"))  # error frame: bus-off
records.append(record(0x2100, "0001000000000000", 200))  # error frame: restarted
for i, r in enumerate(records):
    (out / f"seed_{i:03d}").write_bytes(b"\x01" + r)
(out / "seed_all").write_bytes(b"\x01" + b"".join(records))
PY

cd "$out"
set +e
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ./fuzz_can -max_total_time="$seconds" -max_len=4096 -timeout=10 -use_value_profile=1 -print_final_stats=1 \
  -artifact_prefix="$out/" corpus seeds 2>"$out/fuzz.log"
status=$?
set -e
grep -E "^(#[0-9]+.*(DONE|INITED)|stat::number_of_executed_units|stat::peak_rss_mb)" "$out/fuzz.log" | tail -4
if [[ $status -ne 0 ]]; then
  tail -60 "$out/fuzz.log"
  echo "fuzz-can: FAILED (exit $status); reproducer: $(ls -t "$out"/crash-* "$out"/leak-* "$out"/timeout-* 2>/dev/null | head -1)"
  exit 1
fi
echo "fuzz-can: ${seconds} s under ASan+UBSan, no crash, no sanitizer report"
