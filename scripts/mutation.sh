#!/usr/bin/env bash
# Mutation testing of the safety core (src/canguard/protect/) with mutmut, in a throw-away
# copy of the checkout: mutmut writes ./mutants/ next to the code it mutates.
# Not in CI (minutes to hours). Usage: bash scripts/mutation.sh [max-children]
# SCOPE=gate mutates the guard nodes and the task gate (engine/gate.py, bt/nodes/current.py) instead.
# Prints mutmut's results and the score (killed / all). Settings: [tool.mutmut] in pyproject.toml.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
py="${PYTHON:-$root/.venv/bin/python}"
"$py" -m pip show -q mutmut >/dev/null 2>&1 || "$py" -m pip install -q 'mutmut>=3.2'
work="$(mktemp -d)"
[ -n "${KEEP:-}" ] || trap 'rm -rf "$work"' EXIT
git -C "$root" archive HEAD | tar -x -C "$work"
cd "$work"
if [ "${SCOPE:-protect}" = "gate" ]; then
  # the guard nodes and the task gate instead of protect/: every other module left alone,
  # their own tests selected (set in the copy's pyproject only)
  "$py" - <<'PY'
import pathlib, re
keep = {"src/canguard/engine/gate.py", "src/canguard/bt/nodes/current.py"}
files = sorted(str(p) for p in pathlib.Path("src/canguard").rglob("*.py") if str(p) not in keep)
tests = ["tests/test_stop_resume.py", "tests/test_nodes_guards.py", "tests/test_engine.py",
         "tests/test_recover_timing.py", "tests/test_reload_carry.py", "tests/test_i2t_peak_optional.py",
         "tests/test_faults.py", "tests/test_tree_loader.py", "tests/test_errors_all_at_once.py",
         "tests/test_nodes_ports.py", "tests/test_events.py", "tests/test_timers_per_node.py",
         "tests/test_mutants_gate.py", "tests/test_mutants_guards.py"]
text = pathlib.Path("pyproject.toml").read_text()
text = re.sub(r"do_not_mutate = \[.*?\]", "do_not_mutate = " + repr(files).replace("'", '"'), text, flags=re.S)
text = re.sub(r"pytest_add_cli_args_test_selection = \[.*?\]",
              "pytest_add_cli_args_test_selection = " + repr(tests).replace("'", '"'), text, flags=re.S)
pathlib.Path("pyproject.toml").write_text(text)
PY
fi
mutmut="$(dirname "$py")/mutmut"
# mutmut puts ./mutants/src first on sys.path itself (the whole package is copied there, see
# [tool.mutmut] do_not_mutate); no PYTHONPATH: it would shadow that set-up
"$mutmut" run --max-children "${1:-2}" > run.log 2>&1 || { tail -20 run.log; exit 1; }
"$mutmut" results --all true > results.txt 2>&1
killed=$(grep -c ': killed' results.txt || true)
total=$(grep -cE ': (killed|survived|timeout|suspicious|no tests|segfault)' results.txt || true)
echo "survivors per module (mutmut show NAME in $work/mutants to see one; set KEEP=1 to keep it):"
grep -E ': (survived|no tests|timeout|suspicious)' results.txt | sed -E 's/^ *canguard\.([a-z0-9_.]+)\.x.*: (.*)$/\1 \2/' | sort | uniq -c | sort -rn
echo "mutation score: ${killed} killed of ${total} mutants"
