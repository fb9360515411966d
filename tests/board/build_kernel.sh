#!/usr/bin/env bash
# Print the absolute path of the virtual board's arm64 kernel Image (qemu-system-aarch64
# -M virt: virtio, two kvaser_pci CAN controllers, gpio-sim), building it from Debian's
# linux-source-6.1 with gcc-aarch64-linux-gnu on first use.
#
# Usage: tests/board/build_kernel.sh
#
# The configuration is our own and small: `make allnoconfig` plus the fragment
# tests/board/kernel.config (KCONFIG_ALLCONFIG), everything built in, no modules.
# The kernel is cached outside the work tree in
#   ${ALACS_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/alacs}/board-kernel-<key>/Image
# where <key> hashes the fragment, the linux-source package version and the build
# recipe below (as tests/hil/uml_kernel.sh keys the UML kernel): editing either builds a
# new kernel. Only stdout's last line is meant for callers; progress goes to stderr and
# the full build log to a file whose path is printed when the build fails.
set -euo pipefail
# shellcheck source=tests/lib/cached_build.sh
source "$(dirname "${BASH_SOURCE[0]}")/../lib/cached_build.sh"

readonly kSourcePackage=linux-source-6.1
readonly kSourceTarball=/usr/src/linux-source-6.1.tar.xz
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
readonly kFragment=$here/kernel.config

die() {
    echo "build_kernel.sh: $*" >&2
    exit 1
}

# The build recipe. Its text (declare -f) is part of the cache key, so keep every step
# that shapes the binary inside this function.
# $1: empty build directory; $2: log file; $3: the fragment. Leaves $1/Image and $1/config.
build_kernel() {
    local dir=$1 log=$2 fragment=$3
    local -a make=(nice -n 19 make ARCH=arm64 CROSS_COMPILE=aarch64-linux-gnu-)
    (
        set -euo pipefail
        cd "$dir"
        nice -n 19 tar xJf "$kSourceTarball"
        cd linux-source-6.1
        KCONFIG_ALLCONFIG=$fragment "${make[@]}" allnoconfig
        "${make[@]}" olddefconfig
        "${make[@]}" -j2 Image
        cp arch/arm64/boot/Image "$dir/Image"
        cp .config "$dir/config"
    ) >>"$log" 2>&1
}

# Fails unless every CONFIG_X=y of the fragment is =y in the .config at $1.
verify_config() {
    local config=$1 line missing=()
    while IFS= read -r line; do
        grep -qx "$line" "$config" || missing+=("$line")
    done < <(grep -E '^CONFIG_[A-Z0-9_]+=y$' "$kFragment")
    if ((${#missing[@]})); then
        echo "build_kernel.sh: not built in after olddefconfig (a dependency missing?):" \
            "${missing[*]}" >&2
        return 1
    fi
}

main() {
    [[ -r $kSourceTarball ]] ||
        die "$kSourceTarball missing: apt-get install $kSourcePackage gcc-aarch64-linux-gnu flex bison bc"
    command -v aarch64-linux-gnu-gcc >/dev/null ||
        die "aarch64-linux-gnu-gcc missing: apt-get install gcc-aarch64-linux-gnu"
    local version
    version=$(dpkg-query -W -f='${Version}' "$kSourcePackage") ||
        die "cannot read the version of $kSourcePackage"
    local key
    key=$(
        {
            cat "$kFragment"
            echo "$kSourcePackage $version"
            aarch64-linux-gnu-gcc --version | head -1
            declare -f build_kernel
        } | sha256sum | cut -c1-16
    )
    local root
    root=$(cache_root "") || die "no cache directory"
    cached_build "$root" "board-kernel-$key" Image publish_kernel build_kernel.sh ||
        die "see the log above"
}

# cached_build's PRODUCE: $1 work directory, $2 log; publishes Image and config in $1/out.
publish_kernel() {
    local work=$1 log=$2
    echo "build_kernel.sh: building the board kernel from $kSourcePackage" \
        "(first run on this machine: several minutes on 2 cores); log: $log" >&2
    build_kernel "$work" "$log" "$kFragment" && verify_config "$work/config" &&
        mv "$work/Image" "$work/config" "$work/out/" &&
        printf '%s %s\n' "$kSourcePackage" "$(dpkg-query -W -f='${Version}' "$kSourcePackage")" >"$work/out/source"
}

main "$@"
