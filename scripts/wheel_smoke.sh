#!/usr/bin/env bash
# Build the wheel, install it into a fresh venv outside the checkout (scripts/install_wheel.sh) and run
# the user-facing commands from a temporary directory, each with its documented
# exit code (issue 14). tests/test_installed_wheel.py runs this script.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
py="${PYTHON:-$root/.venv/bin/python}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
# CANGUARD_VENV: a venv where scripts/install_wheel.sh has installed the wheel already (the test
# suite builds it once per run); without it, the wheel is built and installed here.
venv="${CANGUARD_VENV:-$work/venv}"
if [ -z "${CANGUARD_VENV:-}" ] && ! PYTHON="$py" bash "$root/scripts/install_wheel.sh" "$work" >"$work/pip.log" 2>&1; then
  cat "$work/pip.log" >&2; exit 1
fi
cg="$venv/bin/canguard"
cd "$work"
step() { echo "wheel smoke: $*"; }
step "--version"; "$cg" --version | grep -q '^canguard '
step "check"; "$cg" check >/dev/null 2>&1
step "tree"; "$cg" tree >/dev/null
# without a terminal (stdin /dev/null), to its end: the summary, the spike at 4 s tripped PackCurrent, the
# stop frames went out after the trip
step "demo --duration 6 (headless)"; timeout 60 "$cg" demo --duration 6 </dev/null >demo.txt 2>&1
grep -q "canguard demo summary" demo.txt
grep -q "PackCurrent" demo.txt; grep -q "overcurrent" demo.txt
grep -q "stop frames out" demo.txt; grep -q "after the trip's time" demo.txt
step "the status page is in the wheel"
"$venv/bin/python" -c "from canguard.data import data_path; assert data_path('monitor', 'index.html').is_file()"
step "simulate"; "$cg" simulate --scenario overload --duration 5 --out x.log >/dev/null 2>&1
test -s x.log
step "replay"; "$cg" replay x.log >/dev/null 2>&1
step "init + check -c"; "$cg" init starter >/dev/null; "$cg" check -c starter/canguard.yaml >/dev/null
step "replay -c starter --fail-on-trip (its I²t guard trips on the overload: exit 1)"
rc=0; "$cg" replay x.log -c starter/canguard.yaml --fail-on-trip >/dev/null 2>&1 || rc=$?
test "$rc" = 1
step "unit"; "$cg" unit | grep -q "^ExecStart=$venv/bin/canguard run -c /etc/canguard/canguard.yaml$"
echo "wheel smoke: ok"
