#!/usr/bin/env bash
# libFuzzer on LLE's image entry point (edge/image: frame, ROI, parameters, pixels) under
# AddressSanitizer + UndefinedBehaviorSanitizer, for a bounded time. Besides crashes and
# sanitizer reports it fails when the SIMD and scalar kernels differ, when the float
# reference decides otherwise or differs by more than 1/64 px (tests/fuzz/lle/fuzz_lle.cpp).
#
# Usage: tests/fuzz/lle/run.sh [SECONDS]      (default 60; env FUZZ_SECONDS too)
# Builds with clang into build/fuzz-lle/ (every SIMD variant the CPU runs is exercised:
# the target compares the one in use with the scalar one), seeds the corpus with a few
# line images, runs, and leaves any reproducer in build/fuzz-lle/. Needs clang and
# libclang-rt-14-dev.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd -P)
seconds=${1:-${FUZZ_SECONDS:-60}}
out="$root/build/fuzz-lle"
py="${PYTHON:-$root/.venv/bin/python}"
[[ -x $py ]] || py=python3
mkdir -p "$out/obj" "$out/corpus" "$out/seeds"
CLANGXX=${CLANGXX:-clang++}
san=(-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer)
inc=(-I"$root/edge" -isystem /usr/include/opencv4 -isystem /usr/include/eigen3)
warn=(-Wall -Wextra -Werror)

objs=()
compile() {  # compile SRC OBJ [extra flags]
  local src=$1 obj=$2
  shift 2
  "$CLANGXX" -std=c++20 -O1 -g "${san[@]}" "${inc[@]}" "${warn[@]}" "$@" -c "$src" -o "$obj"
  objs+=("$obj")
}
for src in lle lle_focus lle_mask lle_fit lle_reference lle_simd; do
  compile "$root/edge/image/$src.cpp" "$out/obj/$src.o" $([[ $(uname -m) == x86_64 ]] && echo -DALACS_LLE_AVX2=1 -DALACS_LLE_AVX512=1)
done
if [[ $(uname -m) == x86_64 ]]; then
  compile "$root/edge/image/lle_simd_avx2.cpp" "$out/obj/lle_simd_avx2.o" -mavx2
  compile "$root/edge/image/lle_simd_avx512.cpp" "$out/obj/lle_simd_avx512.o" -mavx2 -mavx512f -mavx512bw \
    -mavx512vl -mavx512dq -mavx512cd
fi
compile "$root/edge/common/result.cpp" "$out/obj/result.o"
"$CLANGXX" -std=c++20 -O1 -g "${san[@]}" "${inc[@]}" "${warn[@]}" -c "$root/tests/fuzz/lle/fuzz_lle.cpp" \
  -o "$out/obj/fuzz_lle.o"
"$CLANGXX" -fsanitize=fuzzer,address,undefined "$out/obj/fuzz_lle.o" "${objs[@]}" -o "$out/fuzz_lle"

# Seeds: lines on noise in a few sizes and ROIs, with the default parameters' bytes.
"$py" - "$out/seeds" <<'PY'
import pathlib, random, struct, sys
out = pathlib.Path(sys.argv[1])
rng = random.Random(1)
for i, (w, h) in enumerate([(64, 24), (120, 60), (33, 17), (300, 90), (9, 5)]):
    roi = (0, 0, w, h) if i % 2 == 0 else (3, 2, w - 5, h - 3)
    flags = i & 0x0F
    header = struct.pack("<HBBB", w - 1, h - 1, i % 2, 0) + struct.pack("<hhhh", *roi)
    header += bytes([4, 40, 8, 3, 4, 8 - 5, flags, 4, 6, 3, 8, 1, 8, 20])
    c0 = rng.uniform(3, w - 3)
    px = bytearray()
    for y in range(h):
        for x in range(w):
            d = x - (c0 + 0.05 * y)
            red = min(255, int(30 + rng.random() * 8 + 180 * 2.718 ** (-d * d / 3)))
            px += bytes([red, 20, 20]) if i % 2 == 0 else bytes([20, 20, red])
    (out / f"seed_{i}").write_bytes(header + bytes(px))
PY

cd "$out"
set +e
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ./fuzz_lle -max_total_time="$seconds" -max_len=131072 -timeout=20 -rss_limit_mb=2048 -print_final_stats=1 \
  -artifact_prefix="$out/" corpus seeds 2>"$out/fuzz.log"
status=$?
set -e
grep -E "^(#[0-9]+.*(DONE|INITED)|stat::number_of_executed_units|stat::peak_rss_mb)" "$out/fuzz.log" | tail -4
if [[ $status -ne 0 ]]; then
  tail -60 "$out/fuzz.log"
  echo "fuzz-lle: FAILED (exit $status); reproducer: $(ls -t "$out"/crash-* "$out"/leak-* "$out"/timeout-* 2>/dev/null | head -1)"
  exit 1
fi
echo "fuzz-lle: ${seconds} s under ASan+UBSan, no crash, no sanitizer report, SIMD = scalar, fixed = float within 1/64 px"
