#!/usr/bin/env bash
# Run a command inside User-Mode Linux, on real SocketCAN and real GPIO.
#
# Usage: tests/hil/run_in_uml.sh [--mem SIZE] [--timeout SECONDS] [--] CMD [ARGS...]
#
# Boots the bench kernel (tests/hil/uml_kernel.sh builds it on first use) with
# the host's filesystem as root (hostfs, read-write), so the tree, the build
# and the venv are all there. Inside, before CMD: /proc, /sys, devtmpfs on
# /dev, configfs, tmpfs on /run and /dev/shm; vcan0 and vcan1 up; a gpio-sim
# chip `alacs-sim` with lines STEP DIR ENABLE LASER HOME END SPARE6 SPARE7
# (offsets 0-7; HOME and END at 0, normal travel). CMD runs in the caller's directory
# with the caller's environment plus
#   ALACS_GPIO_CHIP        /dev/gpiochipN of the sim chip
#   ALACS_GPIO_CHIP_LABEL  alacs-sim
#   ALACS_GPIO_SIM_DIR     /sys/devices/platform/gpio-sim.N/gpiochipN
#   ALACS_CAN_IFACE        vcan0
#   ALACS_IN_UML           1
# with stdin from /dev/null and stdout/stderr streamed to ours as pipes.
#
# Exit status: CMD's; 124 if the whole run exceeded --timeout (default 600 s);
# 125 if the bench could not be set up or CMD's status was lost.
# ALACS_UML_VERBOSE=1 shows the kernel's boot log on stderr.
set -euo pipefail

readonly kTimeoutStatus=124
readonly kBenchStatus=125
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
readonly here

usage() {
    sed -n '2,/^set -euo/{s/^# \{0,1\}//p}' "${BASH_SOURCE[0]}"
}

die() {
    echo "run_in_uml.sh: $*" >&2
    exit "$kBenchStatus"
}

# The caller's exported environment, as bash source. Bash's own per-shell
# variables are left out.
write_env() {
    local name
    while IFS= read -r name; do
        case $name in
        PWD | OLDPWD | SHLVL | _ | SHELLOPTS | BASHOPTS) continue ;;
        esac
        printf 'export %s=%q\n' "$name" "${!name}"
    done < <(compgen -e)
}

# Directory for UML's guest memory file: tmpfs if it has room (else the host
# page cache writes guest memory back to disk), otherwise the run directory.
pick_memdir() {
    local run=$1 bytes avail
    bytes=$(numfmt --from=iec "$mem")
    if [[ $(stat -f -c %T /dev/shm 2>/dev/null) == tmpfs && -w /dev/shm ]]; then
        avail=$(df -B1 --output=avail /dev/shm | tail -n 1)
        if ((avail > bytes)); then
            mktemp -d /dev/shm/alacs-uml-mem.XXXXXX
            return
        fi
    fi
    echo "$run"
}

# Ends every host process of this run's UML: UML calls setsid(), so neither
# timeout nor a process-group kill reaches its helpers; they all carry our
# unique umid= on their command line.
kill_leftovers() {
    [[ -n ${umid:-} ]] || return 0
    local pids
    pids=$(pgrep -f -- "umid=$umid " || true)
    if [[ -n $pids ]]; then
        # shellcheck disable=SC2086 # one pid per word
        kill -KILL $pids 2>/dev/null || true
    fi
}

# shellcheck disable=SC2317 # trap handler
cleanup() {
    kill_leftovers
    [[ -n ${out_pid:-} ]] && kill "$out_pid" 2>/dev/null
    [[ -n ${err_pid:-} ]] && kill "$err_pid" 2>/dev/null
    [[ -n ${memdir:-} && $memdir != "${run:-}" ]] && rm -rf "$memdir"
    [[ -n ${run:-} ]] && rm -rf "$run"
    return 0
}

# shellcheck disable=SC2317 # trap handler
on_signal() {
    interrupted=$1
    [[ -n ${uml_pid:-} ]] && kill -TERM "$uml_pid" 2>/dev/null
    return 0
}

main() {
    mem=1024M
    local timeout_s=600
    while (($#)); do
        case $1 in
        --mem | --timeout) (($# >= 2)) || die "$1 needs a value" ;;&
        --mem) mem=$2; shift 2 ;;
        --mem=*) mem=${1#*=}; shift ;;
        --timeout) timeout_s=$2; shift 2 ;;
        --timeout=*) timeout_s=${1#*=}; shift ;;
        -h | --help) usage; exit 0 ;;
        --) shift; break ;;
        -*) usage >&2; die "unknown option $1" ;;
        *) break ;;
        esac
    done
    (($#)) || { usage >&2; die "no command given"; }
    [[ $mem =~ ^[1-9][0-9]*[KMG]$ ]] || die "--mem: want e.g. 512M or 2G, got '$mem'"
    [[ $timeout_s =~ ^[1-9][0-9]*$ ]] || die "--timeout: want whole seconds, got '$timeout_s'"

    local kernel
    kernel=$("$here/uml_kernel.sh" | tail -n 1) || die "no UML kernel"
    [[ -x $kernel ]] || die "uml_kernel.sh gave '$kernel', not an executable"

    trap cleanup EXIT
    trap 'on_signal INT' INT
    trap 'on_signal TERM' TERM
    trap 'on_signal HUP' HUP

    # The guest mounts its own /proc, /sys, /dev and /run over the host's:
    # the run directory must live elsewhere to be shared.
    local base
    base=$(cd "${TMPDIR:-/tmp}" && pwd -P)
    case $base/ in
    /proc/* | /sys/* | /dev/* | /run/*) base=/tmp ;;
    esac
    run=$(mktemp -d "$base/alacs-uml-XXXXXX")
    umid=${run##*/}
    # Both travel on the kernel command line, which splits on blanks.
    [[ $run != *[[:space:]]* && $here != *[[:space:]]* ]] ||
        die "$run or $here contains a blank; set TMPDIR or move the tree"
    memdir=$(pick_memdir "$run")

    write_env >"$run/env.sh"
    local -a cmd=("$@")
    {
        declare -p cmd
        printf 'cwd=%q\n' "$(pwd)"
        printf 'umask %s\n' "$(umask)"
    } >"$run/cmd.sh"
    mkdir "$run/uml"

    local -a quiet=(quiet loglevel=0)
    [[ ${ALACS_UML_VERBOSE:-0} == 1 ]] && quiet=(loglevel=7)
    # shellcheck disable=SC2054 # the commas belong to UML's syntax
    local -a args=(
        mem="$mem" umid="$umid" uml_dir="$run/uml"
        root=/dev/root rootfstype=hostfs rootflags=/ rw
        # No input anywhere (CI has no stdin); the console (kernel, init and
        # CMD's stderr) to stderr, the guest's /dev/tty1 (CMD's stdout) to
        # stdout. One host fd cannot back two UML lines.
        con=null ssl=null con0=null,fd:2 con1=null,fd:1
        "${quiet[@]}"
        init="$here/uml_init.sh" ALACS_UML_RUN="$run"
    )

    # UML makes its console fds non-blocking; give it pipes of its own so
    # the caller's stdout and stderr are left as they were.
    mkfifo "$run/stdout" "$run/stderr"
    cat "$run/stdout" &
    out_pid=$!
    cat "$run/stderr" >&2 &
    err_pid=$!

    # A panicking UML abort()s: no core files in the caller's directory.
    ulimit -c 0
    local start=$SECONDS rc
    [[ -z ${interrupted:-} ]] || die "interrupted by SIG$interrupted"
    TMPDIR=$memdir timeout --kill-after=10 "$timeout_s" "$kernel" "${args[@]}" \
        </dev/null >"$run/stdout" 2>"$run/stderr" &
    uml_pid=$!
    # wait returns early when a trapped signal arrives; wait again then.
    while :; do
        rc=0
        wait "$uml_pid" || rc=$?
        kill -0 "$uml_pid" 2>/dev/null || break
    done
    kill_leftovers
    wait "$out_pid" "$err_pid" || true
    out_pid='' err_pid=''

    if [[ -n ${interrupted:-} ]]; then
        echo "run_in_uml.sh: interrupted by SIG$interrupted" >&2
        case $interrupted in
        INT) exit 130 ;; TERM) exit 143 ;; *) exit 129 ;;
        esac
    fi
    if [[ -s $run/setup-error ]]; then
        die "bench setup failed inside UML: $(<"$run/setup-error")"
    fi
    local timed_out=0
    if ((rc == 124 || (rc == 137 && SECONDS - start >= timeout_s))); then
        timed_out=1
    fi
    if [[ -s $run/status ]]; then
        local status
        status=$(<"$run/status")
        [[ $status =~ ^[0-9]+$ ]] || die "garbled status '$status' from inside UML"
        ((timed_out)) && echo "run_in_uml.sh: command finished" \
            "(status $status) but UML did not halt within ${timeout_s} s" >&2
        exit "$status"
    fi
    if ((timed_out)); then
        echo "run_in_uml.sh: timed out after ${timeout_s} s (--timeout):" \
            "${cmd[*]}" >&2
        exit "$kTimeoutStatus"
    fi
    die "UML exited (status $rc) without reporting the status of: ${cmd[*]}" \
        "(kernel panic? rerun with ALACS_UML_VERBOSE=1)"
}

main "$@"
