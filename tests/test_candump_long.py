"""candump -ta blocks (the long format) read by numpy (canguard.io.candump_long), held to the line parser.

A block is rewritten as candump -L and read by the numpy block parser only when every line
has the plain long shape; the line parser must read each of its lines to the same frame,
and a block with any line the line parser refuses must go to it (to be named file:line).
"""

from __future__ import annotations

import random
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from canguard.config.loader import load_config
from canguard.io.candump import _parse_line
from canguard.io.candump_long import long_columns
from canguard.io.logtypes import _Bad
from canguard.sim import write_log
from test_replay_columns import DBC, ROBOT_GUARD, compare

_FD_SIZES = (0, 1, 8, 12, 16, 20, 24, 32, 48, 64)


def long_line(stamp: str, chan: str, cid: str, data: bytes, fd: bool, rng: random.Random) -> str:
    """One candump -ta line as can-utils prints it, with the spacing and ASCII tail varied."""
    gap = " " * rng.choice([1, 2, 2, 5])
    length = f"[{len(data):02d}]" if fd else f"[{len(data)}]"
    body = "".join(f"{' ' * rng.choice([1, 1, 2])}{b:02X}" for b in data)
    tail = rng.choice(["", "", "   ", "   '" + "".join(chr(b) if 32 <= b < 127 and chr(b) not in "[\n" else "."
                                                      for b in data) + "'"])
    return f"({stamp}){gap}{chan}{gap}{cid.rjust(rng.choice([3, 8]) if len(cid) == 3 else 8)}   {length} {body}{tail}"


def long_block(rng: random.Random, fd_allowed: bool = True) -> list[str]:
    """1 to 40 candump -ta lines of one channel: classic and (if allowed) CAN FD, standard and extended ids."""
    chan = rng.choice(["can0", "vcan1"])
    t = 1_700_000_000_000_000 + rng.randrange(10**9 + 1)
    lines = []
    for _ in range(rng.randint(1, 40)):
        t += rng.choice([0, 1, 250])
        stamp = f"{t // 10**6}.{t % 10**6:06d}"
        ext = rng.random() < 0.5
        top = 0x1FFFFFFF if ext else 0x7FF
        value = rng.randrange(top + 1) if rng.random() < 0.8 else rng.choice([0, top])  # the ends, as hypothesis
        cid = f"{value:{'08X' if ext else '03X'}}"
        fd = fd_allowed and rng.random() < 0.5
        size = rng.choice(_FD_SIZES) if fd else rng.randint(0, 8)
        lines.append(long_line(stamp, chan, cid, rng.randbytes(size), fd, rng))
    return lines


@st.composite
def long_lines(draw: st.DrawFn, fd_allowed: bool = True) -> list[str]:
    """:func:`long_block` of a seed hypothesis draws: a block costs one draw, not a hundred or more (hypothesis's
    draws were most of these tests' time), so the damaged-block property runs its 300 examples for little."""
    return long_block(random.Random(draw(st.integers(0, 2**32))), fd_allowed)


def _text(lines: list[str]) -> tuple[str, int]:
    return "".join(line + "\n" for line in lines), len(lines)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(lines=long_lines())
def test_plain_long_blocks_are_read_as_the_line_parser_reads_them(lines: list[str]) -> None:
    """Classic and CAN FD, standard (indented or not) and extended ids, any spacing, ASCII dumps: taken."""
    cols = long_columns(*_text(lines))
    assert cols is not None, lines
    assert list(cols.frames()) == [_parse_line(line) for line in lines]


@settings(max_examples=60, deadline=None, derandomize=True)
@given(lines=long_lines(fd_allowed=False))
def test_classic_only_blocks_are_read_as_the_line_parser_reads_them(lines: list[str]) -> None:
    """A block without CAN FD lines takes the joined rewrite (no regex template): the same frames."""
    cols = long_columns(*_text(lines))
    assert cols is not None, lines
    assert list(cols.frames()) == [_parse_line(line) for line in lines]


_JUNK = st.sampled_from([*"()[]# .\n'RrXx0189afAF", "  "])


@settings(max_examples=300, deadline=None, derandomize=True)
@given(lines=st.booleans().flatmap(long_lines), where=st.integers(0, 10**6), junk=_JUNK,
       how=st.sampled_from(["insert", "replace", "drop"]))
def test_a_damaged_long_block_is_taken_only_when_every_line_reads_the_same(
    lines: list[str], where: int, junk: str, how: str
) -> None:
    """One character inserted, replaced or dropped anywhere: if the block is still taken, the line parser
    reads every line of it, to the same frames (else it must have been refused)."""
    text, _ = _text(lines)
    k = where % len(text)
    text = {"insert": text[:k] + junk + text[k:], "replace": text[:k] + junk + text[k + 1:],
            "drop": text[:k] + text[k + 1:]}[how]
    if not text.endswith("\n"):
        text += "\n"
    cols = long_columns(text, text.count("\n"))
    if cols is None:
        return
    try:
        expected = [_parse_line(line) for line in text.splitlines()]
    except _Bad as bad:
        raise AssertionError(f"a long block with a bad line was taken ({bad.reason}): {text!r}") from None
    assert list(cols.frames()) == expected


def test_what_is_left_to_the_line_parser() -> None:
    """Remote requests, -x columns, relative timestamps, a wrong [len], tabs: the block goes line by line."""
    good = "(1700000000.000010)  can0  014   [2]  F4 CA"
    assert long_columns(good + "\n", 1) is not None
    for line in ("(1700000000.000010)  can0  014   [0]  remote request",
                 "(1700000000.000010)  can0  RX - -  014   [2]  F4 CA",
                 "(0000000001.000010)  can0  014   [2]  F4 CA".replace("0000000001", "1"),
                 "(1700000000.000010)  can0  014   [3]  F4 CA",
                 "(1700000000.000010)  can0  014   [2]  F4 CA 11",
                 "(1700000000.000010)\tcan0  014   [2]  F4 CA",
                 "(1700000000.000010)  can0  014   [9]  F4 CA 11 22 33 44 55 66 77"):
        assert long_columns(line + "\n", 1) is None, line


def test_a_long_log_replays_as_its_candump_L_twin(tmp_path: Path) -> None:
    """The simulator's log in the long format: the column path (numpy from the first block) equals the
    frame-by-frame reference."""
    short = tmp_path / "sim.log"
    write_log(short, 2.0, db=str(DBC), seed=3, scenarios=["load", "overload", "spike", "dropout"])
    rng = random.Random(1)
    lines = []
    for line in short.read_text(encoding="ascii").splitlines():
        frame = _parse_line(line)
        if frame is None or frame.is_error_frame or frame.is_remote_frame:
            continue
        cid = f"{frame.arbitration_id:08X}" if frame.is_extended_id else f"{frame.arbitration_id:03X}"
        lines.append(long_line(line[1:line.index(")")], frame.channel, cid, frame.data, frame.is_fd, rng))
    log = tmp_path / "sim_ta.log"
    log.write_text("\n".join(lines) + "\n", encoding="ascii")
    [col] = compare(load_config(ROBOT_GUARD), log, tmp_path / "run", (4096,), min_handled=100)
    assert col.byte_blocks > 0
