#!/usr/bin/env bash
# Runs alacs-eval from the source tree with the project's venv (no install needed).
#   tools/eval/run.sh report            full evaluation -> docs/evaluation.md, docs/figures/eval_*.png
#   tools/eval/run.sh report --small    the CI set -> build/eval-small/
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
export PYTHONPATH="$root/tools/eval/src${PYTHONPATH:+:$PYTHONPATH}"
exec "$root/.venv/bin/python" -m alacs_eval "$@"
