#!/usr/bin/env bash
# Compile-checks edge/drivers/gpiod/gpiod_lines.cpp with -DALACS_GPIOD_API=2 against real
# libgpiod 2.x sources (the board's Yocto image has libgpiod 2.1.3; Debian 12 has only
# 1.6). The sources come from PyPI: the `gpiod` Python bindings' sdist vendors the
# libgpiod C library and gpiod.h (gpiod 2.1.3 ships libgpiod 2.1; the newest ships 2.3).
# For each version: build libgpiod from those sources, compile the adapter with the
# project's warnings as errors, link it into a tiny program and run it once (opening a
# chip that does not exist must fail cleanly, not crash).
# Usage: gpiod_v2_check.sh [WORK_DIR]   Prints one "ok"/"FAIL" line per version; exit 1 on any FAIL.
set -uo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
work=${1:-$root/build/gpiod-v2}
pip=$root/.venv/bin/pip
[[ -x $pip ]] || pip=pip3
cxx=${CXX:-g++}
cc=${CC:-gcc}
mkdir -p "$work"
# The project's warning flags, read from cmake/AlacsWarnings.cmake: ALACS_WARNINGS, plus
# ALACS_STRICT_WARNINGS (stricter than the project builds the driver).
# shellcheck source=tests/aarch64/adapter_check_lib.sh
source "$root/tests/aarch64/adapter_check_lib.sh"
project_warnings || { echo "gpiod-v2: FAIL cannot read the warning flags from cmake/AlacsWarnings.cmake"; exit 1; }
versions=("2.1.3" "${ALACS_GPIOD_PY_LATEST:-2.5.0}")
fails=0
for pyver in "${versions[@]}"; do
  dir=$work/gpiod-$pyver
  if [[ ! -f $dir/include/gpiod.h ]]; then
    "$pip" download -q --no-binary :all: --no-deps "gpiod==$pyver" -d "$work" >"$work/pip-$pyver.log" 2>&1 &&
      tar -xzf "$work/gpiod-$pyver.tar.gz" -C "$work" || {
      echo "gpiod-v2: FAIL gpiod $pyver: cannot download the sdist (see $work/pip-$pyver.log)"
      fails=$((fails + 1)); continue; }
  fi
  libver=$(cat "$dir/libgpiod-version.txt" 2>/dev/null || echo "?")
  out=$dir/build
  mkdir -p "$out"
  log=$out/build.log
  : >"$log"
  ok=1
  # libgpiod itself, with the defines the sdist's setup.py passes.
  objs=()
  for c in "$dir"/lib/*.c; do
    o=$out/$(basename "${c%.c}").o
    "$cc" -std=gnu11 -O1 -fPIC -D_GNU_SOURCE -DGPIOD_VERSION_STR="\"$libver\"" -DGPIOD_API_VERSION_STR="\"$libver\"" \
      -I "$dir/include" -I "$dir/lib" -c "$c" -o "$o" >>"$log" 2>&1 || ok=0
    objs+=("$o")
  done
  ((ok)) && { ar rcs "$out/libgpiod.a" "${objs[@]}" >>"$log" 2>&1 || ok=0; }
  # The adapter, as the project builds it, but against v2.
  # Every source of the alacs_drivers_gpiod library (edge/drivers/CMakeLists.txt), so a file added there
  # and missing here fails this check at once rather than at link time.
  driver_objs=()
  for src in $(sed -n 's/^ *SOURCES \(gpiod\/.*\)$/\1/p' "$root/edge/drivers/CMakeLists.txt"); do
    o=$out/$(basename "${src%.cpp}").o
    ((ok)) && { "$cxx" -std=c++20 -O1 "${warn[@]}" -DALACS_GPIOD_API=2 -I "$root/edge" -I "$dir/include" \
      -c "$root/edge/drivers/$src" -o "$o" >>"$log" 2>&1 || ok=0; }
    driver_objs+=("$o")
  done
  ((${#driver_objs[@]} > 0)) || { echo "no gpiod sources found in edge/drivers/CMakeLists.txt" >>"$log"; ok=0; }
  cat >"$out/smoke.cpp" <<'CPP'
#include <cstdio>
#include "drivers/gpiod/gpiod_lines.h"
int main() {
  auto r = alacs::drivers::GpiodLines::open("/dev/gpiochip-alacs-missing", {}, "gpiod-v2-check");
  if (r) { std::puts("unexpected: opened a chip that does not exist"); return 1; }
  std::printf("open(missing chip) -> %s\n", r.status().toString().c_str());
  return 0;
}
CPP
  ((ok)) && { link_smoke "$out" "$log" "${driver_objs[@]}" -- "$out/libgpiod.a" && "$out/smoke" >>"$log" 2>&1 || ok=0; }
  report "$ok" "$log" \
    "gpiod-v2: ok   gpiod_lines.cpp (ALACS_GPIOD_API=2) compiles, links and runs against libgpiod $libver (PyPI gpiod $pyver)" \
    "gpiod-v2: FAIL against libgpiod $libver (PyPI gpiod $pyver)"
done
((fails == 0))
