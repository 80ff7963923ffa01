#!/usr/bin/env bash
# Re-record the BehaviorTree.CPP corpus: build the oracle driver together with BT.CPP from a
# source checkout (static; no Groot2/ZeroMQ, SQLite, tests, examples or tools: CMakeLists.txt),
# and run every tests/data/btcpp/*.xml through it, writing the .json next to each tree.
# Fetches nothing.
#
#   scripts/btcpp_oracle/record.sh BTCPP_SRC [BUILD_DIR]
#
# BTCPP_SRC: a BehaviorTree.CPP 4 checkout (git clone https://github.com/BehaviorTree/BehaviorTree.CPP).
# BUILD_DIR: where to build (default ${TMPDIR:-/tmp}/btcpp-oracle-build); kept, so a
#            second run only re-records.
# Each tree says how to tick it on a comment line of its own:
#   <!-- oracle: ticks=N -->                 N x tree.tickOnce()
#   <!-- oracle: ticks=N exactly-once -->    N x tree.tickExactlyOnce()
# Needs cmake and a C++17 compiler; JOBS (default 2) sets the build's parallelism.
set -euo pipefail

if [[ $# -lt 1 || $# -gt 2 ]]; then
    echo "usage: $0 BTCPP_SRC [BUILD_DIR]" >&2
    exit 2
fi
src=$(cd "$1" && pwd)
build=${2:-${TMPDIR:-/tmp}/btcpp-oracle-build}
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
corpus=$(cd "$here/../../tests/data/btcpp" && pwd)
jobs=${JOBS:-2}
mkdir -p "$build"
build=$(cd "$build" && pwd)

version=$(sed -n 's/.*project(behaviortree_cpp VERSION \([0-9.]*\).*/\1/p' "$src/CMakeLists.txt")
commit=$(git -C "$src" rev-parse HEAD 2>/dev/null || echo unknown)
source="BehaviorTree.CPP $version $commit"
echo "recording with $source" >&2

cmake -S "$here" -B "$build" -DCMAKE_BUILD_TYPE=Release -DBTCPP_SOURCE_DIR="$src" >/dev/null
cmake --build "$build" --target btcpp_oracle -j "$jobs" >/dev/null
driver="$build/btcpp_oracle"

count=0
for tree in "$corpus"/*.xml; do
    header=$(grep -m1 -o '<!-- oracle:[^>]*-->' "$tree" || true)
    if [[ -z $header ]]; then
        echo "$tree: no '<!-- oracle: ticks=N -->' line: how many ticks?" >&2
        exit 2
    fi
    ticks=$(sed -n 's/.*ticks=\([0-9]*\).*/\1/p' <<<"$header")
    args=(--ticks "$ticks" --source "$source")
    if [[ $header == *exactly-once* ]]; then
        args+=(--exactly-once)
    fi
    # The driver runs in the corpus directory, given ./NAME.xml (BT.CPP takes the absolute path of
    # the file's directory, which fails on an empty one), so no recording holds a path of this machine.
    # A tree whose tickOnce() never returns (it wakes itself for ever) would hang the recording.
    if ! (cd "$corpus" && timeout 60 "$driver" "./$(basename "$tree")" "${args[@]}") >"${tree%.xml}.json"; then
        echo "$tree: the driver failed or did not finish in 60 s" >&2
        exit 1
    fi
    count=$((count + 1))
done
echo "recorded $count trees into $corpus" >&2
