#!/usr/bin/env bash
# Print the absolute path of the virtual board's root file system: a Debian 12 (bookworm)
# arm64 ext4 disk image made from the package registry, building it on first use.
#
# Usage: tests/board/build_rootfs.sh
#
# Recipe: `debootstrap --foreign --arch=arm64` on the host (downloads and unpacks only;
# no binfmt_misc needed), the tree written into an ext4 image with `mkfs.ext4 -d` (no
# loop mount), then debootstrap's second stage run inside the board itself
# (qemu-system-aarch64 with tests/board/build_kernel.sh's kernel and
# init=/board-stage2, which runs `debootstrap --second-stage` and the few settings
# below, then powers off). The project is not in it: tests/board/run.sh installs a
# build into a per-run copy.
#
# The image is cached outside the work tree in
#   ${ALACS_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/alacs}/board-rootfs-<key>/rootfs.img
# where <key> hashes the package list, the PyPI pins and the recipe below (as
# tests/hil/uml_kernel.sh keys the UML kernel): editing any of them builds a new image.
# Only stdout's last line is meant for callers; progress goes to stderr and the full
# log to a file whose path is printed when the build fails.
set -euo pipefail
# shellcheck source=tests/lib/cached_build.sh
source "$(dirname "${BASH_SOURCE[0]}")/../lib/cached_build.sh"

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
readonly kSuite=bookworm
readonly kMirror=${ALACS_DEBIAN_MIRROR:-http://deb.debian.org/debian}
readonly kImageSize=3G

# What the board runs besides the project (debootstrap resolves their dependencies):
# systemd (networkd, udevd, journald), the CAN and GPIO tools, Python with python-can for
# the harness, and the shared libraries alacsd links (readelf -d of the aarch64 build:
# OpenCV 4.6 core/imgproc/calib3d, libcamera 0.0.3, libgpiod 1.6, libpng, libsystemd;
# not imgcodecs, whose libgdal alone pulls in about a hundred packages).
readonly kPackages=(
    systemd systemd-sysv udev dbus libnss-systemd iproute2 procps
    can-utils gpiod libgpiod2
    python3 python3-can python3-rich
    libopencv-core406 libopencv-imgproc406 libopencv-calib3d406
    libcamera0.0.3 libpng16-16 libsystemd0 libstdc++6
)
# bookworm has no python3-cantools: the harness's alacs_can and the `alacs` CLI need it,
# so it comes from PyPI (pure Python, plus bitstruct's aarch64 wheel), installed into
# /usr/local with `pip install --target` for cp311/aarch64. Pinned as in the project's
# .venv.
readonly kPyPI=(cantools==45.1.0 bitstruct==8.24.0 textparser==0.26.2 diskcache==5.6.3
    argparse-addons==0.12.0 crccheck==1.3.1)

die() {
    echo "build_rootfs.sh: $*" >&2
    exit 1
}

# The script the board runs as init (PID 1) for the second stage.
stage2_init() {
    cat <<'INIT'
#!/bin/sh
# tests/board/build_rootfs.sh: debootstrap's second stage, run as init inside the board.
export PATH=/usr/sbin:/usr/bin:/sbin:/bin
mount -t proc proc /proc
mount -t sysfs sysfs /sys
mount -t devtmpfs devtmpfs /dev 2>/dev/null
echo "board-stage2: second stage starting"
if /debootstrap/debootstrap --second-stage; then
    echo bookworm-board >/etc/hostname
    printf '127.0.0.1 localhost\n127.0.1.1 bookworm-board\n' >/etc/hosts
    printf '/dev/vda / ext4 rw,errors=remount-ro 0 1\n' >/etc/fstab
    printf 'deb http://deb.debian.org/debian bookworm main\n' >/etc/apt/sources.list
    # The Yocto recipe's GROUPADD_PARAM: the group the udev rule gives /dev/gpiochip* to.
    groupadd --system gpio
    systemctl enable systemd-networkd.service
    # No login on the console and no time sync: the board runs tests and powers off.
    systemctl mask getty@tty1.service serial-getty@ttyAMA0.service systemd-timesyncd.service apt-daily.timer apt-daily-upgrade.timer e2scrub_all.timer fstrim.timer man-db.timer 2>/dev/null
    systemctl set-default multi-user.target
    date -u +%FT%TZ >/etc/board-rootfs.complete
    echo "board-stage2: OK"
else
    echo "board-stage2: FAILED"
    tail -n 40 /debootstrap/debootstrap.log 2>/dev/null
fi
sync
mount -o remount,ro / 2>/dev/null
sync
# init exiting panics the kernel; with panic=-1 and QEMU's -no-reboot that ends QEMU.
# (This script stays on the disk until then: deleting a running init leaves an orphan
# inode and keeps the remount above from succeeding. The host removes it.)
exit 0
INIT
}

# The build recipe. Its text (declare -f) is part of the cache key, so keep every step
# that shapes the image inside this function (and stage2_init above).
# $1: empty build directory; $2: log file. Leaves $1/rootfs.img.
build_rootfs() {
    local dir=$1 log=$2 kernel
    local include
    include=$(IFS=,; echo "${kPackages[*]}")
    (
        set -euo pipefail
        echo "== debootstrap --foreign ($kSuite, arm64)"
        nice -n 19 debootstrap --foreign --arch=arm64 --variant=minbase --include="$include" \
            "$kSuite" "$dir/root" "$kMirror"
        echo "== PyPI for the harness: ${kPyPI[*]}"
        python3 -m pip install --quiet --no-deps --no-compile --target "$dir/root/usr/local/lib/python3.11/dist-packages" \
            --platform manylinux2014_aarch64 --platform manylinux_2_17_aarch64 \
            --python-version 3.11 --implementation cp --only-binary=:all: "${kPyPI[@]}"
        stage2_init >"$dir/root/board-stage2"
        chmod 0755 "$dir/root/board-stage2"
        echo "== mkfs.ext4 -d ($kImageSize)"
        truncate -s "$kImageSize" "$dir/rootfs.img"
        mkfs.ext4 -q -F -L board-root -d "$dir/root" "$dir/rootfs.img"
        rm -rf "$dir/root"
        echo "== second stage inside the board"
        # The kernel is asked for only now: a first build of both overlaps the two.
        kernel=$("$here/build_kernel.sh" | tail -n 1)
        timeout -s KILL 7200 nice -n 19 qemu-system-aarch64 -M virt -cpu cortex-a72 -smp 2 -m 2048 \
            -nographic -no-reboot -nic none -kernel "$kernel" \
            -append "console=ttyAMA0 root=/dev/vda rw rootfstype=ext4 init=/board-stage2 panic=-1" \
            -drive file="$dir/rootfs.img",format=raw,if=none,id=root -device virtio-blk-pci,drive=root \
            -device virtio-rng-pci </dev/null
        echo "== check"
        debugfs -R 'cat /etc/board-rootfs.complete' "$dir/rootfs.img" | grep -q T ||
            { echo "the second stage did not complete"; exit 1; }
        debugfs -w -R 'rm /board-stage2' "$dir/rootfs.img"
        # The board powers off by panicking: replay the journal if the remount did not
        # happen (exit 1 = errors corrected), then the image must be clean.
        e2fsck -fy "$dir/rootfs.img" || (($? == 1))
        e2fsck -fn "$dir/rootfs.img"
    ) >>"$log" 2>&1
}

main() {
    local tool
    for tool in debootstrap qemu-system-aarch64 mkfs.ext4 debugfs; do
        command -v "$tool" >/dev/null ||
            die "$tool missing: apt-get install debootstrap qemu-system-arm e2fsprogs"
    done
    python3 -m pip --version >/dev/null 2>&1 || die "pip missing: apt-get install python3-pip"
    local key
    key=$(
        {
            echo "$kSuite $kMirror $kImageSize"
            printf "%s\n" "${kPackages[@]}" "${kPyPI[@]}"
            declare -f stage2_init build_rootfs
        } | sha256sum | cut -c1-16
    )
    local root
    root=$(cache_root "") || die "no cache directory"
    cached_build "$root" "board-rootfs-$key" rootfs.img publish_rootfs build_rootfs.sh ||
        die "see the log above"
}

# cached_build's PRODUCE: $1 work directory, $2 log; publishes rootfs.img in $1/out.
publish_rootfs() {
    local work=$1 log=$2
    echo "build_rootfs.sh: building the board root file system (debootstrap from" \
        "$kMirror, second stage under TCG: tens of minutes on 2 cores); log: $log" >&2
    build_rootfs "$work" "$log" && mv "$work/rootfs.img" "$work/out/"
}

main "$@"
