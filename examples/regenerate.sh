#!/usr/bin/env bash
# Regenerate examples/: one candump -L log per simulator scenario (deterministic: seed 0)
# and the replay summary each must give with config/examples/robot_guard.yaml.
# tests/test_examples.py checks both: the simulator still writes these exact logs, and
# replaying them still gives these summaries.
set -euo pipefail
cd "$(dirname "$0")"
CFG=../config/examples/robot_guard.yaml
SCENARIOS="normal inrush spike overload dropout garbage errorburst load"
for s in $SCENARIOS; do
  duration=6
  [ "$s" = load ] && duration=3
  canguard simulate -c "$CFG" --out "$s.log.gz" --scenario "$s" --duration "$duration" --seed 0
  canguard replay "$s.log.gz" -c "$CFG" --json > "$s.summary.json"
done
