#!/usr/bin/env bash
# Static checks of the appliance: device-tree overlays, systemd units, the default config,
# the Yocto layer and the kas files. Installs what it needs first (apt: device-tree-compiler,
# systemd; pip into .venv: oelint-adv, kas, jsonschema); a second run installs nothing.
# Ends with one line: "appliance: N passed, N failed". See docs/appliance.md.
set -uo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd -P)
cd "$root"
max_exposure=${ALACS_MAX_EXPOSURE:-2.0}   # systemd-analyze security: fail above this
passed=0
failed=0
pass() { passed=$((passed + 1)); echo "appliance: ok   $*"; }
fail() { failed=$((failed + 1)); echo "appliance: FAIL $*"; }
finish() { echo; echo "appliance: $passed passed, $failed failed"; ((failed == 0)); exit; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# ------------------------------------------------------------------ tools
sudo=()
[[ $(id -u) -eq 0 ]] || sudo=(sudo)
need_apt=()
command -v dtc >/dev/null || need_apt+=(device-tree-compiler)
command -v systemd-analyze >/dev/null || need_apt+=(systemd)
[[ -x $root/.venv/bin/python ]] || python3 -c 'import ensurepip' 2>/dev/null || need_apt+=(python3-venv)
if ((${#need_apt[@]})); then
  echo "installing: ${need_apt[*]}"
  "${sudo[@]}" apt-get update -q -o DPkg::Lock::Timeout=600 >/dev/null
  DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -q --no-install-recommends \
    -o DPkg::Lock::Timeout=600 "${need_apt[@]}" >"$tmp/apt.log" 2>&1 || { cat "$tmp/apt.log"; fail "apt-get install ${need_apt[*]}"; finish; }
fi
venv=$root/.venv
py=$venv/bin/python
[[ -x $py ]] || python3 -m venv "$venv" || { fail "python3 -m venv .venv"; finish; }
if ! "$py" -c 'import kas.configschema, jsonschema' 2>/dev/null || [[ ! -x $venv/bin/oelint-adv ]]; then
  echo "installing into .venv: oelint-adv kas jsonschema"
  "$venv/bin/pip" install -q oelint-adv kas jsonschema || { fail "pip install oelint-adv kas jsonschema"; finish; }
fi
pass "tools: dtc $(dtc --version | awk '{print $NF}'), systemd $(systemd-analyze --version | awk 'NR==1{print $2}'), oelint-adv $("$venv/bin/oelint-adv" --version 2>/dev/null | awk '{print $NF}'), kas $("$py" -c 'import kas; print(kas.__version__)')"

# ------------------------------------------------------------------ device tree
for dts in firmware/dts/*.dts; do
  if out=$(dtc -@ -I dts -O dtb -o "$tmp/$(basename "${dts%.dts}").dtbo" "$dts" 2>&1) && [[ -z $out ]]; then
    pass "dtc -@: $dts"
  else
    fail "dtc -@: $dts"; echo "$out"
  fi
done
# The GPIO overlay's contract, read back from the compiled blob: each line's name at its
# BCM number, the outputs (LASER among them) pulled down, the limit switches pulled up.
g=$tmp/alacs-gpio-overlay.dtbo
if out=$(dtc -I dtb -O dts "$g" 2>/dev/null | python3 -c '
import re, sys
dts = sys.stdin.read()
want = {"STEP": 17, "DIR": 27, "ENABLE": 22, "LASER": 23, "HOME": 5, "END": 6}
names = re.search(r"gpio-line-names = \"([^;]*)\";", dts).group(1).split("\\0")
errs = [f"{n} is not line {i}" for n, i in want.items() if i >= len(names) or names[i] != n]
def group(label):
    m = re.search(label + r" \{[^}]*brcm,pins = <([^>]*)>;[^}]*brcm,pull = <([^>]*)>;", dts)
    return [int(x, 0) for x in m.group(1).split()], [int(x, 0) for x in m.group(2).split()]
for label, lines, pull in (("alacs_outputs", ("STEP", "DIR", "ENABLE", "LASER"), 1), ("alacs_switches", ("HOME", "END"), 2)):
    pins, pulls = group(label)
    if sorted(pins) != sorted(want[n] for n in lines) or set(pulls) != {pull}:
        errs.append(f"{label}: pins {pins} pull {pulls}")
print("; ".join(errs)); sys.exit(1 if errs else 0)
' 2>&1); then
  pass "overlay: STEP/DIR/ENABLE/LASER/HOME/END named at 17/27/22/23/5/6; outputs pulled down, switches up"
else
  fail "overlay contract: $out"
fi

# ------------------------------------------------------------------ systemd
# verify exits 0 even on unknown keys; any output is a failure. Exec* paths that do not
# exist on this host (/usr/bin/alacsd) are pointed at /bin/true in a temporary copy.
for unit in firmware/systemd/*.service; do
  copy=$tmp/$(basename "$unit")
  sed -E 's#^(Exec[A-Za-z]*=[-@:+!]*)/[^ ]+#\1/bin/true#' "$unit" >"$copy"
  out=$(systemd-analyze verify "$copy" 2>&1)
  rc=$?
  if [[ $rc -eq 0 && -z $out ]]; then pass "systemd-analyze verify: $unit"; else fail "systemd-analyze verify: $unit (exit $rc)"; echo "$out"; fi
  sec=$(systemd-analyze security --offline=yes --no-pager "$copy" 2>&1)
  score=$(sed -nE 's/.*Overall exposure level for [^:]+: ([0-9.]+).*/\1/p' <<<"$sec")
  grep -E '✗' <<<"$sec" | sed -E 's/ {2,}/  /g' | sed 's/^/    /'
  if [[ -z $score ]]; then
    fail "systemd-analyze security: $unit (no score)"; echo "$sec" | tail -5
  elif awk -v s="$score" -v m="$max_exposure" 'BEGIN{exit !(s <= m)}'; then
    pass "systemd-analyze security: $unit exposure $score (threshold $max_exposure)"
  else
    fail "systemd-analyze security: $unit exposure $score above $max_exposure"
  fi
done
# Settings the brief pins down (and that verify cannot judge).
u=firmware/systemd/alacsd.service
missing=()
for want in '^Type=notify$' '^WatchdogSec=' '^Restart=on-failure$' '^ProtectSystem=strict$' '^ProtectHome=yes$' \
  '^NoNewPrivileges=yes$' '^PrivateTmp=yes$' '^DevicePolicy=closed$' '^CapabilityBoundingSet=$' \
  '^RestrictAddressFamilies=AF_CAN AF_UNIX AF_NETLINK$' '^StateDirectory=alacs$' '^ConfigurationDirectory=alacs$' \
  '^ExecStart=/usr/bin/alacsd --config /etc/alacs/alacsd.json$'; do
  grep -qE "$want" "$u" || missing+=("$want")
done
unit_section=$(awk '/^\[Unit\]/{f=1;next} /^\[/{f=0} f' "$u")
grep -q '^StartLimitIntervalSec=' <<<"$unit_section" && grep -q '^StartLimitBurst=' <<<"$unit_section" || missing+=("StartLimit* in [Unit]")
if ((${#missing[@]} == 0)); then pass "alacsd.service: required settings present"; else fail "alacsd.service lacks: ${missing[*]}"; fi
# networkd has no offline verifier: check the sections and keys against a known list.
net=firmware/systemd/80-can0.network
bad=$(awk -F= '/^\[/{sec=$0; next} /^[A-Za-z]/{print sec" "$1}' "$net" |
  grep -vxE '\[Match\] Name|\[CAN\] (BitRate|RestartSec|SamplePoint|TripleSampling|BusErrorReporting|ListenOnly)|\[Link\] (RequiredForOnline|ActivationPolicy)')
if [[ -z $bad ]] && grep -qx 'BitRate=500000' "$net" && grep -qx 'RestartSec=100ms' "$net"; then
  pass "$net: [CAN] BitRate=500000, RestartSec=100ms"
else
  fail "$net: unexpected keys or values: $bad"
fi

# ------------------------------------------------------------------ default config
# Every key config.cpp reads is in firmware/config/alacsd.json, and nothing else is.
if out=$("$py" - <<'PY'
import json, re, sys
# config.cpp reads each section as `if (auto v = root.object("sec")) { v->kind("key", ...) }`
# and top-level keys as `root.kind("key", ...)`.
src = open("edge/app/config.cpp").read()
keys = set()
for var, sec, body in re.findall(r'if \(auto (\w+) = root\.object\("([a-z0-9_]+)"\)\) \{(.*?)\n  \}', src, re.S):
    keys |= {sec + "." + k for k in re.findall(r'\b' + var + r'->(?:integer|number|text|boolean|flag)\("([a-z0-9_]+)"', body)}
keys |= set(re.findall(r'\broot\.(?:integer|number|text|boolean|flag)\("([a-z0-9_]+)"', src))
def flat(d, p=""):
    for k, v in d.items():
        yield from flat(v, p + k + ".") if isinstance(v, dict) else [p + k]
have = set(flat(json.load(open("firmware/config/alacsd.json"))))
if not keys: sys.exit("no keys found in edge/app/config.cpp")
if keys != have:
    sys.exit(f"missing: {sorted(keys - have)} unknown: {sorted(have - keys)}")
print(len(keys))
PY
); then pass "firmware/config/alacsd.json has all $out keys of config.cpp"; else fail "firmware/config/alacsd.json: $out"; fi
# ... and the daemon accepts it (a built alacsd, if any: exit 2 is a config error; with a
# CAN interface that does not exist it stops at the socket with exit 1).
alacsd=""
for b in build/release build/dev build/asan; do [[ -x $b/edge/app/alacsd ]] && { alacsd=$b/edge/app/alacsd; break; }; done
if [[ -n $alacsd ]]; then
  out=$("$alacsd" --config firmware/config/alacsd.json --can nocan0 2>&1)
  rc=$?
  if [[ $rc -eq 1 ]]; then pass "alacsd ($alacsd) accepts firmware/config/alacsd.json"; else fail "alacsd rejects the config (exit $rc): $out"; fi
else
  echo "appliance: skip alacsd config load (no built alacsd; tests/aarch64/run.sh does it under qemu)"
fi

# ------------------------------------------------------------------ Yocto layer
layer=yocto/meta-alacs
mapfile -t recipes < <(find "$layer" -name '*.bb' -o -name '*.bbappend' -o -name '*.bbclass' -o -name '*.inc' -o -name '*.conf' | sort)
if ((${#recipes[@]} == 0)); then
  fail "no recipes in $layer"
else
  out=$("$venv/bin/oelint-adv" --quiet --release scarthgap --suppress oelint.vars.homepageping "${recipes[@]}" 2>&1)
  rc=$?
  if [[ $rc -eq 0 && -z $out ]]; then pass "oelint-adv --release scarthgap: ${#recipes[@]} files (recipes, include, layer.conf) clean"; else fail "oelint-adv (exit $rc)"; echo "$out"; fi
fi
# Pre-honister override syntax no longer parses (and oelint-adv misses some of it).
old='(_append|_prepend|_remove)\b|_\$\{PN\}|_(class|pn|virtclass|task)-|_(raspberrypi[0-9a-z-]*|rpi|aarch64|arm|libc-[a-z]+|linux|qemuall)[[:space:]]*([?:+.]?=|=[+.]|\?\?=)'
if hits=$(grep -rnE "$old" yocto --include='*.bb' --include='*.bbappend' --include='*.bbclass' --include='*.inc' --include='*.conf' --include='*.yml'); then
  fail "old override syntax in yocto/:"; echo "$hits"
else
  pass "no old (underscore) override syntax in yocto/"
fi
grep -q '^LAYERSERIES_COMPAT_alacs = "scarthgap"$' "$layer/conf/layer.conf" && pass "layer.conf: LAYERSERIES_COMPAT scarthgap" ||
  fail "layer.conf: LAYERSERIES_COMPAT_alacs must be \"scarthgap\""
# Files the recipes install from the source tree must exist.
miss=()
for f in $(grep -ohE '\$\{S\}/[A-Za-z0-9_./-]+' "${recipes[@]}" | sed 's#^${S}/##' | sort -u); do
  [[ -e $f ]] || miss+=("$f")
done
if ((${#miss[@]} == 0)); then pass "every \${S}/ file the recipes install exists"; else fail "recipes install missing files: ${miss[*]}"; fi

# ------------------------------------------------------------------ kas
for k in yocto/kas/*.yml; do
  if out=$("$py" - "$k" <<'PY' 2>&1
import sys, yaml, jsonschema
from kas.configschema import CONFIGSCHEMA
doc = yaml.safe_load(open(sys.argv[1]))
try:
    jsonschema.validate(doc, CONFIGSCHEMA)
except jsonschema.ValidationError as e:
    sys.exit("/".join(str(p) for p in e.absolute_path) + ": " + e.message)
for name, repo in (doc.get("repos") or {}).items():
    if repo and "commit" in repo and not isinstance(repo["commit"], str):
        sys.exit(f"{name}: commit must be a quoted string")
PY
  ); then pass "kas schema: $k"; else fail "kas schema: $k: $out"; fi
done

finish
