#!/usr/bin/env bash
# The virtual board (docs/board.md): boots the appliance as shipped on an emulated arm64
# board and runs the board tests from the harness side of its CAN bus. Ends with one line
# "board: N passed, N failed"; the exit status is non-zero on any failure.
#
# Usage: tests/board/run.sh
#   ALACS_BOARD_BREAK=no-execstoppost  stage the unit without its ExecStopPost (a test must fail)
#   ALACS_TWIN=path                    the host's alacs-twin (default: build/release's, built here)
#   ALACS_BOARD_TIMEOUT=seconds        the whole boot and test run (default 1800)
#   ALACS_BOARD_TESTS=name,name        run only these harness tests (harness.py's function names)
#
# 1. tests/board/build_kernel.sh and build_rootfs.sh: the kernel and the Debian 12 arm64
#    root file system, built once and cached (keyed by their recipes).
# 2. tests/board/stage.sh: the aarch64 cross build installed with `cmake --install`, plus
#    firmware/'s files, as the Yocto recipe lays them out, into build/board-run/stage.
# 3. The recorded scan: a twin scan directory made on this host, with its x86 result
#    (`alacs-twin process`, the same pipeline offline) for the harness to compare with;
#    its calibration installed as the sensor's (/var/lib/alacs/calibration.json).
# 4. The board's own files (tests/board/rootfs: the gpio-sim header chip, the replay
#    drop-in, the harness and its unit) and the harness's Python packages.
# 5. All of it written into a per-run copy of the cached image with debugfs (no mount).
# 6. qemu-system-aarch64 -M virt, two kvaser_pci controllers on one can-bus (can0 the
#    sensor's, can1 the harness's); the harness's result lines come back through a virtio
#    console (/dev/hvc0 -> build/board-run/results.txt), the serial console goes to
#    build/board-run/console.log.
set -uo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root" || exit 1
run=$root/build/board-run
timeout_s=${ALACS_BOARD_TIMEOUT:-1800}
twin=${ALACS_TWIN:-$root/build/release/tools/twin/alacs-twin}
now() { date +%s.%N; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }
die() { echo "board: $*" >&2; echo "board: 0 passed, 1 failed"; exit 1; }

sudo=()
[[ $(id -u) -eq 0 ]] || sudo=(sudo)
missing=()
for t in qemu-system-aarch64:qemu-system-arm debootstrap:debootstrap debugfs:e2fsprogs aarch64-linux-gnu-gcc:gcc-aarch64-linux-gnu; do
  command -v "${t%%:*}" >/dev/null || missing+=("${t#*:}")
done
[[ -r /usr/src/linux-source-6.1.tar.xz ]] || missing+=(linux-source-6.1 flex bison bc)
if ((${#missing[@]})); then
  echo "board: installing ${missing[*]}" >&2
  DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -q --no-install-recommends \
    -o DPkg::Lock::Timeout=600 "${missing[@]}" >/dev/null || die "apt-get install ${missing[*]}"
fi

t=$(now)
kernel=$(tests/board/build_kernel.sh | tail -n 1) || die "no kernel"
echo "board: kernel $kernel ($(since "$t") s)" >&2
t=$(now)
rootfs=$(tests/board/build_rootfs.sh | tail -n 1) || die "no root file system"
echo "board: rootfs $rootfs ($(since "$t") s)" >&2

rm -rf "$run" && mkdir -p "$run"
stage=$run/stage
t=$(now)
tests/board/stage.sh "$stage" >"$run/stage.log" 2>&1 || { tail -n 30 "$run/stage.log"; die "stage.sh failed ($run/stage.log)"; }
echo "board: staged ($(since "$t") s)" >&2

if [[ ${ALACS_BOARD_BREAK:-} == no-execstoppost ]]; then
  echo "board: ALACS_BOARD_BREAK=no-execstoppost: the unit is staged without ExecStopPost" >&2
  sed -i '/^ExecStopPost=/d' "$stage/usr/lib/systemd/system/alacsd.service"
fi

# The recorded scan and its x86 result, from the host's alacs-twin built from the same
# sources as the board's alacsd (unless ALACS_TWIN names one): a clean clone has none yet,
# and a stale one would compare the board with older code.
if [[ -z ${ALACS_TWIN:-} ]]; then
  t=$(now)
  { cmake -S . -B build/release -G Ninja -DCMAKE_BUILD_TYPE=Release >"$run/twin-build.log" 2>&1 &&
    nice ninja -C build/release alacs-twin >>"$run/twin-build.log" 2>&1; } ||
    { tail -n 30 "$run/twin-build.log"; die "building alacs-twin failed ($run/twin-build.log)"; }
  echo "board: host alacs-twin built ($(since "$t") s)" >&2
fi
[[ -x $twin ]] || die "$twin is not built (cmake --build build/release --target alacs-twin)"
"$twin" generate --set loc --out "$run/twin" --count 1 --distance-mm 1200 --occluded 0 --seed 5 --jobs 1 \
  >"$run/twin.log" 2>&1 || die "alacs-twin generate ($run/twin.log)"
scan=$run/twin/d1200_occ0_0000
# The command carries the rough position at CAN resolution (x, y in mm, z in 10 mm): the
# offline run is planned from the same rounded position.
python3 - "$scan/manifest.json" <<'EOF' || die "manifest"
import json, sys
p = sys.argv[1]
m = json.load(open(p))
r = m["scan"]["rough_mm"]
m["scan"]["rough_mm"] = [round(r[0]), round(r[1]), round(r[2], -1)]
json.dump(m, open(p, "w"))
EOF
"$twin" process "$scan" >"$run/x86.json" 2>"$run/x86.log" || die "alacs-twin process ($run/x86.log)"
python3 - "$scan/manifest.json" "$run/x86.json" "$run/expected.json" <<'EOF' || die "the x86 result"
import json, sys
m = json.load(open(sys.argv[1]))
x = json.loads(open(sys.argv[2]).read().splitlines()[-1])["multi"]
assert x["ok"], x
json.dump({"rough_mm": m["scan"]["rough_mm"], "center_mm": x["center_mm"], "diameter_mm": x["diameter_mm"],
           "approach_mm": x["approach_mm"], "source": "alacs-twin process on x86"}, open(sys.argv[3], "w"))
EOF
mkdir -p "$stage/usr/share/alacs-board" "$stage/var/lib/alacs"
cp -r "$scan" "$stage/usr/share/alacs-board/scan"
cp "$run/expected.json" "$stage/usr/share/alacs-board/expected.json"
# The sensor's own calibration, where firmware/README.md says it goes.
install -m 0640 "$scan/calibration.json" "$stage/var/lib/alacs/calibration.json"

# The board's own files and the harness's Python packages (pure Python, built here).
cp -r tests/board/rootfs/. "$stage/"
mkdir -p "$stage/etc/systemd/system/sysinit.target.wants"
ln -s /etc/systemd/system/board-gpio-sim.service "$stage/etc/systemd/system/sysinit.target.wants/board-gpio-sim.service"
ln -s /etc/systemd/system/board-harness.service "$stage/etc/systemd/system/multi-user.target.wants/board-harness.service"
# (From copies: setuptools leaves a build/ folder beside the sources it builds.)
mkdir -p "$run/py"
cp -r can_protocol/python "$run/py/alacs_can"
cp -r tools/alacs_cli "$run/py/alacs_cli"
python3 -m pip install --quiet --no-deps --no-compile --target "$stage/usr/local/lib/python3.11/dist-packages" \
  "$run/py/alacs_can" "$run/py/alacs_cli" >"$run/pip.log" 2>&1 || die "pip install the harness packages ($run/pip.log)"
# pip's console script names the host's interpreter: the board's is /usr/bin/python3.
mkdir -p "$stage/usr/local/bin"
printf '#!/usr/bin/python3\nimport sys\nfrom alacs_cli.main import main\nsys.exit(main())\n' >"$stage/usr/local/bin/alacs"
chmod 0755 "$stage/usr/local/bin/alacs"
rm -rf "$stage/usr/local/lib/python3.11/dist-packages/bin"

# The per-run disk: the cached image, plus the staged tree written with debugfs.
t=$(now)
cp --sparse=always "$rootfs" "$run/disk.img"
tests/board/e2install.sh "$stage" "$run/disk.img" >"$run/e2install.log" 2>&1 || die "e2install ($run/e2install.log)"
echo "board: per-run image ($(since "$t") s)" >&2

append="console=ttyAMA0 root=/dev/vda rw rootfstype=ext4 panic=-1 systemd.show_status=1 systemd.getty_auto=0"
[[ -n ${ALACS_BOARD_TESTS:-} ]] && append+=" systemd.setenv=BOARD_TESTS=$ALACS_BOARD_TESTS"
t=$(now)
: >"$run/results.txt"
echo "board: booting (console: $run/console.log)" >&2
timeout -s KILL "$timeout_s" qemu-system-aarch64 -M virt -cpu cortex-a72 -smp 2 -m 2048 -nographic -no-reboot -nic none \
  -kernel "$kernel" -append "$append" \
  -drive file="$run/disk.img",format=raw,if=none,id=root -device virtio-blk-pci,drive=root \
  -device virtio-rng-pci \
  -device virtio-serial-pci -chardev file,id=results,path="$run/results.txt" -device virtconsole,chardev=results \
  -object can-bus,id=canbus0 -device kvaser_pci,canbus=canbus0 -device kvaser_pci,canbus=canbus0 \
  </dev/null >"$run/console.log" 2>&1
rc=$?
wall=$(since "$t")
echo "board: QEMU ended (exit $rc) after $wall s" >&2

cat "$run/results.txt"
passed=$(grep -c '^board: ok ' "$run/results.txt")
failed=$(grep -c '^board: FAIL ' "$run/results.txt")
if ! grep -q '^board: done ' "$run/results.txt"; then
  echo "board: FAIL the harness did not finish (QEMU exit $rc; see $run/console.log)"
  tail -n 40 "$run/console.log"
  failed=$((failed + 1))
fi
((passed + failed > 0)) || failed=1
echo "board: figure boot_and_tests_wall_s=$wall"
echo
echo "board: $passed passed, $failed failed"
((failed == 0))
