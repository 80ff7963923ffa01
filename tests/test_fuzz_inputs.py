"""Fuzzing what users hand canguard: logs, configs, trees.

Property: any input gives a result or canguard's own error naming where (file:line or
the key) — never another exception, i.e. never a traceback for the user. CI runs a
small profile; ``CANGUARD_FUZZ_EXAMPLES=100000`` runs the long one.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cantools
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canguard.bt.context import Context, NullTaskGate
from canguard.bt.loader import load_tree
from canguard.bt.nodes import BUILTIN_NODES
from canguard.config.dbc import load_dbc_file
from canguard.config.loader import load_config_text
from canguard.errors import ConfigError, LogFormatError, TreeError
from canguard.io.clock import ManualClock
from canguard.io.logs import ReadStats, read_log
from checkout import REPO
from treekit import ListSink

EXAMPLES = int(os.environ.get("CANGUARD_FUZZ_EXAMPLES", "150"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=EXAMPLES <= 1000,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

CHARS = st.characters(exclude_categories=["Cs"])
"""``st.text``'s own alphabet (every code point but the surrogates, which UTF-8 cannot encode), given by Unicode
category: ``st.text()`` finds it by encoding each of the 1.1 million code points as UTF-8, ~3 CPU-s in each process
that first draws a text (hypothesis means to keep the table in ``.hypothesis/``, which a fresh checkout lacks)."""

# -- logs --------------------------------------------------------------------------------------
VALID = ["(1700000000.000100) can0 123#DEADBEEF", "(1700000000.000200) can1 18FF50E5#0011223344556677",
         "(1700000000.000300) can0 123##1" + "00" * 12, "(1700000000.000400) can0 123#R",
         "(1700000000.000500) can0 20000004#0004000000000000", " (1700000000.000600)  can0  123   [2]  11 22"]
TOKENS = st.sampled_from(["(", ")", "#", "##", " ", "can0", "123", "18FF50E5", "DEAD", "R", "[8]", "\t", "1.5",
                          "-", "nan", "inf", "0x", "\x00", "é", "FFFFFFFFF", "##F", "(1e400)", "_9"])
line = st.one_of(
    st.sampled_from(VALID),
    st.text(CHARS, max_size=60),
    st.lists(TOKENS, max_size=10).map("".join),
    st.tuples(st.sampled_from(VALID), st.integers(0, 40), st.text(CHARS, max_size=3)).map(
        lambda v: v[0][: v[1]] + v[2] + v[0][v[1]:]),
)


@FUZZ
@given(lines=st.lists(line, min_size=1, max_size=8), skip=st.booleans())
def test_any_log_line_is_a_frame_a_counted_bad_line_or_a_located_error(tmp_path_factory: Any,
                                                                       lines: list[str], skip: bool) -> None:
    path = tmp_path_factory.mktemp("log") / "x.log"
    path.write_bytes("\n".join(lines).encode("utf-8", "surrogatepass") + b"\n")
    stats = ReadStats()
    try:
        frames = list(read_log(path, skip_bad=skip, stats=stats))
    except LogFormatError as exc:
        assert str(path) in str(exc)
        return
    text = "\n".join(lines).replace("\r\n", "\n").replace("\r", "\n")  # text mode: \r ends a line too
    assert len(frames) + stats.bad_lines <= len(text.split("\n"))
    if not skip:
        assert stats.bad_lines == 0


# -- configs -----------------------------------------------------------------------------------
ROBOT_DBC = str(REPO / "dbc" / "robot.dbc")
BASE = yaml.safe_load((REPO / "config" / "examples" / "robot_guard.yaml").read_text(encoding="utf-8"))
BASE["dbc"] = [ROBOT_DBC]
BASE["tree"]["file"] = str(REPO / "config" / "trees" / "robot_guard.xml")
BASE.pop("events", None)
BASE["state"].pop("file", None)

scalar = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                   st.text(CHARS, max_size=12))
value = st.recursive(scalar, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                     st.dictionaries(st.text(CHARS, max_size=8), inner, max_size=4)),
                     max_leaves=10)


def paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += paths(v, (*prefix, i))
    return out


ALL_PATHS = [p for p in paths(BASE) if p]


@pytest.fixture(scope="module")
def robot_dbc_parsed_once() -> Iterator[None]:
    """cantools parses robot.dbc once for every example, not once each (half of an example's time went there):
    the property is about canguard's checks of the config, and cantools' database is not changed by them (the
    file has no unsound signal to take out). canguard's own pre-pass still reads the file every time; any other
    text it hands cantools is parsed as ever."""
    load_string = cantools.database.load_string
    robot: dict[str, Any] = {}

    def first(text: str, *args: Any, **kwargs: Any) -> Any:
        robot.update(key=(text, args, kwargs), db=load_string(text, *args, **kwargs))
        return robot["db"]

    def once(text: str, *args: Any, **kwargs: Any) -> Any:
        return robot["db"] if (text, args, kwargs) == robot["key"] else load_string(text, *args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cantools.database, "load_string", first)
        assert load_dbc_file(Path(ROBOT_DBC)).database is robot["db"]
        mp.setattr(cantools.database, "load_string", once)
        yield


DUMPER: Any = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
"""libyaml's emitter where PyYAML has it: the pure-Python one took most of this test's time."""


@FUZZ
@given(edits=st.lists(st.tuples(st.sampled_from(ALL_PATHS), value), min_size=1, max_size=3))
@pytest.mark.usefixtures("robot_dbc_parsed_once")
def test_any_config_is_a_config_or_a_config_error_naming_the_file(edits: list[tuple[tuple[Any, ...], Any]]) -> None:
    doc = copy.deepcopy(BASE)
    for path, new in edits:
        node = doc
        try:
            for key in path[:-1]:
                node = node[key]
            node[path[-1]] = new
        except (KeyError, IndexError, TypeError):
            continue
    text = yaml.dump(doc, Dumper=DUMPER)
    try:
        load_config_text(text, "/fuzz/canguard.yaml")
    except ConfigError as exc:
        assert "/fuzz/canguard.yaml" in str(exc)


@FUZZ
@given(text=st.text(CHARS, max_size=200))
def test_any_text_as_config(text: str) -> None:
    try:
        load_config_text(text, "/fuzz/any.yaml")
    except ConfigError as exc:
        assert "/fuzz/any.yaml" in str(exc)


# -- trees -------------------------------------------------------------------------------------
NODE_IDS = [*sorted(BUILTIN_NODES), "SubTree", "Nope", "Action", "Condition", "BehaviorTree"]
ATTRS = st.dictionaries(st.sampled_from(["name", "ID", "msec", "code", "num_attempts", "topic_name", "if", "else",
                                         "success_count", "value", "output_key", "key", "x", "_skipIf"]),
                        st.sampled_from(["1", "-1", "abc", "{k}", "x := 1", "true", "", "1e9", "{=}", "&amp;"]),
                        max_size=3)


@st.composite
def element(draw: Any, depth: int = 0) -> str:
    tag = draw(st.sampled_from(NODE_IDS))
    attrs = " ".join(f'{k}="{v}"' for k, v in draw(ATTRS).items())
    children = [] if depth >= 2 else draw(st.lists(element(depth + 1), max_size=3))
    if not children:
        return f"<{tag} {attrs}/>"
    return f"<{tag} {attrs}>{''.join(children)}</{tag}>"


@FUZZ
@given(body=element(), fmt=st.sampled_from(['BTCPP_format="4" ', "", 'BTCPP_format="3" ']))
def test_any_tree_is_a_tree_or_a_tree_error_with_its_line(tmp_path_factory: Any, body: str, fmt: str) -> None:
    path = tmp_path_factory.mktemp("tree") / "t.xml"
    path.write_text(f'<root {fmt}main_tree_to_execute="M">\n<BehaviorTree ID="M">\n{body}\n</BehaviorTree>\n</root>\n',
                    encoding="utf-8")
    ctx = Context(ManualClock(), {}, sink=ListSink(), task=NullTaskGate())
    try:
        load_tree(path, ctx)
    except TreeError as exc:
        assert str(path) in str(exc)


@FUZZ
@given(text=st.text(CHARS, max_size=120))
def test_any_text_as_tree(tmp_path_factory: Any, text: str) -> None:
    path = tmp_path_factory.mktemp("tree") / "t.xml"
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    try:
        load_tree(path, Context(ManualClock(), {}, sink=ListSink(), task=NullTaskGate()))
    except TreeError as exc:
        assert str(path) in str(exc)
