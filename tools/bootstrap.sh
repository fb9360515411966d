#!/usr/bin/env bash
# Installs what the demo and the tests need on a fresh Debian 12 machine, only what is
# missing: Debian packages (apt-get, as root or through sudo) and the project's Python
# venv in .venv. Safe to run again; a second run changes nothing and takes a second.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)

apt_packages=(
  build-essential cmake ninja-build pkg-config git
  libopencv-dev libeigen3-dev libpng-dev libgpiod-dev gpiod libcamera-dev libsystemd-dev catch2
  can-utils kmod iproute2
  libcamera-ipa libcamera-tools v4l-utils udev
  user-mode-linux linux-source-6.1 flex bison bc libelf-dev xz-utils
  python3 python3-venv python3-pip
  clang libclang-rt-14-dev clang-format clang-tidy
  nlohmann-json3-dev libcli11-dev
)
missing=()
for p in "${apt_packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "bootstrap: installing Debian packages: ${missing[*]}" >&2
  sudo=()
  [[ $(id -u) -eq 0 ]] || sudo=(sudo)
  "${sudo[@]}" apt-get update -q
  DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -q -o DPkg::Lock::Timeout=600 "${missing[@]}"
fi

venv="$root/.venv"
stamp="$venv/.alacs-stamp"
want=$(cat "$root/tools/requirements.txt" "$root/can_protocol/python/pyproject.toml" \
  "$root/tools/alacs_cli/pyproject.toml" | sha256sum | cut -c1-16)
if [[ ! -x "$venv/bin/python" || ! -f "$stamp" || $(cat "$stamp") != "$want" ]]; then
  echo "bootstrap: preparing the Python venv in .venv" >&2
  python3 -m venv "$venv"
  "$venv/bin/pip" install -q --upgrade pip
  "$venv/bin/pip" install -q -r "$root/tools/requirements.txt"
  "$venv/bin/pip" install -q -e "$root/can_protocol/python" -e "$root/tools/alacs_cli"
  echo "$want" > "$stamp"
fi
