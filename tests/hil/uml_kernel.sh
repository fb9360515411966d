#!/usr/bin/env bash
# Print the absolute path of a User-Mode Linux kernel with SocketCAN (vcan,
# vxcan), gpio-sim and the vimc virtual camera built in, building it from
# Debian's linux-source-6.1 on first use.
#
# Usage: tests/hil/uml_kernel.sh
#
# The kernel is cached outside the work tree in
#   ${ALACS_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/alacs}/uml/<key>/linux
# where <key> hashes the config fragment, the linux-source package version and
# the build recipe below, so editing any of them builds a new kernel and the old
# one is simply left behind. Only stdout's last line is meant for callers:
# progress goes to stderr and the full build log to a file whose path is
# printed when the build fails.
set -euo pipefail
# shellcheck source=tests/lib/cached_build.sh
source "$(dirname "${BASH_SOURCE[0]}")/../lib/cached_build.sh"

readonly kSourcePackage=linux-source-6.1
readonly kSourceTarball=/usr/src/linux-source-6.1.tar.xz

# Everything the bench needs, built in (=y): no modules are loaded inside UML.
readonly kOptions=(
    CAN CAN_RAW CAN_BCM CAN_GW CAN_DEV CAN_VCAN CAN_VXCAN
    GPIOLIB GPIO_CDEV GPIO_CDEV_V1 GPIO_SIM CONFIGFS_FS
    HOSTFS DEVTMPFS DEVTMPFS_MOUNT TMPFS
    # vimc, the kernel's virtual media-controller camera that libcamera's vimc
    # pipeline handler drives (docs/hil.md). VIRTIO_UML and UML_PCI_OVER_VIRTIO
    # bring no device: they supply the IOMEM and DMA emulation the media core
    # depends on under ARCH=um.
    VIRTIO_UML UML_PCI_OVER_VIRTIO
    MEDIA_SUPPORT MEDIA_SUPPORT_FILTER MEDIA_TEST_SUPPORT MEDIA_CAMERA_SUPPORT
    VIDEO_DEV MEDIA_CONTROLLER V4L_TEST_DRIVERS VIDEO_VIMC VIDEOBUF2_VMALLOC
)
# Options turned off. VMAP_STACK: with it each kernel stack (and the thread_info at its
# foot) is vmalloc'd, and UML 6.1 flushes its kernel TLB by unmapping a vmalloc range on
# the host in batches and mapping back what is present. A host signal that came while a
# task's stack was so unmapped faulted on it forever, and the whole guest froze
# (docs/hil.md, "A bench kernel that freezes"). Off, the stacks are pages of physical
# memory, which no such flush unmaps.
readonly kDisabled=(VMAP_STACK)
# Integer options (name=value), set with the booleans above.
# KERNEL_STACK_ORDER 4 (64 KB): each thread_info and the signal stack's register
# frame hold a host XSAVE area, up to 16 KB with uml-xstate.patch.
readonly kValues=(UML_PCI_OVER_VIRTIO_DEVICE_ID=1234 KERNEL_STACK_ORDER=4)
# Linux 6.1's UML hard-codes the host's XSAVE area as 2696 bytes (an AVX-512 CPU's).
# The host's PTRACE_SETREGSET takes exactly its own size and fails with EFAULT on
# any other, so on a CPU with AMX (11008 bytes) init dies at its first context
# switch ("userspace - ptrace set fp regs failed, errno = 14", then a panic). The
# patch reads the size from the host and makes room for 16 KB.
readonly kPatch="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)/uml-xstate.patch"

die() {
    echo "uml_kernel.sh: $*" >&2
    exit 1
}

# The build recipe. Its text (declare -f) is part of the cache key, so keep
# every step that shapes the binary inside this function.
# $1: empty build directory; $2: log file. Leaves $1/linux (stripped) and
# $1/config.
build_kernel() {
    local dir=$1 log=$2 opt
    local -a enable=()
    for opt in "${kOptions[@]}"; do
        enable+=(-e "$opt")
    done
    for opt in "${kDisabled[@]}"; do
        enable+=(-d "$opt")
    done
    for opt in "${kValues[@]}"; do
        enable+=(--set-val "${opt%%=*}" "${opt#*=}")
    done
    # nice: the machines that run this are shared; the build is not urgent.
    local -a run=(nice -n 19)
    (
        set -euo pipefail
        cd "$dir"
        "${run[@]}" tar xJf "$kSourceTarball"
        cd linux-source-6.1
        patch -p1 --quiet <"$kPatch"
        "${run[@]}" make ARCH=um defconfig
        ./scripts/config "${enable[@]}"
        "${run[@]}" make ARCH=um olddefconfig
        "${run[@]}" make ARCH=um -j"$(nproc)" linux
        strip -o "$dir/linux" linux
        cp .config "$dir/config"
    ) >>"$log" 2>&1
}

# Fails unless every option in kOptions is =y in the .config at $1.
verify_config() {
    local config=$1 opt missing=()
    for opt in "${kOptions[@]}"; do
        grep -qx "CONFIG_${opt}=y" "$config" || missing+=("$opt")
    done
    if ((${#missing[@]})); then
        echo "uml_kernel.sh: not built in (=y) after olddefconfig:" \
            "${missing[*]}" >&2
        return 1
    fi
    for opt in "${kDisabled[@]}"; do
        grep -qx "CONFIG_${opt}=y" "$config" || continue
        echo "uml_kernel.sh: still on after olddefconfig: $opt" >&2
        return 1
    done
}

main() {
    [[ -r $kSourceTarball ]] ||
        die "$kSourceTarball missing: apt-get install $kSourcePackage flex bison bc"
    local version
    version=$(dpkg-query -W -f='${Version}' "$kSourcePackage") ||
        die "cannot read the version of $kSourcePackage"

    local key
    key=$(
        {
            printf "%s\n" "${kOptions[@]}" "${kValues[@]}" "off: ${kDisabled[*]}"
            echo "$kSourcePackage $version"
            declare -f build_kernel
            cat "$kPatch"
        } | sha256sum | cut -c1-16
    )
    local root
    root=$(cache_root uml) || die "no cache directory"
    cached_build "$root" "$key" linux publish_kernel uml_kernel.sh ||
        die "see the log above"
}

# cached_build's PRODUCE: $1 work directory, $2 log; publishes linux and config in $1/out.
publish_kernel() {
    local work=$1 log=$2
    echo "uml_kernel.sh: building the UML kernel from $kSourcePackage" \
        "(first run on this machine: 3-8 min on 2 cores); log: $log" >&2
    build_kernel "$work" "$log" && verify_config "$work/config" &&
        mv "$work/linux" "$work/config" "$work/out/" &&
        printf '%s %s\n' "$kSourcePackage" "$(dpkg-query -W -f='${Version}' "$kSourcePackage")" >"$work/out/source"
}

main "$@"
