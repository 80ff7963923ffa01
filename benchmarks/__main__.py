"""canguard's benchmarks, one runner: every suite prints one table, worst case first, each figure beside its peer.

    python -m benchmarks SUITE [--quick] [--json FILE] [--rounds N] [--ab REV]
    python -m benchmarks docs [SUITE ...] [--quick]     # rewrite the tables of docs/benchmarks.md

Run from the checkout's root. Suites: replay, live, monitor, fleet, models, startup, soak (``all``: every
one in turn). ``--quick``: tiny sizes, one round, seconds (what CI runs; its figures mean nothing).
``--ab REV``: the suite's canguard figures on this tree and on git revision REV (its ``src`` exported
with ``git archive``), the two taking turns for ``--rounds`` rounds; the benchmark code is this tree's.
"""

from __future__ import annotations

import argparse
import importlib
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

from benchmarks import kit
from benchmarks.kit import Options, Table

SUITES = ("replay", "live", "monitor", "fleet", "models", "startup", "soak")
DOC = kit.REPO / "docs" / "benchmarks.md"


def run_suite(name: str, opts: Options) -> Table:
    """The suite's table (its module ``benchmarks.NAME``, function ``run``)."""
    module = importlib.import_module(f"benchmarks.{name}")
    return module.run(opts)  # type: ignore[no-any-return]


def child(suite: str, src: Path, out: Path, quick: bool, rounds: int | None) -> dict[str, Any]:
    """The suite in a runner process of its own with ``src`` first on its path; its JSON document."""
    shown = ["python -m benchmarks", suite, *(["--quick"] if quick else []),
             *(["--rounds", str(rounds)] if rounds else [])]
    cmd = [sys.executable, "-m", "benchmarks", *shown[1:], "--json", str(out), "--src", str(src), "--label",
           " ".join(shown)]
    out.unlink(missing_ok=True)
    proc = subprocess.run(cmd, cwd=kit.REPO, env=kit.child_env(src), stdout=subprocess.DEVNULL)
    if proc.returncode != 0 and not out.exists():  # exit 1 with a table: a check of the suite failed, shown there
        raise SystemExit(f"{' '.join(cmd)}: exit {proc.returncode}")
    return json.loads(out.read_text(encoding="utf-8"))  # type: ignore[no-any-return]


def ab(suite: str, rev: str, quick: bool, rounds: int) -> Table:
    """The suite's cost columns on this tree and on ``rev``, alternating runs (each first in turn), best of each."""
    best: dict[tuple[str, str], dict[str, float]] = {}  # (version, row) -> {cost column: best}
    order: list[str] = []
    costs: list[str] = []
    with kit.scratch("ab") as d:
        tmp = Path(d)
        versions = {"this tree": kit.compiled(kit.SRC), rev: kit.export(rev, tmp / "old")}
        for r in range(rounds):
            for label in (list(versions) if r % 2 == 0 else list(reversed(versions))):
                doc = child(suite, versions[label], tmp / "out.json", quick, 1)
                costs = doc["costs"]
                for row in doc["rows"]:
                    key = " / ".join(str(row[c]) for c in doc["columns"] if isinstance(row[c], str))
                    if key not in order:
                        order.append(key)
                    slot = best.setdefault((label, key), {})
                    for c in costs:
                        if isinstance(row.get(c), (int, float)):
                            slot[c] = min(slot.get(c, float("inf")), float(row[c]))
    columns = ["row"] + [f"{c}: {v}" for c in costs for v in ("this tree", rev)] + \
              [f"{c}: this tree / {rev}" for c in costs]
    rows: list[list[kit.Cell]] = []
    for key in order:
        this, old = best.get(("this tree", key), {}), best.get((rev, key), {})
        rows.append([key, *[x.get(c) for c in costs for x in (this, old)],
                     *[kit.ratio(this.get(c), old.get(c)) for c in costs]])
    rows.sort(key=lambda row: -(row[-len(costs)] or 0.0) if costs else 0.0)
    return Table(f"{suite} --ab {rev}", f"the {suite} suite's canguard figures on this tree and on {rev}, "
                 f"{rounds} alternating rounds, best of each; largest this / {rev} first (above 1: this tree is "
                 "slower)",
                 columns, rows, [f"the benchmark code is this tree's; {rev}'s src was exported with git archive"],
                 costs)


def docs(suites: list[str], quick: bool) -> None:
    """Run ``suites`` (runner processes of their own) and put their tables into docs/benchmarks.md."""
    text = DOC.read_text(encoding="utf-8")
    with kit.scratch("docs") as d:
        for suite in suites:
            head, table = kit.from_json(child(suite, kit.SRC, Path(d) / f"{suite}.json", quick, None))
            block = f"<!-- table:{suite} -->\n{kit.render(head, table)}<!-- /table:{suite} -->"
            pattern = re.compile(rf"<!-- table:{suite} -->.*?<!-- /table:{suite} -->", re.S)
            if not pattern.search(text):
                raise SystemExit(f"{DOC}: no <!-- table:{suite} --> ... <!-- /table:{suite} --> block to fill")
            text = pattern.sub(lambda _m, b=block: b, text)
            DOC.write_text(text, encoding="utf-8")
            print(f"{DOC}: {suite} table rewritten", file=sys.stderr)


def parse(argv: list[str] | None) -> argparse.Namespace:
    """The runner's arguments."""
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    ap.add_argument("suite", choices=(*SUITES, "all", "docs"))
    ap.add_argument("only", nargs="*", metavar="SUITE", help="docs: the suites to run (default: all)")
    ap.add_argument("--quick", action="store_true", help="tiny sizes, one round: checks the suite runs (CI)")
    ap.add_argument("--json", type=Path, metavar="FILE", help="write the table as JSON here too")
    ap.add_argument("--rounds", type=int, default=None, metavar="N", help="best of N rounds (default: the suite's)")
    ap.add_argument("--ab", metavar="REV", help="this tree against git revision REV, alternating runs")
    ap.add_argument("--src", type=Path, default=kit.SRC, help=argparse.SUPPRESS)  # the tree timed (--ab's children)
    ap.add_argument("--label", help=argparse.SUPPRESS)  # the command the header shows (docs' children)
    args = ap.parse_args(argv)
    if args.only and (args.suite != "docs" or set(args.only) - set(SUITES)):
        ap.error(f"only docs takes suites after it, of {', '.join(SUITES)}")
    return args


def main(argv: list[str] | None = None) -> int:
    """Run the suite(s), print each table; with ``--json`` write them there; exit 1 when a suite's check failed."""
    args = parse(argv)
    kit.clean_up_on_sigterm()
    command = [args.label] if args.label else ["python -m benchmarks", *(sys.argv[1:] if argv is None else argv)]
    if args.suite == "docs":
        docs(args.only or list(SUITES), args.quick)
        return 0
    suites = list(SUITES) if args.suite == "all" else [args.suite]
    out: list[dict[str, Any]] = []
    for suite in suites:
        head = kit.meta(command)
        if args.ab:
            table = ab(suite, args.ab, args.quick, args.rounds or (1 if args.quick else 3))
        else:
            src = kit.compiled(args.src.resolve())
            opts = Options(quick=args.quick, src=src, rounds=args.rounds or (1 if args.quick else 3))
            table = run_suite(suite, opts)
        print(kit.render(head, table), flush=True)
        out.append(kit.as_json(head, table))
    if args.json:
        args.json.write_text(json.dumps(out[0] if len(out) == 1 else out, indent=1) + "\n", encoding="utf-8")
    return 1 if any(doc["failed"] for doc in out) else 0


if __name__ == "__main__":
    sys.exit(main())
