#!/usr/bin/env bash
# Mutation testing of the safety core (src/canguard/protect/) with mutmut, in a throw-away
# copy of the checkout: mutmut writes ./mutants/ next to the code it mutates.
# Not in CI (minutes to hours). Usage: bash scripts/mutation.sh [max-children]
# Prints mutmut's results and the score (killed / all). Settings: [tool.mutmut] in pyproject.toml.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
py="${PYTHON:-$root/.venv/bin/python}"
"$py" -m pip show -q mutmut >/dev/null 2>&1 || "$py" -m pip install -q 'mutmut>=3.2'
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
git -C "$root" archive HEAD | tar -x -C "$work"
cd "$work"
mutmut="$(dirname "$py")/mutmut"
# the mutated copy of the package must win over an editable install of the checkout; the
# directory must exist when Python starts (a missing sys.path entry is cached as "nothing here")
mkdir -p mutants/src
PYTHONPATH="$work/mutants/src" "$mutmut" run --max-children "${1:-2}" > run.log 2>&1 || { tail -20 run.log; exit 1; }
"$mutmut" results --all true > results.txt 2>&1
killed=$(grep -c ': killed' results.txt || true)
total=$(grep -cE ': (killed|survived|timeout|suspicious|no tests|segfault)' results.txt || true)
grep -E ': (survived|no tests|timeout|suspicious)' results.txt || true
echo "mutation score: ${killed} killed of ${total} mutants"
