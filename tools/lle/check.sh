#!/usr/bin/env bash
# LLE checks for CI (tests/run calls this; the unit tests run with the others, the fuzzer
# in tests/fuzz/lle/run.sh):
#   1. the numpy paper method (tools/paper_lle) = the C++ paper path, bit for bit (pytest)
#   2. the twin's LLE benchmark sets (alacs-twin generate --set lle: 100 lab, 200 outdoor,
#      100 full-sun cases, and 100 full-sun cases behind the camera's optional 635 nm
#      band-pass filter; occluded and free, 0.8-1.6 m) through alacs_lle_eval: fixed
#      point within 1/64 px of the float reference and SIMD = scalar on every case (it
#      exits non-zero otherwise); the accuracy table is printed, not judged
#   3. the command: JSON and overlay for an image, a scan directory (the twin's), refusals
#   4. the speed benchmark (alacs_lle_bench): printed, never a failure
# Builds Release into build/lle-ci (or $ALACS_LLE_BUILD: tests/run shares its Release build). Usage: tools/lle/check.sh [--junit-dir DIR]
# Ends with one line: "lle: N passed, N failed". About 3 min on 2 cores from scratch.
set -uo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root"
junit=""
[[ ${1:-} == --junit-dir ]] && junit=${2:-}
build=${ALACS_LLE_BUILD:-build/lle-ci}
py="$root/.venv/bin/python"
[[ -x $py ]] || py=python3
passed=0
failed=0
pass() { passed=$((passed + 1)); echo "lle: ok   $*"; }
fail() { failed=$((failed + 1)); echo "lle: FAIL $*"; }
finish() { echo; echo "lle: $passed passed, $failed failed"; ((failed == 0)); exit; }
step() { printf '\n=== %s\n' "$*"; }

step "build (Release, $build)"
if cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release >"$root/build/lle-ci-configure.log" 2>&1 &&
  nice ninja -C "$build" alacs_lle alacs_lle_eval alacs_lle_bench alacs-twin >"$root/build/lle-ci-build.log" 2>&1; then
  pass "build"
else
  tail -30 "$root/build/lle-ci-build.log" "$root/build/lle-ci-configure.log" 2>/dev/null
  fail "build (build/lle-ci-build.log)"
  finish
fi
bin="$build/tools/lle"

step "numpy paper method vs the C++ paper path"
args=(-q tools/paper_lle/tests -p no:cacheprovider --rootdir tools/paper_lle)
[[ -n $junit ]] && args+=(--junitxml="$junit/lle-paper.xml")
if ALACS_LLE="$root/$bin/alacs_lle" "$py" -m pytest "${args[@]}"; then pass "paper_lle pytest"; else fail "paper_lle pytest"; fi

step "the twin's benchmark sets: fixed point vs float reference, SIMD vs scalar, accuracy"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
twin="$build/tools/twin/alacs-twin"
if "$twin" generate --set lle --lighting lab --count 100 --out "$tmp/lab" --jobs "$(nproc)" >/dev/null &&
  "$twin" generate --set lle --count 200 --out "$tmp/outdoor" --jobs "$(nproc)" >/dev/null &&
  "$twin" generate --set lle --lighting sun --count 100 --out "$tmp/sun" --jobs "$(nproc)" >/dev/null &&
  "$twin" generate --set lle --lighting sun --count 100 --bandpass-nm 10 --out "$tmp/sun-bp10" --jobs "$(nproc)" >/dev/null; then
  pass "alacs-twin generate --set lle (500 cases, 100 of them full sun behind a 635 nm band-pass filter)"
else
  fail "alacs-twin generate"
  finish
fi
if "$bin/alacs_lle_eval" --set-dir "$tmp/lab" --set-dir "$tmp/outdoor" --set-dir "$tmp/sun" --jobs "$(nproc)" \
  >"$tmp/eval.txt" 2>"$tmp/eval.err"; then
  pass "alacs_lle_eval: fixed = float within 1/64 px, SIMD = scalar on every case"
else
  fail "alacs_lle_eval (see below)"
fi
cat "$tmp/eval.txt"
if "$bin/alacs_lle_eval" --set-dir "$tmp/sun-bp10" --jobs "$(nproc)" >"$tmp/eval-bp.txt" 2>"$tmp/eval-bp.err"; then
  pass "alacs_lle_eval, full sun with the band-pass filter: fixed = float, SIMD = scalar"
else
  fail "alacs_lle_eval, full sun with the band-pass filter"
fi
grep -E '^(method|ours|paper) +(cases|sun)' "$tmp/eval-bp.txt"

step "the command"
# The first laser-on frame: a scan begins with its metering frames (laser off, tag "meter").
case0="$tmp/lab/lle_0000/$("$py" -c "import json,sys; print(next(f['file'] for f in json.load(open(sys.argv[1]))['frames'] if f['laser_on']))" "$tmp/lab/lle_0000/manifest.json")"
if "$bin/alacs_lle" "$case0" --json "$tmp/one.json" --overlay "$tmp/one.png" >/dev/null &&
  "$py" - "$tmp/one.json" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
rows = d["rows"]
assert len(rows) == d["roi"][3], "one entry per ROI row"
assert all(("column" in r and "confidence" in r and "valid" in r) for r in rows)
assert any(r["valid"] for r in rows) and any(not r["valid"] for r in rows)
assert d["polynomial"]["valid"] and len(d["polynomial"]["coeffs"]) == d["polynomial"]["order"] + 1
PY
then pass "alacs_lle IMAGE -> JSON + overlay"; else fail "alacs_lle IMAGE"; fi
if "$bin/alacs_lle" --scan "$tmp/outdoor/lle_0007" --out "$tmp/scan-out" >/dev/null &&
  "$py" -c "import json,sys; s=json.load(open(sys.argv[1])); assert s['processed']==1 and s['frames'][0]['line_valid']" \
    "$tmp/scan-out/summary.json"; then
  pass "alacs_lle --scan DIR (a twin scan directory: manifest ROI)"
else
  fail "alacs_lle --scan DIR"
fi
# Sunlit scans with their laser-off frame subtracted: the one at the laser frame's exposure
# (the daemon's), and the matched filter for the rows the rerun leaves (on by default;
# alacsd runs it only where its metering found direct sun) finds rows that 0 does not.
valid_rows() {  # OUT SCANS: the laser-on frames' valid rows, summed, after checking what each subtracted
  "$py" - "$1" "$2" <<'PY'
import glob, json, os, sys
out, scans = sys.argv[1], sys.argv[2]
n = 0
for f in sorted(glob.glob(out + "/*/frame_*.json")):
    d = json.load(open(f))
    m = json.load(open(os.path.join(scans, "lle_000" + os.path.basename(os.path.dirname(f)), "manifest.json")))
    by_file = {fr["file"]: fr for fr in m["frames"]}
    on, off = by_file[d["image"]], by_file.get(d["laser_off"] or "")
    assert off is not None and not off["laser_on"], f + ": no laser-off frame subtracted"
    assert off["exposure_us"] == on["exposure_us"], f + ": subtracted at another exposure"
    n += sum(r["valid"] for r in d["rows"])
print(n)
PY
}
mf_failed=0
for mf in 0 1; do
  for k in 0 1 2 3 4 5 6 7; do
    "$bin/alacs_lle" --scan "$tmp/sun/lle_000$k" --out "$tmp/sun-mf$mf/$k" --subtract-off --matched-filter "$mf" \
      >/dev/null 2>"$tmp/sun-mf$mf-$k.err" || mf_failed=$((mf_failed + 1))
  done
done
rows0=$(valid_rows "$tmp/sun-mf0" "$tmp/sun") rows1=$(valid_rows "$tmp/sun-mf1" "$tmp/sun")
if ((mf_failed == 0)) && [[ -n $rows0 && -n $rows1 ]] && ((rows1 > rows0)); then
  pass "alacs_lle --scan --subtract-off in sun: valid rows $rows0 without the matched filter, $rows1 with it"
else
  fail "alacs_lle --scan --subtract-off in sun ($mf_failed runs failed; rows: '$rows0' without the matched filter, '$rows1' with it)"
  cat "$tmp"/sun-mf*.err
fi
refused=0
"$bin/alacs_lle" "$tmp/missing.png" --overlay none 2>/dev/null; [[ $? -eq 1 ]] && refused=$((refused + 1))
"$bin/alacs_lle" "$case0" --roi 0,0,99999,10 --overlay none 2>/dev/null; [[ $? -eq 1 ]] && refused=$((refused + 1))
"$bin/alacs_lle" "$case0" --roi 0,0,0,0 --overlay none 2>/dev/null; [[ $? -eq 1 ]] && refused=$((refused + 1))
"$bin/alacs_lle" "$case0" --step 99 --overlay none 2>/dev/null; [[ $? -eq 1 ]] && refused=$((refused + 1))
# A laser-off frame of another size (the 1.6 m case's crop is smaller than the 0.8 m one's).
"$bin/alacs_lle" "$case0" --laser-off "$tmp/lab/lle_0004/frames/frame_0000.png" --overlay none 2>/dev/null
[[ $? -eq 1 ]] && refused=$((refused + 1))
"$bin/alacs_lle" --bogus 2>/dev/null; [[ $? -eq 2 ]] && refused=$((refused + 1))
if ((refused == 6)); then pass "bad input refused with exit 1 (usage 2)"; else fail "bad input: $refused of 6 refused"; fi

step "speed (a benchmark: printed, not judged)"
"$build/tools/bench/alacs_lle_bench" --frames 200 || echo "(the benchmark could not run)"
finish
