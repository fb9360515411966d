#!/usr/bin/env bash
# Compile-and-link check of the libcamera adapter (edge/drivers/libcamera) against newer
# libcamera APIs than Debian 12's 0.0.3: Debian 13's (trixie, 0.4) and Debian unstable's
# (sid, the newest packaged). Boards ship 0.2-0.5 (Yocto scarthgap, Raspberry Pi OS).
# The packages come from the Debian package registry through a private apt state (own
# sources list, lists and cache under WORK_DIR): the machine's apt configuration is not
# touched and nothing is installed. For each suite: `apt-get download libcamera-dev` and
# its library, `dpkg -x`, compile libcamera_source.cpp with the project's warnings as
# errors against those headers, and link a small program against that libcamera.so, so
# that every symbol the adapter uses must exist in it (the library's own dependencies on
# a newer C++ runtime are not resolved: --allow-shlib-undefined). Not run: bookworm's C++
# runtime is older than the one those libraries were built with.
# Usage: libcamera_api_check.sh [WORK_DIR]   One "ok"/"FAIL" line per suite; exit 1 on any FAIL.
set -uo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
work=${1:-$root/build/libcamera-api}
cxx=${CXX:-g++}
mkdir -p "$work"
# shellcheck source=tests/aarch64/adapter_check_lib.sh
source "$root/tests/aarch64/adapter_check_lib.sh"
project_warnings || { echo "libcamera-api: FAIL cannot read the warning flags from cmake/AlacsWarnings.cmake"; exit 1; }
fails=0
for suite in ${ALACS_LIBCAMERA_SUITES:-trixie sid}; do
  dir=$work/$suite
  log=$dir/check.log
  mkdir -p "$dir/lists/partial" "$dir/cache/archives/partial" "$dir/debs"
  : >"$log"
  printf 'deb [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] http://deb.debian.org/debian %s main\n' \
    "$suite" >"$dir/sources.list"
  apt=(-o "Dir::Etc::SourceList=$dir/sources.list" -o Dir::Etc::SourceParts=/dev/null
    -o "Dir::State::Lists=$dir/lists" -o "Dir::Cache=$dir/cache" -o Debug::NoLocking=1
    -o APT::Sandbox::User=root)
  ok=1
  # Lists at most a day old are reused.
  if [[ -z $(find "$dir/lists" -maxdepth 1 -name '*Packages*' -mtime -1 2>/dev/null) ]]; then
    apt-get "${apt[@]}" update -q >>"$log" 2>&1 || ok=0
  fi
  version=$(apt-cache "${apt[@]}" show libcamera-dev 2>>"$log" | sed -n 's/^Version: //p' | head -1)
  lib=$(apt-cache "${apt[@]}" depends libcamera-dev 2>>"$log" | awk '/Depends: libcamera[0-9]/{print $2; exit}')
  [[ -n $version && -n $lib ]] || ok=0
  sysroot=$dir/root-$version
  if ((ok)) && [[ ! -f $sysroot/usr/include/libcamera/libcamera/camera.h ]]; then
    rm -rf "$dir/debs"/*.deb "$sysroot"
    (cd "$dir/debs" && apt-get "${apt[@]}" download libcamera-dev "$lib") >>"$log" 2>&1 || ok=0
    for deb in "$dir/debs"/*.deb; do dpkg -x "$deb" "$sysroot" >>"$log" 2>&1 || ok=0; done
  fi
  libdir=$sysroot/usr/lib/x86_64-linux-gnu
  out=$dir/build
  mkdir -p "$out"
  ((ok)) && { "$cxx" -std=c++20 -O1 "${warn[@]}" -DALACS_HAVE_LIBCAMERA=1 -I "$root/edge" \
    -isystem "$sysroot/usr/include/libcamera" -c "$root/edge/drivers/libcamera/libcamera_source.cpp" \
    -o "$out/libcamera_source.o" >>"$log" 2>&1 || ok=0; }
  # The frame clock the adapter learns (edge/common, plain C++).
  ((ok)) && { "$cxx" -std=c++20 -O1 "${warn[@]}" -I "$root/edge" -c "$root/edge/common/frame_clock.cpp" \
    -o "$out/frame_clock.o" >>"$log" 2>&1 || ok=0; }
  cat >"$out/smoke.cpp" <<'CPP'
#include <cstdio>
#include "drivers/libcamera/libcamera_source.h"
int main() {
  auto n = alacs::drivers::LibcameraSource::countCameras();
  auto r = alacs::drivers::LibcameraSource::open({});
  std::printf("%d %d\n", n ? *n : -1, r ? 1 : 0);
  return 0;
}
CPP
  ((ok)) && { link_smoke "$out" "$log" "$out/libcamera_source.o" "$out/frame_clock.o" -- \
    -L "$libdir" -Wl,--allow-shlib-undefined -Wl,-rpath-link,"$libdir" -lcamera -lcamera-base || ok=0; }
  report "$ok" "$log" \
    "libcamera-api: ok   libcamera_source.cpp compiles and links against libcamera $version (Debian $suite)" \
    "libcamera-api: FAIL against libcamera ${version:-?} (Debian $suite)"
done
((fails == 0))
