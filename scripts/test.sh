#!/usr/bin/env bash
# Install canguard with its test extras into .venv, then lint, type-check, check the layers and test.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
.venv/bin/ruff check src tests benchmarks
.venv/bin/mypy
.venv/bin/lint-imports --no-cache
# Bytecode as a wheel install writes it: the tests start canguard in subprocesses, and where the
# environment sets PYTHONDONTWRITEBYTECODE=1 each would compile the package from source (~90 ms).
.venv/bin/python -m compileall -q src
if [ "$#" -gt 0 ]; then  # a selection (-k, -m, files): as asked
    exec .venv/bin/python -m pytest -q -p no:cacheprovider "$@"
fi
# The whole suite: the 1-minute soak (tests/test_soak.py) mostly waits on the clock, so it runs beside
# the other tests instead of after them (~60 s of the 5-minute budget); its output is shown if it fails.
soak_log=$(mktemp)
trap 'rm -f "$soak_log"' EXIT
.venv/bin/python -m pytest -q -p no:cacheprovider tests/test_soak.py >"$soak_log" 2>&1 &
soak=$!
status=0
.venv/bin/python -m pytest -q -p no:cacheprovider --deselect tests/test_soak.py::test_one_minute_soak || status=$?
if wait "$soak"; then
    echo "tests/test_soak.py (beside the others): $(tail -n 1 "$soak_log")"
else
    cat "$soak_log"
    status=1
fi
exit "$status"
