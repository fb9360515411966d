#!/bin/bash
# PID 1 of the HIL bench inside User-Mode Linux. Started by run_in_uml.sh as
# init=, never by hand.
#
# Mounts the pseudo filesystems, brings up vcan0/vcan1 and the gpio-sim chip
# `alacs-sim`, then runs the caller's command in the caller's directory with the
# caller's environment, its stdout on /dev/tty1 and its stderr on the console
# (which run_in_uml.sh wires to the host's stdout and stderr), writes its exit
# status to $ALACS_UML_RUN/status and always halts: if PID 1 returned instead,
# the kernel would panic.
#
# Not `set -e`: every failure must still reach the status file and the halt.
set -uo pipefail

# The kernel gives init only HOME and TERM.
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin

# Set on the kernel command line by run_in_uml.sh.
readonly run=${ALACS_UML_RUN:-}
unset ALACS_UML_RUN

# The gpio-sim line table: offset -> name. The only copy; gpio_sim.py and the
# daemon find lines by name through the chip itself.
readonly kGpioLines=(STEP DIR ENABLE LASER HOME END SPARE6 SPARE7)
# Limit switches are normally closed to GND (docs/install.md): in normal travel HOME and
# END read 0 (gpio-sim's default pull-down); a test drives 1 for "switch reached".
readonly kGpioPullUp=()
readonly kGpioLabel=alacs-sim
readonly kSimConfig=/sys/kernel/config/gpio-sim/alacs

power_off() {
    sync
    # systemd's halt with -f calls reboot(2) itself; -d: no wtmp record, which
    # would land in the host's /var/log through hostfs.
    halt -f -d --no-wall >/dev/null 2>&1
    # No systemd halt on this host: the UML kernel has magic SysRq.
    echo o >/proc/sysrq-trigger
    sleep 60
}
trap power_off EXIT

# Records why the bench could not be set up, for the host to report; exits.
setup_failed() {
    echo "uml_init: $*" >&2
    [[ -n $run ]] && echo "$*" >"$run/setup-error"
    exit 1
}

mount_pseudo_filesystems() {
    mount -t proc proc /proc || setup_failed "mount /proc"
    mount -t sysfs sysfs /sys || setup_failed "mount /sys"
    # CONFIG_DEVTMPFS_MOUNT has usually mounted /dev already.
    mountpoint -q /dev || mount -t devtmpfs devtmpfs /dev ||
        setup_failed "mount devtmpfs on /dev"
    mkdir -p /dev/shm /dev/pts
    mount -t tmpfs -o mode=1777,nosuid,nodev shm /dev/shm ||
        setup_failed "mount /dev/shm"
    mount -t devpts -o newinstance,ptmxmode=0666 devpts /dev/pts 2>/dev/null
    mount -t configfs configfs /sys/kernel/config || setup_failed "mount configfs"
    # The host's /run (sockets, pid files of host daemons) means nothing here.
    mount -t tmpfs -o mode=0755,nosuid,nodev run /run || setup_failed "mount /run"
}

setup_can() {
    ip link set dev lo up || setup_failed "lo up"
    ip link add dev vcan0 type vcan || setup_failed "add vcan0"
    ip link set dev vcan0 txqueuelen 1000 up || setup_failed "vcan0 up"
    ip link add dev vcan1 type vcan || setup_failed "add vcan1"
    ip link set dev vcan1 up || setup_failed "vcan1 up"
}

# Writes $2 to the file $1, failing the setup if the kernel refuses it.
put() {
    echo "$2" >"$1" || setup_failed "write '$2' to $1"
}

setup_gpio_sim() {
    local bank=$kSimConfig/bank0 i name
    mkdir "$kSimConfig" "$bank" || setup_failed "mkdir $bank (CONFIG_GPIO_SIM?)"
    put "$bank/num_lines" "${#kGpioLines[@]}"
    put "$bank/label" "$kGpioLabel"
    for i in "${!kGpioLines[@]}"; do
        mkdir "$bank/line$i" || setup_failed "mkdir $bank/line$i"
        put "$bank/line$i/name" "${kGpioLines[i]}"
    done
    put "$kSimConfig/live" 1

    local chip dev
    chip=$(<"$bank/chip_name") || setup_failed "read $bank/chip_name"
    dev=$(<"$kSimConfig/dev_name") || setup_failed "read $kSimConfig/dev_name"
    sim_dir=/sys/devices/platform/$dev/$chip
    [[ -c /dev/$chip ]] || setup_failed "/dev/$chip missing"
    for name in "${kGpioPullUp[@]}"; do
        for i in "${!kGpioLines[@]}"; do
            [[ ${kGpioLines[i]} == "$name" ]] && put "$sim_dir/sim_gpio$i/pull" pull-up
        done
    done
    gpio_chip=/dev/$chip
}

# Output through a tty gets "\n" -> "\r\n" unless output processing is off.
raw_tty() {
    stty -F "$1" -opost 2>/dev/null
}

# Runs the caller's command; sets `status`.
run_command() {
    # The caller's environment, command line (cmd), directory (cwd), umask.
    local cwd=''
    local -a cmd=()
    # shellcheck source=/dev/null
    source "$run/env.sh" || setup_failed "source $run/env.sh"
    # shellcheck source=/dev/null
    source "$run/cmd.sh" || setup_failed "source $run/cmd.sh"
    cd "$cwd" || setup_failed "cd $cwd (is it hidden by a mount inside UML?)"

    export ALACS_GPIO_CHIP=$gpio_chip
    export ALACS_GPIO_CHIP_LABEL=$kGpioLabel
    export ALACS_GPIO_SIM_DIR=$sim_dir
    export ALACS_CAN_IFACE=vcan0
    export ALACS_IN_UML=1

    # /dev/tty1 is the host's stdout and /dev/console its stderr. Through
    # pipes, as on a CI host: the command must not see a terminal.
    exec 3>/dev/tty1 || setup_failed "open /dev/tty1"
    raw_tty /dev/tty1
    mkfifo /run/alacs-stdout /run/alacs-stderr || setup_failed "mkfifo in /run"
    cat /run/alacs-stdout >&3 &
    local out_pid=$!
    cat /run/alacs-stderr >&2 &
    local err_pid=$!

    "${cmd[@]}" </dev/null >/run/alacs-stdout 2>/run/alacs-stderr 3>&-
    status=$?
    echo "$status" >"$run/status"

    # A process the command left running may hold the pipes open: wait for
    # the output a little, not forever.
    local i
    for ((i = 0; i < 50; i++)); do
        kill -0 "$out_pid" "$err_pid" 2>/dev/null || break
        sleep 0.1
    done
    kill "$out_pid" "$err_pid" 2>/dev/null
    wait "$out_pid" "$err_pid" 2>/dev/null
    # tcsetattr(TCSADRAIN): returns once the ttys have handed everything to
    # the host, so halting cannot cut the tail of the output.
    raw_tty /dev/tty1
    raw_tty /dev/console
}

main() {
    [[ -n $run && -d $run ]] ||
        setup_failed "ALACS_UML_RUN not set: start this through run_in_uml.sh"
    mount_pseudo_filesystems
    raw_tty /dev/console
    setup_can
    setup_gpio_sim
    run_command
}

main
