#!/usr/bin/env bash
# Install canguard with its test extras into .venv, then lint, type-check, check the layers and test.
set -euo pipefail
cd "$(dirname "$0")/.."
# The status page's browser tests drive Debian's chromium through chromedriver: install them where missing.
if ! { command -v chromium && command -v chromedriver; } >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  sudo=""; [ "$(id -u)" = 0 ] || sudo="sudo -n"
  { $sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq chromium chromium-driver; } \
    >/dev/null 2>&1 || echo "test.sh: could not install chromium + chromium-driver: the browser tests will skip" >&2
fi
# The venv without ensurepip's pip (~7 s of CPU: it installs and byte-compiles an older pip, which is then
# upgraded): where this Python's pip can install into another environment (pip >= 22.3, --python), it
# installs there the installer, uv. Otherwise the venv gets its own pip, which installs uv.
if python3 -m pip --help 2>/dev/null | grep -q -- '--python <python>'; then
  python3 -m venv --without-pip .venv
  pip=(python3 -m pip --python .venv/bin/python)
else
  python3 -m venv .venv
  pip=(.venv/bin/python -m pip)
fi
# pip byte-compiles all it installs (~5,200 files, ~35 s of CPU); the tests import about a sixth of them.
# Instead each module is compiled when first imported and its bytecode written then, also where the
# environment sets PYTHONDONTWRITEBYTECODE=1 (the tests start canguard in subprocesses, and each would
# compile the package from source again).
unset PYTHONDONTWRITEBYTECODE
# uv (Astral's installer, one wheel from the package index) resolves, downloads and unpacks the test extra
# in parallel and does not byte-compile: on a fresh 2-core machine 9 s of wall where pip took 48 s
# (2026-11-27). It keeps what it downloaded in its cache, from which scripts/install_wheel.sh installs the
# wheel's dependencies again. pip goes into the venv too (`.venv/bin/pip` as the README's other commands
# use it). Where uv cannot be had or fails, pip installs everything, as it did before uv.
if ! { "${pip[@]}" install -q --no-compile uv && .venv/bin/uv pip install -q --python .venv/bin/python pip -e ".[test]"; }
then
  echo "test.sh: uv could not install the test extra: pip installs it" >&2
  "${pip[@]}" install -q --no-compile --upgrade pip -e ".[test]"
fi
# mypy (~5 s of CPU on one core) checks the package while the linters and the tests run, which leave a core
# idle now and then; its report and exit code come after theirs, and either failing fails the script.
mypy_out="$(mktemp)"
.venv/bin/mypy >"$mypy_out" 2>&1 & mypy_pid=$!
trap 'kill "$mypy_pid" 2>/dev/null || true; rm -f "$mypy_out"' EXIT
.venv/bin/ruff check src tests benchmarks
.venv/bin/lint-imports --no-cache
# Every pytest-xdist worker collects the whole suite. On a fresh checkout each would rewrite the asserts of
# every test module and compile what collection imports (uv writes no bytecode), all at once: ~5.5 CPU-s a
# worker. One collection first writes that bytecode, and the workers read it (~2.3 CPU-s each): 3.3 CPU-s
# less with three workers, at about the same wall time, as mypy has the other core meanwhile (2026-11-29).
# Its findings, if any, the run itself reports.
[ "$#" -gt 0 ] || .venv/bin/python -m pytest -q -p no:cacheprovider --collect-only >/dev/null 2>&1 || true
# In parallel (pytest-xdist): a worker per core and one more, since the slow tests, which mostly wait on
# subprocesses and the clock, start first (tests/conftest.py) and leave a core half idle meanwhile. xdist's
# default scheduler: worksteal took the same wall time (118 s both, 2026-11-29) and once left the run waiting
# forever on an idle worker after the last test. `bash scripts/test.sh -n 0` runs them in one process.
status=0
.venv/bin/python -m pytest -q -p no:cacheprovider -n "$(( $(nproc) + 1 ))" --dist load "$@" || status=$?
mypy_status=0
wait "$mypy_pid" || mypy_status=$?
cat "$mypy_out"
[ "$mypy_status" = 0 ] || { echo "test.sh: mypy failed (exit $mypy_status)" >&2; [ "$status" != 0 ] || status=$mypy_status; }
exit "$status"
