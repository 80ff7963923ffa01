"""The numpy block parser (canguard.io.candump_np) against the text block parser and Python's float().

The replay of a long candump log reads its blocks with numpy. It must accept exactly the
blocks the text parser accepts (for one channel), give the same frames, and refuse
everything else, so that the text parser can name the bad line's file:line.
"""

from __future__ import annotations

import os
import random
import struct

from hypothesis import example, given, settings
from hypothesis import strategies as st

from canguard.io.candump import _parse_line
from canguard.io.candump_np import ByteColumns, byte_columns
from canguard.io.frame import Frame
from canguard.io.logtypes import EXT_KEY, _Bad, id_key


def _block(lines: list[str]) -> tuple[str, int]:
    text = "".join(line + "\n" for line in lines)
    return text, len(lines)


def plain_block(rng: random.Random) -> list[str]:
    """candump -L lines of one channel: classic, CAN FD, remote, extended ids, any letter case, markers."""
    marker = rng.choice(["", " T", " R"])
    chan = rng.choice(["can0", "vcan1", "c", "slcan12"])
    mixed = rng.random() < 0.5  # can0 / can1 / can2 line by line, or one channel
    decimals = rng.randint(1, 6)
    secs = rng.choice([0, 10**9]) if rng.random() < 0.2 else rng.randrange(10**9 + 1)  # the ends, as hypothesis
    ticks = secs * 10**decimals
    lines = []
    for _ in range(rng.randint(1, 40)):
        ticks += rng.choice([0, 1, 7, 10**decimals])
        text = str(ticks).rjust(decimals + 1, "0")
        stamp = text[:-decimals].rjust(10, "0") + "." + text[-decimals:]  # one width, as candump writes
        ext = rng.random() < 0.5
        top = 0x1FFFFFFF if ext else 0x7FF
        value = rng.randrange(top + 1) if rng.random() < 0.8 else rng.choice([0, top])
        cid = f"{value:{'08X' if ext else '03X'}}"
        kind = rng.choice(["classic", "classic", "fd", "remote"])
        if kind == "fd":
            size = rng.choice([0, 1, 8, 12, 64])
            body = f"#{rng.randint(0, 15):X}" + rng.randbytes(size).hex()
        elif kind == "remote":
            body = rng.choice(["R", "r", "R0", "R4", "R8"])
        else:
            body = rng.randbytes(rng.randint(0, 8)).hex()
        if rng.random() < 0.5:
            body, cid = body.upper(), cid.lower()
        lane = f"can{rng.randint(0, 2)}" if mixed else chan
        lines.append(f"({stamp}) {lane} {cid}#{body}{marker}")
    return lines


@st.composite
def plain_lines(draw: st.DrawFn) -> list[str]:
    """:func:`plain_block` of a seed hypothesis draws: one draw a block (a draw per field and byte was most of
    these tests' time)."""
    return plain_block(random.Random(draw(st.integers(0, 2**32))))


@settings(max_examples=60, deadline=None, derandomize=True)
@given(lines=plain_lines())
def test_plain_blocks_give_the_line_parsers_frames(lines: list[str]) -> None:
    """Every plain block is taken, and row by row it is what the line parser reads (floats bit for bit)."""
    cols = byte_columns(*_block(lines))
    assert isinstance(cols, ByteColumns)
    expected = [_parse_line(line) for line in lines]
    assert list(cols.frames()) == expected
    assert [struct.pack("<d", t) for t in cols.ts] == [struct.pack("<d", f.t) for f in expected]
    assert cols.ids == [id_key(f.arbitration_id, f.is_extended_id) for f in expected]
    assert cols.ordered


DAMAGED = int(os.environ.get("CANGUARD_FUZZ_EXAMPLES", "0")) * 30 or 120
"""Damaged blocks tried (``CANGUARD_FUZZ_EXAMPLES=N``: 30 N, random; 30,000 passed before this landed), besides
the explicit examples: 120 derandomized ones reach every line and branch of :mod:`canguard.io.candump_np` that
300 did, with those (each block's lines drawn from one seed, :func:`plain_block`; the explicit examples hold the
cases a change of draws may miss)."""
_TWO = ["(0000000001.000000) can0 123#00", "(0000000001.000001) can0 123#01"]
_JUNK = st.sampled_from([*list("()# .\n\tRrTtGgxz~-+_:0189afAF"), "é"])


@settings(max_examples=DAMAGED, deadline=None, derandomize=DAMAGED <= 600)
@example(lines=_TWO, where=len(_TWO[0]) + 1 + 11, junk="(", how="replace")  # line 2: its dot a "("
@example(lines=_TWO, where=len(_TWO[0]) + 1 + 18, junk=".", how="replace")  # line 2: its ")" a "."
@example(lines=_TWO, where=19, junk=" ", how="insert")  # line 1: two spaces before its channel
@example(lines=_TWO, where=len(_TWO[0]) + 1 + 21, junk=" ", how="replace")  # line 2: channel "c n0" of 2 channels
@example(lines=_TWO, where=len(_TWO[0]) + 1 + 19, junk=" ", how="insert")  # line 2: two spaces before its channel
@given(lines=plain_lines(), where=st.integers(0, 10**6), junk=_JUNK, how=st.sampled_from(["insert", "replace", "drop"]))
def test_a_damaged_block_is_refused_as_the_line_parser_refuses_it(
    lines: list[str], where: int, junk: str, how: str
) -> None:
    """One character inserted, replaced or dropped anywhere: a block numpy takes is read line by line the same
    (every line well formed)."""
    text, _ = _block(lines)
    k = where % len(text)
    if how == "insert":
        text = text[:k] + junk + text[k:]
    elif how == "replace":
        text = text[:k] + junk + text[k + 1:]
    else:
        text = text[:k] + text[k + 1:]
    if not text.endswith("\n"):
        text += "\n"
    n = text.count("\n")
    ours = byte_columns(text, n)
    if ours is not None:
        try:
            expected = [_parse_line(line) for line in text.splitlines()]
        except _Bad as bad:
            raise AssertionError(f"numpy took a block with a bad line ({bad.reason}): {text!r}") from None
        assert list(ours.frames()) == expected


@settings(max_examples=300, deadline=None, derandomize=True)
@given(secs=st.integers(0, 10**10 - 1), frac=st.integers(0, 10**6 - 1), decimals=st.integers(1, 6),
       zeros=st.integers(0, 6))
def test_timestamps_are_pythons_floats(secs: int, frac: int, decimals: int, zeros: int) -> None:
    """The timestamp column is float() of the text, to the last bit, while its digits stay below 2**53
    (leading zeros count for nothing); a larger one is refused, left to the text parser."""
    stamp = "0" * zeros + f"{secs}.{frac % 10**decimals:0{decimals}d}"
    cols = byte_columns(f"({stamp}) can0 123#00\n", 1)
    if int(stamp.replace(".", "")) >= 2**53:
        assert cols is None  # the line parser takes it (float() is exact there)
        assert _parse_line(f"({stamp}) can0 123#00") is not None
    else:
        assert cols is not None
        assert struct.pack("<d", cols.ts[0]) == struct.pack("<d", float(stamp))


def test_several_channels_of_one_name_length_are_one_block() -> None:
    """can0 and can1 interleaved (a robot's two interfaces): one block, each row with its channel; names of
    other lengths (can0 and can10) are the text parser's."""
    lines = ["(1.000000) can0 123#00", "(1.000001) can1 123#01", "(1.000002) can0 124#", "(1.000003) vcan 7FF#0A"]
    cols = byte_columns(*_block(lines))
    assert cols is not None and cols.channel is None
    assert cols.channels == ["can0", "can1", "vcan"] and cols.lanes is not None
    assert cols.lanes.tolist() == [0, 1, 0, 2]
    assert list(cols.frames()) == [_parse_line(line) for line in lines]
    text, n = _block(["(1.000000) can0 123#00", "(1.000001) can10 123#00"])
    assert byte_columns(text, n) is None
    assert [_parse_line(line) for line in text.splitlines()] == [
        Frame(1.0, "can0", 0x123, b"\x00"), Frame(1.000001, "can10", 0x123, b"\x00")]


def test_error_frames_and_out_of_range_ids_are_refused() -> None:
    """An id above 7FF in 3 digits, or above 1FFFFFFF in 8 (error frames), is the line parser's to read."""
    for line in ("(1.000000) can0 800#00", "(1.000000) can0 20000080#0000000000000000", "(1.000000) can0 12#00"):
        assert byte_columns(line + "\n", 1) is None, line


@settings(max_examples=200, deadline=None, derandomize=True)
@given(sizes=st.lists(st.sampled_from([0, 2, 4, 8]), min_size=1, max_size=120), size=st.sampled_from([2, 4, 8]))
def test_payloads_of_a_message_and_the_rows_of_other_lengths(sizes: list[int], size: int) -> None:
    """``payload`` joins the rows of the DBC's length and says which they are, for few rows and for many."""
    lines = [f"(1.{i:06d}) can0 0AB#" + bytes(range(i % 7, i % 7 + n)).hex() for i, n in enumerate(sizes)]
    cols = byte_columns(*_block(lines))
    assert cols is not None
    rows = list(range(len(sizes)))
    good, data = cols.payload(rows, 2 * size)
    want = [k for k, n in enumerate(sizes) if n == size]
    assert good == (None if len(want) == len(sizes) else want)
    assert data == b"".join(bytes(range(k % 7, k % 7 + size)) for k in want)


def test_id_keys() -> None:
    """Standard ids are their value; extended ones are above every standard one, in any letter case."""
    cols = byte_columns(*_block(["(1.000000) can0 7fF#", "(1.000001) can0 1aBcDeF0#"]))
    assert cols is not None
    assert cols.ids == [0x7FF, 0x1ABCDEF0 + EXT_KEY]


def test_mixed_id_lengths_read_as_the_line_parser_does() -> None:
    """A block of 3- and 8-digit ids, in any letter case, reads each id as the line parser does, and one id
    out of range (a short one above 7FF, a long one above 1FFFFFFF) leaves the block to the line parser."""
    lines = ["(1.000000) can0 7fF#01", "(1.000001) can0 1aBcDeF0#02", "(1.000002) can0 000#",
             "(1.000003) can0 00000000#03", "(1.000004) can0 5A3#0405", "(1.000005) can0 1FFFFFFF#"]
    cols = byte_columns(*_block(lines))
    assert cols is not None
    assert cols.ids == [0x7FF, 0x1ABCDEF0 + EXT_KEY, 0, EXT_KEY, 0x5A3, 0x1FFFFFFF + EXT_KEY]
    assert list(cols.frames()) == [_parse_line(line) for line in lines]
    for bad in ("(1.000006) can0 800#00", "(1.000006) can0 20000080#00"):
        assert byte_columns(*_block([*lines, bad])) is None, bad


def test_threads_parse_at_once() -> None:
    """Each thread has its own scratch (a Dask worker with several threads replays several logs at once):
    blocks parsed by four threads at the same time read as parsed one after the other."""
    import threading

    blocks = []
    for k in range(4):
        lines = [f"({1_700_000_000 + k}.{i:06d}) can{k} {(k * 97 + i) % 0x7FF:03X}#{i:016X}" for i in range(20_000)]
        blocks.append(_block(lines))
    alone = [byte_columns(text, n) for text, n in blocks]
    assert all(c is not None for c in alone)
    got: dict[int, list[tuple[list[float], list[int]]]] = {k: [] for k in range(4)}

    def parse(k: int) -> None:
        for _ in range(6):
            cols = byte_columns(*blocks[k])
            assert cols is not None
            got[k].append((cols.ts, cols.ids))

    threads = [threading.Thread(target=parse, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for k, cols in enumerate(alone):
        assert cols is not None
        assert got[k] == [(cols.ts, cols.ids)] * 6
