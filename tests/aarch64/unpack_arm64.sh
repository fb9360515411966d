#!/usr/bin/env bash
# Unpack arm64 -dev packages (and what apt would add with them) into a private root, not
# installed: the cross builds (tests/aarch64/run.sh, tests/board/stage.sh) link against it
# where Debian's arm64 packages cannot be co-installed with the host's (see run.sh).
#
# Usage: tests/aarch64/unpack_arm64.sh DIR PACKAGE...
#
# Done once: DIR/.complete marks a finished root and the callers share it. A -dev symlink
# whose library is installed on the host (not unpacked here) dangles: it is pointed at the
# host's copy. No static archives: the board runs what is linked dynamically.
set -euo pipefail
dir=${1:?usage: unpack_arm64.sh DIR PACKAGE...}
shift
(($#)) || { echo "unpack_arm64.sh: no packages given" >&2; exit 2; }
triplet=aarch64-linux-gnu
[[ -f $dir/.complete ]] && exit 0
rm -rf "$dir" && mkdir -p "$dir/debs"
# What apt would add to install them here = what the private root needs.
mapfile -t debs < <(apt-get install -s --no-install-recommends "$@" 2>/dev/null |
  awk '$1 == "Inst" {print $2}' | grep ':arm64$')
((${#debs[@]})) || {
  echo "unpack_arm64.sh: apt cannot resolve $* (dpkg --add-architecture arm64; apt-get update)" >&2
  exit 1
}
echo "unpacking ${#debs[@]} packages into $dir: ${debs[*]}" >&2
# (apt-get download as root warns that the download is unsandboxed: kept in the log.)
(cd "$dir/debs" && apt-get download -q "${debs[@]}" >"$dir/download.log" 2>&1) ||
  { cat "$dir/download.log" >&2; echo "unpack_arm64.sh: apt-get download failed" >&2; exit 1; }
for d in "$dir"/debs/*.deb; do dpkg-deb -x "$d" "$dir"; done
find "$dir/usr/lib" -name '*.a' -delete
while IFS= read -r link; do
  target=/usr/lib/$triplet/$(readlink "$link")
  if [[ -e $target ]]; then ln -sf "$target" "$link"; fi
done < <(find "$dir/usr/lib" -xtype l)
touch "$dir/.complete"
