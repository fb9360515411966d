#!/usr/bin/env bash
# libFuzzer on the PNG reader (edge/replay/png_io.cpp, libpng underneath) under
# AddressSanitizer + UndefinedBehaviorSanitizer, for a bounded time: any bytes as a PNG
# file must give an image or an error naming the file, never a crash, a sanitizer report,
# a leak or an allocation past the reader's limits (tests/fuzz/png/fuzz_png.cpp).
#
# Usage: tests/fuzz/png/run.sh [SECONDS]      (default 60; env FUZZ_SECONDS too)
# Builds with clang into build/fuzz-png/, starts from the seeds in tests/fuzz/png/seeds
# (small PNGs of every colour type, bit depth and interlace), prints the executions and
# the corpus size, and leaves any reproducer in build/fuzz-png/. Needs clang,
# libclang-rt-14-dev and libpng-dev.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd -P)
seconds=${1:-${FUZZ_SECONDS:-60}}
out="$root/build/fuzz-png"
mkdir -p "$out/obj" "$out/corpus"
CLANGXX=${CLANGXX:-clang++}
san=(-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer)
inc=(-I"$root/edge" -isystem /usr/include/opencv4)
warn=(-Wall -Wextra -Werror)

objs=()
for src in edge/replay/png_io.cpp edge/common/result.cpp tests/fuzz/png/fuzz_png.cpp; do
  obj="$out/obj/$(basename "$src" .cpp).o"
  "$CLANGXX" -std=c++20 -O1 -g "${san[@]}" "${inc[@]}" "${warn[@]}" -c "$root/$src" -o "$obj"
  objs+=("$obj")
done
"$CLANGXX" -fsanitize=fuzzer,address,undefined "${objs[@]}" -lpng -lopencv_core -o "$out/fuzz_png"

cd "$out"
set +e
# -malloc_limit_mb: one allocation beyond the reader's decoded-bytes cap (96 MiB) and some
# slack is a finding, as is a process beyond -rss_limit_mb.
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ./fuzz_png -max_total_time="$seconds" -max_len=65536 -timeout=20 -rss_limit_mb=1024 -malloc_limit_mb=160 \
  -print_final_stats=1 -artifact_prefix="$out/" corpus "$root/tests/fuzz/png/seeds" 2>"$out/fuzz.log"
status=$?
set -e
grep -E "^(#[0-9]+.*(DONE|INITED)|stat::number_of_executed_units|stat::peak_rss_mb)" "$out/fuzz.log" | tail -4
execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$out/fuzz.log" | tail -1)
echo "fuzz-png: ${execs:-?} executions, corpus $(find "$out/corpus" -type f | wc -l) files"
if [[ $status -ne 0 ]]; then
  tail -60 "$out/fuzz.log"
  echo "fuzz-png: FAILED (exit $status); reproducer: $(ls -t "$out"/crash-* "$out"/leak-* "$out"/timeout-* "$out"/oom-* 2>/dev/null | head -1)"
  exit 1
fi
echo "fuzz-png: ${seconds} s under ASan+UBSan, no crash, no sanitizer report, no allocation past the limits"
