# Shared by the adapters' API checks (gpiod_v2_check.sh, libcamera_api_check.sh): each
# compiles one driver of edge/drivers against another version of its library, links a
# small program with it, and prints one ok/FAIL line per version. Sourced, not run.

# Sets the array `warn` to the project's warning flags, read from
# cmake/AlacsWarnings.cmake (ALACS_WARNINGS and ALACS_STRICT_WARNINGS); fails if unread.
project_warnings() {
  mapfile -t warn < <(sed -n '/^set(ALACS_\(STRICT_\)\?WARNINGS/,/)/p' "$root/cmake/AlacsWarnings.cmake" |
    sed -e 's/^set(ALACS_[A-Z_]*//' -e 's/)//' | tr ' ' '\n' | grep '^-W')
  ((${#warn[@]} > 5))
}

# link_smoke OUT LOG OBJECT... -- LINK-ARG...: compiles OUT/smoke.cpp and common/result.cpp
# and links them with the objects and link arguments into OUT/smoke; output to LOG.
link_smoke() {
  local out=$1 log=$2
  shift 2
  local -a objs=()
  while (($#)) && [[ $1 != -- ]]; do objs+=("$1"); shift; done
  (($#)) && shift
  "$cxx" -std=c++20 -O1 -I "$root/edge" -c "$out/smoke.cpp" -o "$out/smoke.o" >>"$log" 2>&1 &&
    "$cxx" -std=c++20 -O1 -I "$root/edge" -c "$root/edge/common/result.cpp" -o "$out/result.o" >>"$log" 2>&1 &&
    "$cxx" -o "$out/smoke" "$out/smoke.o" "${objs[@]}" "$out/result.o" "$@" >>"$log" 2>&1
}

# report OK LOG OK-LINE FAIL-LINE: prints the line for the outcome (after a FAIL, the
# log's errors) and counts a failure in `fails`.
report() {
  if (($1)); then
    echo "$3"
  else
    echo "$4; log: $2"
    grep -E "error|undefined" "$2" | head -20
    fails=$((fails + 1))
  fi
}
