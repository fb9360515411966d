#!/usr/bin/env bash
# Cross-build alacsd for aarch64 into build/board-aarch64 and install it, with firmware/'s
# files, into a staging tree laid out as the Yocto recipe (yocto/meta-alacs/recipes-alacs/
# alacsd/alacsd_git.bb) installs them; tests/board/run.sh writes that tree into the board's
# root file system.
#
# Usage: tests/board/stage.sh STAGE_DIR
#
# The build: cmake/toolchain-aarch64.cmake (as tests/aarch64/run.sh), Release, no unit
# tests, ccache when present, and the project's own install step (`cmake --install
# --prefix /usr` with DESTDIR). ALACS_WITH_SIM stays ON (the recipe turns it off): the
# board has no camera, so the daemon's camera is `--replay` of a recorded scan directory.
# Then firmware/: the unit, the network file, the udev rule, the default config, the
# install guide, as the recipe's do_install:append does, and the unit enabled as
# SYSTEMD_AUTO_ENABLE does.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
stage=${1:?usage: tests/board/stage.sh STAGE_DIR}
build=$root/build/board-aarch64
extra=$root/build/aarch64-extra
triplet=aarch64-linux-gnu
cd "$root"
log() { echo "stage.sh: $*" >&2; }

# The arm64 OpenCV imgcodecs/calib3d -dev packages, unpacked beside the host's (not
# installed): the same private root as tests/aarch64/run.sh makes, and the same stamp, so
# either script reuses the other's. See that script for why.
[[ -f $extra/.complete ]] || log "unpacking the arm64 OpenCV imgcodecs/calib3d -dev packages into $extra"
tests/aarch64/unpack_arm64.sh "$extra" libopencv-calib3d-dev:arm64 libopencv-imgcodecs-dev:arm64 >&2
extra_libs="$extra/usr/lib/$triplet:$extra/usr/lib"

launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_C_COMPILER_LAUNCHER=ccache -DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
log "configure $build"
nice -n 19 cmake -S . -B "$build" -G Ninja -DCMAKE_TOOLCHAIN_FILE="$root/cmake/toolchain-aarch64.cmake" \
  -DCMAKE_BUILD_TYPE=Release -DCMAKE_INSTALL_PREFIX=/usr -DALACS_BUILD_TESTS=OFF -DALACS_WITH_SIM=ON \
  -DCMAKE_PREFIX_PATH="$extra/usr" -DCMAKE_EXE_LINKER_FLAGS="-Wl,-rpath-link,$extra_libs" \
  "${launcher[@]}" >"$root/build/board-aarch64-configure.log" 2>&1 ||
  { cat "$root/build/board-aarch64-configure.log" >&2; exit 1; }
grep -E "^-- ALACS" "$root/build/board-aarch64-configure.log" >&2 || true

# What the install rules install (alacsd, and the camera probe when libcamera is found):
# `ninja install` would first build `all`, the host tools included.
mapfile -t targets < <(ninja -C "$build" -t targets all 2>/dev/null |
  sed -nE 's#^(edge/app/alacsd|tools/camera_probe/alacs_camera_probe): .*#\1#p')
log "build ${targets[*]}"
nice -n 19 ninja -C "$build" -j2 "${targets[@]}" >&2

rm -rf "$stage" && mkdir -p "$stage"
log "cmake --install --prefix /usr (DESTDIR=$stage)"
DESTDIR=$stage cmake --install "$build" --prefix /usr >&2

# firmware/, as the recipe's do_install:append (systemd_system_unitdir = /usr/lib/systemd/system,
# systemd_unitdir/network = /usr/lib/systemd/network, nonarch_base_libdir = /usr/lib on a
# usrmerge image like Debian 12's).
install -D -m 0644 firmware/systemd/alacsd.service "$stage/usr/lib/systemd/system/alacsd.service"
install -D -m 0644 firmware/systemd/80-can0.network "$stage/usr/lib/systemd/network/80-can0.network"
install -D -m 0644 firmware/udev/60-alacs.rules "$stage/usr/lib/udev/rules.d/60-alacs.rules"
install -D -m 0644 firmware/config/alacsd.json "$stage/etc/alacs/alacsd.json"
install -D -m 0644 docs/install.md "$stage/usr/share/doc/alacs/install.md"
# SYSTEMD_AUTO_ENABLE = "enable": the unit's [Install] WantedBy=multi-user.target.
mkdir -p "$stage/etc/systemd/system/multi-user.target.wants"
ln -s /usr/lib/systemd/system/alacsd.service "$stage/etc/systemd/system/multi-user.target.wants/alacsd.service"
file -b "$stage/usr/bin/alacsd" | grep -q "ARM aarch64" || { log "$stage/usr/bin/alacsd is not aarch64"; exit 1; }
(cd "$stage" && find . ! -type d | sort) >&2
echo "$stage"
