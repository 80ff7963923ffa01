#!/usr/bin/env bash
# The tests (no lint) against the oldest dependencies pyproject.toml allows, on the oldest Python it allows
# when one is installed: a fresh venv in a temporary directory with the built wheel and
# scripts/oldest-constraints.txt. Not part of CI (it takes as long again); run it before raising or lowering a bound.
#   PYTHON=python3.10 bash scripts/test-oldest.sh [pytest arguments]
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
py="${PYTHON:-$(command -v python3.10 || command -v python3)}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
"$py" -m venv "$work/venv"
"$work/venv/bin/python" -m pip install -q --upgrade pip
"$work/venv/bin/python" -m pip wheel -q --no-deps "$root" -w "$work/wheel"
wheel=("$work"/wheel/*.whl)
"$work/venv/bin/python" -m pip install -q -c "$root/scripts/oldest-constraints.txt" "${wheel[0]}[test]"
"$work/venv/bin/python" -m pip list 2>/dev/null | grep -iE '^(python-can|cantools|py.trees|pyyaml|numpy) '
cd "$root"
"$work/venv/bin/python" -m compileall -q src
"$work/venv/bin/python" -m pytest -q -p no:cacheprovider "$@"
