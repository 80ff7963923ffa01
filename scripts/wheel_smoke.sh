#!/usr/bin/env bash
# Build the wheel, install it into a fresh venv outside the checkout and run
# the user-facing commands from a temporary directory (issue 14 item 2).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
py="${PYTHON:-$root/.venv/bin/python}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
"$py" -m pip wheel -q --no-deps "$root" -w "$work/wheel"
python3 -m venv "$work/venv"
"$work/venv/bin/pip" install -q "$work"/wheel/*.whl
cg="$work/venv/bin/canguard"
cd "$work"
step() { echo "wheel smoke: $*"; }
step "--version"; "$cg" --version | grep -q '^canguard '
step "check"; "$cg" check >/dev/null
step "tree"; "$cg" tree >/dev/null
step "demo --duration 3"; timeout 30 "$cg" demo --duration 3 >/dev/null 2>&1
step "simulate"; "$cg" simulate --scenario overload --duration 5 --out x.log >/dev/null 2>&1
test -s x.log
step "replay"; "$cg" replay x.log >/dev/null 2>&1
echo "wheel smoke: ok"
