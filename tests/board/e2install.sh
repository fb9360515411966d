#!/usr/bin/env bash
# Write a staged tree into an ext4 image without mounting it (debugfs): directories made
# (existing ones kept), files and symbolic links replaced, each with the staged file's
# mode and owner (debugfs `write` takes them from the source file; directories get
# theirs with `sif`). Then e2fsck checks the image and every staged path is looked up.
#
# Usage: tests/board/e2install.sh STAGE_DIR IMAGE
set -euo pipefail
stage=$(cd "${1:?usage: e2install.sh STAGE_DIR IMAGE}" && pwd -P)
image=$(realpath "${2:?usage: e2install.sh STAGE_DIR IMAGE}")
cmds=$(mktemp)
check=$(mktemp)
trap 'rm -f "$cmds" "$check"' EXIT
cd "$stage"
while IFS= read -r -d '' p; do
  p=${p#.}
  [[ -z $p ]] && continue
  mode=$(stat -c '%a' ".$p")
  if [[ -L .$p ]]; then
    printf 'rm "%s"\nsymlink "%s" "%s"\n' "$p" "$p" "$(readlink ".$p")" >>"$cmds"
  elif [[ -d .$p ]]; then
    printf 'mkdir "%s"\nsif "%s" mode %s\nsif "%s" uid %s\nsif "%s" gid %s\n' \
      "$p" "$p" "$(printf '0%o' $((8#40000 | 8#$mode)))" "$p" "$(stat -c %u ".$p")" "$p" "$(stat -c %g ".$p")" >>"$cmds"
  else
    printf 'rm "%s"\nwrite "%s" "%s"\n' "$p" "$stage$p" "$p" >>"$cmds"
  fi
  printf 'stat "%s"\n' "$p" >>"$check"
done < <(find . -print0 | sort -z)
# Expected noise: the banner, inode numbers, `rm` of a path not there yet, `mkdir` of one
# that is. Anything else is an error.
errors=$(debugfs -w -f "$cmds" "$image" 2>&1 |
  grep -vE '^debugfs|^Allocated inode|File not found by ext2_lookup|directory already exists|^mkdir: |^rm: ' || true)
[[ -z $errors ]] || { echo "e2install.sh: debugfs: $errors"; exit 1; }
e2fsck -fn "$image"
missing=$(debugfs -f "$check" "$image" 2>&1 | grep -c "File not found" || true)
((missing == 0)) || { echo "e2install.sh: $missing staged paths missing from $image"; exit 1; }
echo "e2install.sh: $(wc -l <"$check") paths written into $image"
