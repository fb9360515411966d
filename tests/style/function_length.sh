#!/usr/bin/env bash
# No function in edge/ is longer than 120 lines. A function's length is lizard's "length":
# its lines from the signature to the closing brace, comments and blank lines included
# (not its NLOC, which leaves those out). Lambdas count towards the function around them.
# Lists each offender as FILE:LINE: NAME: N lines and exits 1; exits 0 when there is none,
# 2 when lizard (tools/requirements.txt) is missing.
# Usage: tests/style/function_length.sh [MAX_LINES]
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root"
max=${1:-120}

if [[ -x $root/.venv/bin/lizard ]]; then
  lizard=("$root/.venv/bin/lizard")
elif command -v lizard >/dev/null; then
  lizard=(lizard)
else
  echo "function length: lizard not found (pip install -r tools/requirements.txt)" >&2
  exit 2
fi

# Every C++ source under edge/ (.inl too, which lizard skips when it walks a folder).
mapfile -t files < <(find edge -type f \( -name '*.h' -o -name '*.hpp' -o -name '*.cpp' -o -name '*.cc' -o -name '*.inl' \) | sort)
# -w: only the functions over a threshold; the other thresholds (complexity, parameters)
# are set out of reach so that length is the only one checked. -i -1: exit 0 regardless,
# the offenders are counted here.
warnings=$("${lizard[@]}" -l cpp -L "$max" -C 1000000 -a 1000000 -i -1 -w "${files[@]}")
offenders=$(sed -nE 's/^([^:]+:[0-9]+): warning: (.+) has [0-9]+ NLOC, .* ([0-9]+) length, .*/\1: \2: \3 lines/p' <<<"$warnings")
if [[ -n $offenders ]]; then
  echo "$offenders"
  echo "function length: $(wc -l <<<"$offenders") function(s) in edge/ over $max lines"
  exit 1
fi
echo "function length: no function in edge/ over $max lines (${#files[@]} files)"
