#!/usr/bin/env bash
# Build this checkout's wheel and install it into a fresh venv: DEST/venv/bin/canguard.
#   PYTHON=... bash scripts/install_wheel.sh DEST
# The wheel is built from a copy of the source in DEST/source: setuptools writes build/ and
# *.egg-info into the tree it builds, where another build may be running; the copy resolves the
# package's links to the checkout's config/, dbc/ and systemd/ and leaves out what a run left there.
# The venv is made without pip (ensurepip costs ~5 s of CPU): uv beside $PYTHON (scripts/test.sh puts it
# there) builds the wheel and installs it with the dependencies from its cache; without uv, $PYTHON's pip
# does (pip --python), with the dependencies from the package index or pip's cache; neither byte-compiles
# (~5 s of CPU for every module of the dependencies): a command compiles what it imports when it
# first runs, and writes that bytecode into the venv for the next.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
py="${PYTHON:-$root/.venv/bin/python}"
dest="${1:?usage: install_wheel.sh DEST}"
rm -rf "$dest/source" "$dest/wheel" "$dest/venv"  # what a failed attempt left
mkdir -p "$dest/source"
cp -RL "$root/src" "$dest/source/src"
find "$dest/source/src" \( -name __pycache__ -o -name '*.egg-info' -o -name 'events.jsonl*' \
  -o -name 'i2t_state.json*' \) -prune -exec rm -rf {} +
cp "$root/pyproject.toml" "$root/README.md" "$root/LICENSE" "$dest/source/"
python3 -m venv --without-pip "$dest/venv"
uv="$(dirname "$py")/uv"
if [ -x "$uv" ]; then  # scripts/test.sh installed uv: the dependencies come from its cache
  "$uv" build -q --wheel --out-dir "$dest/wheel" "$dest/source"
  "$uv" pip install -q --python "$dest/venv/bin/python" "$dest"/wheel/canguard-*.whl
else
  "$py" -m pip wheel -q --no-deps "$dest/source" -w "$dest/wheel"
  "$py" -m pip --python "$dest/venv/bin/python" install -q --no-compile "$dest"/wheel/canguard-*.whl
fi
test -x "$dest/venv/bin/canguard"
