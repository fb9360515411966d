#!/usr/bin/env bash
# The house rules (.clang-format, .clang-tidy) on the code a change touches: the C++ lines
# that differ between BASE and the working tree (edge/, tests/, tools/). Old code is held
# to them only once it is edited, so the check costs seconds per changed file, not a pass
# over the whole tree. clang-format: `git clang-format --diff` on the changed lines.
# clang-tidy: each changed .cpp (and the .cpp beside a changed header) with a line filter of
# the changed lines, compile flags from a configure-only build (build/style-tidy).
# BASE: $ALACS_STYLE_BASE, else the merge base with origin/main, else HEAD~1 (the last
# commit, as CI sees a push), always with the uncommitted changes on top.
# Exits 1 listing what to fix; 2 when clang-format/clang-tidy are missing (Debian:
# clang-format clang-tidy, installed by tools/bootstrap.sh).
# Usage: tests/style/format_tidy.sh [BASE]
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root"
for tool in clang-format git-clang-format clang-tidy; do
  command -v "$tool" >/dev/null || { echo "format/tidy: $tool not found (apt-get install clang-format clang-tidy)"; exit 2; }
done
base=${1:-${ALACS_STYLE_BASE:-}}
if [[ -z $base ]]; then
  if git rev-parse -q --verify origin/main >/dev/null; then base=$(git merge-base HEAD origin/main); else base=HEAD~1; fi
fi
paths=('edge/*.h' 'edge/*.cpp' 'edge/*.inl' 'tests/*.h' 'tests/*.cpp' 'tools/*.h' 'tools/*.cpp')
mapfile -t changed < <(git diff --name-only --diff-filter=ACMR "$base" -- "${paths[@]}")
if ((${#changed[@]} == 0)); then
  echo "format/tidy: no C++ changed since $(git rev-parse --short "$base")"
  exit 0
fi
failed=0

# clang-format, on the changed lines only.
fmt=$(git clang-format --diff --extensions h,cpp,inl "$base" -- "${changed[@]}" 2>&1 || true)
if grep -q '^diff ' <<<"$fmt"; then
  echo "$fmt"
  echo "format/tidy: clang-format would change the lines above (git clang-format $base)"
  failed=1
fi

# clang-tidy, on the changed lines of the translation units that hold them.
build=build/style-tidy
mkdir -p "$build"
cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release >"$build/configure.log" 2>&1 ||
  { cat "$build/configure.log"; echo "format/tidy: configure failed"; exit 1; }
python3 - "$base" "$build" "${changed[@]}" >"$build/units.txt" <<'EOF'
import json, os, re, subprocess, sys

base, build, changed = sys.argv[1], sys.argv[2], sys.argv[3:]
db = {os.path.realpath(e["file"]) for e in json.load(open(os.path.join(build, "compile_commands.json")))}
ranges = {}
diff = subprocess.run(["git", "diff", "-U0", base, "--", *changed], capture_output=True, text=True, check=True).stdout
path = None
for line in diff.splitlines():
    if line.startswith("+++ "):
        path = line[6:] if line.startswith("+++ b/") else None
    m = re.match(r"@@ -\S+ \+(\d+)(?:,(\d+))? @@", line)
    if m and path:
        start, count = int(m.group(1)), int(m.group(2) or "1")
        if count:
            ranges.setdefault(path, []).append([start, start + count - 1])
# Headers are seen through their component's include root (build/include/<target>/<folder>/x.h,
# cmake/AlacsWarnings.cmake); clang-tidy matches a filter's name against the end of a path,
# so a header's name is given without its edge/ prefix.
line_filter = [{"name": p[len("edge/"):] if p.startswith("edge/") else p, "lines": r} for p, r in ranges.items()]
units = set()
for p in ranges:
    stem, ext = os.path.splitext(os.path.realpath(p))
    for candidate in ([stem + ".cpp"] if ext in (".h", ".inl") else [stem + ext]):
        if candidate in db:
            units.add(candidate)
filt = json.dumps(line_filter, separators=(",", ":"))
for u in sorted(units):
    print(f"{filt}\t{u}")
EOF
if [[ -s $build/units.txt ]]; then
  # --quiet, and only the diagnostics (clang-tidy also prints how many it suppressed).
  tidy_out=$(while IFS=$'\t' read -r filter unit; do printf '%s\0%s\0' "$filter" "$unit"; done <"$build/units.txt" |
    xargs -0 -n 2 -P "$(nproc)" sh -c 'clang-tidy -p "$0" --quiet --extra-arg=-Wno-unknown-warning-option \
      --header-filter=".*" --line-filter="$1" "$2" 2>/dev/null || echo "clang-tidy failed: $2"' "$build" ||
    true)
  if grep -qE 'error:|clang-tidy failed' <<<"$tidy_out"; then
    echo "$tidy_out"
    echo "format/tidy: clang-tidy found the above in changed lines"
    failed=1
  fi
fi
units=$(wc -l <"$build/units.txt")
if ((failed)); then exit 1; fi
echo "format/tidy: ${#changed[@]} changed C++ file(s) since $(git rev-parse --short "$base"): formatted; clang-tidy clean on $units translation unit(s)"
