#!/usr/bin/env bash
# The board's build (Yocto's recipe: -DALACS_WITH_SIM=OFF) gives an alacsd that builds and
# does not link the simulator. Always (a configure and one compile, about 15 s of CPU):
# the build has no alacs_sim or alacs_app_sim target; alacsd's link line (build.ninja)
# names no library of edge/sim; and alacsd.cpp, the only source that the option changes
# (the libraries are the host build's, compiled in tests/run's build step), compiles in
# that configuration, where no simulator header is even reachable (each component sees
# only the headers of what it links). With --build, also links that alacsd (Release,
# ccache when present) and checks with nm that it holds no alacs::sim symbol (and does
# hold alacs::app ones, so the check would see them).
# Usage: tests/style/board_build.sh [--build]
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root"
build=build/style-board
fail() { echo "board build: $*"; exit 1; }
launcher=()
if [[ ${1:-} == --build ]] && command -v ccache >/dev/null; then launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache); fi
mkdir -p "$build"
type=Debug  # the compile check parses; -O0 is the quickest
[[ ${1:-} == --build ]] && type=Release
cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=$type -DALACS_WITH_SIM=OFF "${launcher[@]}" \
  --graphviz="$build/deps.dot" >"$build/configure.log" 2>&1 || { cat "$build/configure.log"; fail "configure failed"; }

# No simulator target at all.
if grep -E 'label = "alacs_(app_)?sim"' "$build/deps.dot"; then fail "ALACS_WITH_SIM=OFF still has a simulator target"; fi
# alacsd's link step: its inputs and LINK_LIBRARIES.
link=$(awk '/^build edge\/app\/alacsd:/ {on = 1} on && /^$/ {exit} on' "$build/build.ninja")
[[ -n $link ]] || fail "no link step for alacsd in $build/build.ninja"
if grep -oE '[^ ]*(alacs_sim|alacs_app_sim|edge/sim/)[^ ]*' <<<"$link"; then fail "alacsd's link line names the simulator"; fi
libs=$(grep -oE '[^ ]*libalacs_[a-z_]+\.a' <<<"$link" | sort -u | xargs -n1 basename | tr '\n' ' ')
echo "board build: alacsd links ${libs}and no simulator library (ALACS_WITH_SIM=OFF, link line)"

[[ ${1:-} == --build ]] || {
  nice ninja -C "$build" edge/app/CMakeFiles/alacsd.dir/alacsd.cpp.o edge/app/CMakeFiles/alacsd.dir/alacsd_options.cpp.o >"$build/build.log" 2>&1 ||
    { grep -E 'error|FAILED' "$build/build.log" | head -20; fail "alacsd.cpp does not compile with ALACS_WITH_SIM=OFF"; }
  echo "board build: alacsd.cpp compiles with ALACS_WITH_SIM=OFF"
  exit 0
}
nice -n 10 ninja -C "$build" alacsd >"$build/build.log" 2>&1 || { tail -20 "$build/build.log"; fail "alacsd does not build"; }
bin=$build/edge/app/alacsd
sim=$(nm -C "$bin" | grep -c 'alacs::sim::' || true)
app=$(nm -C "$bin" | grep -c 'alacs::app::' || true)
((app > 0)) || fail "nm finds no alacs::app symbol in $bin (stripped?): the check would prove nothing"
((sim == 0)) || { nm -C "$bin" | grep 'alacs::sim::' | head; fail "$bin holds $sim alacs::sim symbols"; }
echo "board build: nm $bin: $app alacs::app symbols, 0 alacs::sim"
