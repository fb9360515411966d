#!/usr/bin/env bash
# libFuzzer on every JSON reader of edge/ (config, calibration, scan manifest, scene,
# calibration gate limits) under AddressSanitizer + UndefinedBehaviorSanitizer, each for a
# bounded time. Besides crashes and sanitizer reports a target fails when an error is not
# one short line, or when what a reader accepted does not read back the same after
# writing (tests/fuzz/json/fuzz_*.cpp).
#
# Usage: tests/fuzz/json/run.sh [SECONDS]      (per target; default 60; env FUZZ_SECONDS too)
# Builds with clang into build/fuzz-json/, starts from the seed corpus kept in
# tests/fuzz/json/corpus/<target>/ (valid files and broken ones) with the dictionary
# tests/fuzz/json/json.dict, and leaves any reproducer in build/fuzz-json/<target>/.
# Prints the executions and the corpus size per target. Needs clang and libclang-rt-14-dev.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd -P)
here="$root/tests/fuzz/json"
seconds=${1:-${FUZZ_SECONDS:-60}}
out="$root/build/fuzz-json"
targets=(config calibration manifest scene limits)
mkdir -p "$out/obj"
CLANG=${CLANG:-clang}
CLANGXX=${CLANGXX:-clang++}
san=(-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer)
inc=(-I"$root/edge" -isystem /usr/include/opencv4 -isystem /usr/include/eigen3)
warn=(-Wall -Wextra -Werror)

# The readers and what their checks call (validateConfig reaches the LLE, motion and scan
# parameters; the scene's validate the calibration's). An archive, so that each target
# links only the objects it needs.
sources=(common/json_file common/file_beneath common/result common/log common/clock
         geometry/calibration geometry/calibration_gate geometry/triangulation geometry/sphere_fit
         geometry/spheroid_fit
         image/lle image/lle_focus image/lle_mask image/lle_fit image/lle_reference image/lle_simd
         motion/trapezoid localize/localizer localize/exposure localize/weak_arc localize/leaf_colour sim/scene replay/scan_dir replay/png_io app/config)
objs=()
for src in "${sources[@]}"; do
  obj="$out/obj/${src//\//_}.o"
  if [[ ! -e $obj || "$root/edge/$src.cpp" -nt $obj || -n $(find "$root/edge" -name '*.h' -newer "$obj" -print -quit) ]]; then
    "$CLANGXX" -std=c++20 -O1 -g "${san[@]}" "${inc[@]}" "${warn[@]}" -c "$root/edge/$src.cpp" -o "$obj"
  fi
  objs+=("$obj")
done
rm -f "$out/libjson_readers.a"
ar rcs "$out/libjson_readers.a" "${objs[@]}"
libs=(-lopencv_calib3d -lopencv_imgproc -lopencv_core -lpng -lm -lpthread)

status=0
for t in "${targets[@]}"; do
  mkdir -p "$out/$t/corpus"
  "$CLANGXX" -std=c++20 -O1 -g "${san[@]}" "${inc[@]}" "${warn[@]}" -c "$here/fuzz_$t.cpp" -o "$out/obj/fuzz_$t.o"
  "$CLANGXX" -fsanitize=fuzzer,address,undefined "$out/obj/fuzz_$t.o" "$out/libjson_readers.a" "${libs[@]}" \
    -o "$out/fuzz_$t"
  set +e
  (cd "$out/$t" &&
    ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
      "$out/fuzz_$t" -max_total_time="$seconds" -max_len=65536 -timeout=10 -rss_limit_mb=2048 \
      -dict="$here/json.dict" -print_final_stats=1 -artifact_prefix="$out/$t/" \
      corpus "$here/corpus/$t" 2>"$out/$t/fuzz.log")
  rc=$?
  set -e
  execs=$(grep -E "^stat::number_of_executed_units" "$out/$t/fuzz.log" | awk '{print $2}')
  size=$(find "$out/$t/corpus" -type f | wc -l)
  echo "fuzz-json $t: ${execs:-0} executions in ${seconds} s, corpus $size files (+ $(ls "$here/corpus/$t" | wc -l) seeds)"
  if [[ $rc -ne 0 ]]; then
    tail -40 "$out/$t/fuzz.log"
    echo "fuzz-json $t: FAILED (exit $rc); reproducer: $(ls -t "$out/$t"/crash-* "$out/$t"/leak-* "$out/$t"/timeout-* "$out/$t"/oom-* 2>/dev/null | head -1)"
    status=1
  fi
done
[[ $status -eq 0 ]] && echo "fuzz-json: ${#targets[@]} targets × ${seconds} s under ASan+UBSan, no crash, no sanitizer report, no broken invariant"
exit $status
