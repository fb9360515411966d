# Sourced by tools/demo/run.sh: run a noisy step with its output in a log file.
#
# quiet_step LABEL LOG CMD [ARGS...]
#   Runs CMD with stdout and stderr appended to LOG and prints one line to stderr,
#   "demo: LABEL ... done (log: LOG)", its label as the step starts (a first install
#   takes minutes) and the rest when it ends. On failure it prints the log and returns
#   CMD's status, so the demo's own output is not buried under (for example) 1 700 lines
#   of apt.
quiet_step() {
    local label="$1" log="$2"
    shift 2
    mkdir -p "$(dirname "$log")"
    : >"$log"
    printf 'demo: %s ... ' "$label" >&2
    local status=0
    "$@" >>"$log" 2>&1 || status=$?
    if [[ $status -ne 0 ]]; then
        echo "FAILED (exit $status); its output ($log):" >&2
        cat "$log" >&2
        return "$status"
    fi
    echo "done (log: $log)" >&2
}
