#!/usr/bin/env bash
# Cross-builds the whole project for aarch64 (Raspberry Pi 4/5) into build/aarch64 with
# cmake/toolchain-aarch64.cmake and runs the unit tests under qemu-user; then checks the
# libgpiod v2 backend (tests/aarch64/gpiod_v2_check.sh) and the libcamera adapter against
# newer libcamera APIs (tests/aarch64/libcamera_api_check.sh). Installs what is missing first
# (apt, as root or through sudo). Ends with one line: "aarch64: N passed, N failed"
# (N = unit test cases run under qemu plus this script's own checks).
#
# Why a private arm64 root (build/aarch64-extra): the arm64 -dev packages of OpenCV's
# imgcodecs and calib3d cannot be installed beside the host's amd64 OpenCV (libgdal32,
# libopenexr-dev, ... are not Multi-Arch: same), and tools/bootstrap.sh needs the amd64
# libopencv-dev. So those few packages are downloaded and unpacked into a directory of
# their own instead of being installed; nothing else on the host changes.
#
# --build-only: stop after the cross build (tests/run starts it in the background early, at
# nice 19, so that it takes the core the single-threaded steps leave idle).
set -uo pipefail
build_only=0
[[ ${1:-} == --build-only ]] && build_only=1
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root"
build=build/aarch64
extra=$root/build/aarch64-extra
triplet=aarch64-linux-gnu
qemu_timeout=${ALACS_QEMU_TIMEOUT:-600}
passed=0
failed=0
step() { printf '\n=== %s\n' "$*"; }
pass() { passed=$((passed + 1)); echo "aarch64: ok   $*"; }
fail() { failed=$((failed + 1)); echo "aarch64: FAIL $*"; }
now_ms() { echo $(($(date +%s%N) / 1000000)); }
secs_since() { local ms=$(($(now_ms) - $1)); printf '%d.%d' $((ms / 1000)) $((ms % 1000 / 100)); }
finish() { echo; echo "aarch64: $passed passed, $failed failed"; ((failed == 0)); exit; }

sudo=()
[[ $(id -u) -eq 0 ]] || sudo=(sudo)
installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }

step "host packages"
host_packages=(file cmake ninja-build pkg-config g++-aarch64-linux-gnu qemu-user-static binfmt-support catch2 libeigen3-dev
  libgpiod-dev:arm64 libcamera-dev:arm64 libsystemd-dev:arm64 libpng-dev:arm64
  libopencv-core-dev:arm64 libopencv-imgproc-dev:arm64)
# Unpacked into $extra, never installed (see above).
extra_packages=(libopencv-calib3d-dev:arm64 libopencv-imgcodecs-dev:arm64)
if ! dpkg --print-foreign-architectures | grep -qx arm64; then
  "${sudo[@]}" dpkg --add-architecture arm64
  updated=0
else
  updated=1
  # A stale list from before arm64 was added has no arm64 packages at all.
  apt-cache policy libgpiod-dev:arm64 2>/dev/null | grep -q 'Candidate: [0-9]' || updated=0
fi
missing=()
for p in "${host_packages[@]}"; do installed "$p" || missing+=("$p"); done
if ((${#missing[@]})); then
  echo "installing: ${missing[*]}"
  ((updated)) || "${sudo[@]}" apt-get update -q -o DPkg::Lock::Timeout=600 >/dev/null
  updated=1
  DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -q --no-install-recommends \
    -o DPkg::Lock::Timeout=600 "${missing[@]}" >"$root/build/aarch64-apt.log" 2>&1 ||
    { fail "apt-get install (build/aarch64-apt.log)"; finish; }
fi
pass "host packages"

step "private arm64 root for ${extra_packages[*]}"
stamp=$extra/.complete
if [[ ! -f $stamp ]]; then
  ((updated)) || "${sudo[@]}" apt-get update -q -o DPkg::Lock::Timeout=600 >/dev/null
  tests/aarch64/unpack_arm64.sh "$extra" "${extra_packages[@]}" || { fail "unpack ${extra_packages[*]}"; finish; }
fi
pass "private arm64 root ($extra)"
# Some of those packages are not multiarch-clean: they put arm64 libraries in /usr/lib.
extra_libs="$extra/usr/lib/$triplet:$extra/usr/lib"

step "configure"
# The private root is one more prefix for find_library; its libraries' own dependencies
# (libgdal, ...) are found by the linker through -rpath-link and at run time through
# the build RPATH (qemu -L / maps the absolute path onto the host's). DT_RPATH, not
# DT_RUNPATH (--disable-new-dtags): only the former also serves the libraries' own
# dependencies.
nice cmake -S . -B "$build" -G Ninja -U 'ALACS_OPENCV_*'  -DCMAKE_TOOLCHAIN_FILE="$root/cmake/toolchain-aarch64.cmake" \
  -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$extra/usr" \
  -DCMAKE_EXE_LINKER_FLAGS="-Wl,--disable-new-dtags -Wl,-rpath-link,$extra_libs" -DCMAKE_BUILD_RPATH="${extra_libs//:/;}" \
  >"$root/build/aarch64-configure.log" 2>&1 || { cat "$root/build/aarch64-configure.log"; fail "configure"; finish; }
grep -E "^-- ALACS" "$root/build/aarch64-configure.log"
pass "configure"

step "build"
start=$(now_ms)
# What runs under qemu: the daemon and the unit tests (the host tools are built and
# tested on the host; cross-building them too cost CI minutes and proved nothing more).
# ALACS_AARCH64_JOBS: compile jobs (default: every core; tests/run builds with one beside the
# system tests, so that UML keeps a core of its own).
if nice ninja -C "$build" -j "${ALACS_AARCH64_JOBS:-$(nproc)}" alacsd alacs_unit_tests; then
  pass "cross build in $(secs_since "$start") s"
else
  fail "cross build"
  finish
fi
for bin in "$build/edge/app/alacsd" "$build/tests/alacs_unit_tests"; do
  if file -b "$bin" | grep -q "ARM aarch64"; then pass "$(basename "$bin") is an aarch64 ELF"; else fail "$bin: $(file -b "$bin")"; fi
done
((build_only)) && finish

step "alacsd under qemu"
qemu=(timeout -s KILL 60 qemu-aarch64-static -L /)
if v=$("${qemu[@]}" "$build/edge/app/alacsd" --version 2>&1); then pass "alacsd --version: $v"; else fail "alacsd --version: $v"; fi
# The appliance's default config must load and validate: with a missing CAN interface the
# daemon gets past the config (exit 2 would be a config error) and stops at the socket.
out=$("${qemu[@]}" "$build/edge/app/alacsd" --config firmware/config/alacsd.json --can nocan0 2>&1)
rc=$?
if [[ $rc -eq 1 ]] && ! grep -qi "config" <<<"$out"; then
  pass "firmware/config/alacsd.json loads (alacsd exit $rc at the CAN socket)"
else
  fail "firmware/config/alacsd.json (alacsd exit $rc): $out"
fi

step "unit tests under qemu"
# 300 s a test. The [render] and [slow] tests are not registered for the cross build
# (tests/CMakeLists.txt): they run natively in Release.
start=$(now_ms)
timeout -s KILL "$qemu_timeout" ctest --test-dir "$build" --timeout 300 -j "$(nproc)" \
  --output-junit "$root/build/aarch64-unit.xml" >"$root/build/aarch64-ctest.log" 2>&1
rc=$?
secs=$(secs_since "$start")
tail -n 20 "$root/build/aarch64-ctest.log"
total=$(sed -nE 's/.*tests passed, ([0-9]+) tests failed out of ([0-9]+).*/\2/p' "$root/build/aarch64-ctest.log" | tail -1)
nfail=$(sed -nE 's/.*tests passed, ([0-9]+) tests failed out of ([0-9]+).*/\1/p' "$root/build/aarch64-ctest.log" | tail -1)
if [[ -n $total && -n $nfail ]]; then
  passed=$((passed + total - nfail))
  failed=$((failed + nfail))
  echo "aarch64: unit tests under qemu: $((total - nfail))/$total passed in $secs s"
  [[ $rc -eq 0 || $nfail -gt 0 ]] || fail "ctest exit $rc"
else
  fail "ctest under qemu (exit $rc, no summary; killed after ${qemu_timeout}s?)"
fi

step "libgpiod v2 backend"
if tests/aarch64/gpiod_v2_check.sh; then pass "gpiod v2 compile check"; else fail "gpiod v2 compile check"; fi

step "libcamera 0.4 and newest APIs"
if tests/aarch64/libcamera_api_check.sh; then pass "libcamera API check"; else fail "libcamera API check"; fi

finish
