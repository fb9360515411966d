# shellcheck shell=bash
# Sourced, not run: the cache of one-time builds (kernels, root file systems) that the
# test scripts share, outside the work tree so that a clean clone reuses them.
#
#   root=$(cache_root [SUBDIR])    ${ALACS_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/alacs}[/SUBDIR],
#                                  created, as an absolute path
#   cached_build ROOT NAME ARTIFACT PRODUCE WHO
#                                  prints ROOT/NAME/ARTIFACT, building it first when absent
#
# NAME carries the key (a hash of the recipe: tests/hil/uml_kernel.sh,
# tests/board/build_kernel.sh, tests/board/build_rootfs.sh), so a changed recipe builds
# anew and the old build is left behind. `PRODUCE WORK LOG` builds into WORK/out every file
# to publish (an empty directory it is given), logging to LOG; it returns non-zero on
# failure. One build per NAME at a time (flock on ROOT/NAME.lock; a second caller waits and
# then takes the first one's result). Published by renaming WORK/out to ROOT/NAME, so
# ROOT/NAME only ever appears complete and the fast path needs no lock. WHO prefixes the
# progress lines on stderr; only stdout's last line is meant for callers.

cache_root() {
    local root=${ALACS_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/alacs}${1:+/$1}
    mkdir -p "$root" || {
        echo "cannot create the cache directory $root" >&2
        return 1
    }
    (cd "$root" && pwd -P)
}

cached_build() {
    local root=$1 name=$2 artifact=$3 produce=$4 who=$5
    local final=$root/$name
    if [[ -e $final/$artifact ]]; then
        echo "$final/$artifact"
        return 0
    fi
    local lock_fd
    exec {lock_fd}>"$root/$name.lock"
    if ! flock -n "$lock_fd"; then
        echo "$who: waiting for another build of $name to finish" >&2
        flock "$lock_fd"
    fi
    # Another caller may have built it while this one waited.
    if [[ -e $final/$artifact ]]; then
        echo "$final/$artifact"
        return 0
    fi
    local work
    work=$(mktemp -d "$root/build.$name.XXXXXX")
    # shellcheck disable=SC2064 # expand $work now: it is local to this function.
    trap "rm -rf '$work'" EXIT
    mkdir "$work/out"
    local log=$root/$name.build.log
    : >"$log"
    local start=$SECONDS
    if ! "$produce" "$work" "$log"; then
        tail -n 40 "$log" >&2
        echo "$who: build of $name failed; full log: $log" >&2
        return 1
    fi
    printf 'built in %d s\n' $((SECONDS - start)) >>"$work/out/source"
    mv -T "$work/out" "$final"
    echo "$who: built in $((SECONDS - start)) s: $final/$artifact" >&2
    echo "$final/$artifact"
}
