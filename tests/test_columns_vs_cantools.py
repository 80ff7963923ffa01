"""A message's one kernel (canguard.decode.message) gives exactly what cantools gives, frame by frame.

Random messages of random DBC shapes (hypothesis): Intel and Motorola, signed and
unsigned, IEEE float 32/64, any length 1..64 at any bit position, scale and offset
(integer and real), classic and CAN FD lengths, simple and extended multiplexing;
random payloads. Every signal is configured; each row decoded by
``Message.decode(..., decode_choices=False)`` must equal the kernel's value (NaN equal to
NaN, bit for bit for floats), whether the row comes in a block or as a block of one.
``CANGUARD_FUZZ_EXAMPLES`` raises the number of examples for a long run.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
import pytest
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion
from cantools.database.errors import DecodeError
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canguard.decode.message import MessageDecoder, Output

EXAMPLES = int(os.environ.get("CANGUARD_FUZZ_EXAMPLES", "120"))
FD_LENGTHS = (8, 12, 16, 20, 24, 32, 48, 64)


@st.composite
def one_signal(draw: Any, frame_bytes: int, name: str) -> Signal:
    is_float = draw(st.booleans()) and draw(st.booleans())
    length = draw(st.sampled_from([32, 64])) if is_float else draw(st.integers(1, 64))
    length = min(length, frame_bytes * 8)
    if is_float and length not in (32, 64):
        is_float = False
    big = draw(st.booleans())
    first_lin = draw(st.integers(0, frame_bytes * 8 - length))  # linear position of the MSB (Motorola) / LSB
    start = (first_lin // 8) * 8 + (7 - first_lin % 8) if big else first_lin
    scale = draw(st.sampled_from([1, 1, 2, 0.1, 0.5, 0.001, -1, 3.75]))
    offset = draw(st.sampled_from([0, 0, -40, 100, 0.5, -273.15]))
    return Signal(name, start, length, byte_order="big_endian" if big else "little_endian",
                  is_signed=(not is_float) and draw(st.booleans()),
                  conversion=BaseConversion.factory(scale=scale, offset=offset, is_float=is_float))


@st.composite
def message_and_payloads(draw: Any) -> tuple[Message, np.ndarray]:
    fd = draw(st.booleans())
    length = draw(st.sampled_from(FD_LENGTHS)) if fd else draw(st.integers(1, 8))
    kind = draw(st.sampled_from(["plain", "mux", "nested"]))
    if kind == "plain" or length < 2:
        signals = [draw(one_signal(length, "S"))]
    else:
        # selector in byte 0, one page signal per selector value in the other bytes
        sel = Signal("Sel", 0, 8, is_multiplexer=True)
        pages = [draw(one_signal(length - 1, f"P{i}")) for i in range(2)]
        signals = [sel]
        for i, p in enumerate(pages):
            shifted = Signal(p.name, p.start + 8, p.length, byte_order=p.byte_order, is_signed=p.is_signed,
                             conversion=p.conversion, multiplexer_ids=[i],
                             multiplexer_signal="Sel")
            signals.append(shifted)
        if kind == "nested" and length >= 3:
            signals[1] = Signal("P0", 8, 8, is_multiplexer=True, multiplexer_ids=[0], multiplexer_signal="Sel")
            signals.append(Signal("Deep", 16, min(8, (length - 2) * 8), multiplexer_ids=[3], multiplexer_signal="P0"))
    msg = Message(0x123, "M", length, signals, is_fd=fd, strict=False)
    Database(messages=[msg])  # the message must be a valid part of a database
    rows = draw(st.integers(1, 6))
    data = draw(st.lists(st.binary(min_size=length, max_size=length), min_size=rows, max_size=rows))
    if len(signals) > 1:  # make the selectors hit the pages often
        data = [bytes([draw(st.integers(0, 3))]) + d[1:] for d in data]
        if any(s.name == "Deep" for s in signals):
            data = [d[:1] + bytes([draw(st.sampled_from([3, 7]))]) + d[2:] for d in data]
    return msg, np.frombuffer(b"".join(data), dtype=np.uint8).reshape(rows, length)


def same(a: Any, b: Any) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        a, b = float(a), float(b)
        # equal to the bit: -0.0 is not 0.0 (events print the sign), NaN is NaN
        return (math.isnan(a) and math.isnan(b)) or np.float64(a).tobytes() == np.float64(b).tobytes()
    return int(a) == int(b)


def decoded(msg: Message, payload: np.ndarray) -> list[dict[str, float] | None]:
    """Per row: every signal on the row's multiplexer page with its value as a sample carries it (NaN for NaN
    and +-inf), or None when the row is refused (a multiplexer value no signal is multiplexed on); each row
    read from the block and again as a block of one, which must agree."""
    names = [s.name for s in msg.signals]
    decoder = MessageDecoder(msg, [Output(name, "value", name, False) for name in names])
    n, length = payload.shape
    lengths = np.full(n, length)
    out = []
    for block, k in [(decoder.decode(payload, lengths), k) for k in range(n)]:
        one = decoder.decode(payload[k:k + 1], lengths[k:k + 1])
        rows = [(block, k), (one, 0)]
        found = []
        for rows_of, at in rows:
            row = rows_of[at]
            if row:
                found.append(dict(zip(names, row, strict=True)))
                continue
            reason, cells = rows_of.verdict(at)  # type: ignore[attr-defined]
            found.append(None if reason == "undecodable" else {names[j]: value for j, value, _why in cells})
        assert _key(found[0]) == _key(found[1]), (k, found)
        out.append(found[0])
    return out


def _key(row: dict[str, float] | None) -> Any:
    return None if row is None else {name: float(v).hex() for name, v in row.items()}


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=message_and_payloads())
def test_decode_equals_cantools(case: tuple[Message, np.ndarray]) -> None:
    """Every signal of every row equals cantools' value to the bit, in a block and as a block of one."""
    msg, payload = case
    found = decoded(msg, payload)
    for row in range(payload.shape[0]):
        try:
            expected = msg.decode(bytes(payload[row]), decode_choices=False, scaling=True)
        except DecodeError:  # a multiplexer value no page has: cantools refuses the frame
            assert found[row] is None
            continue
        got = found[row]
        assert got is not None and set(got) == set(expected), (row, got, expected)
        for name, value in expected.items():
            want = value if math.isfinite(float(value)) else math.nan  # a sample carries NaN for NaN and +-inf
            assert same(got[name], want), (name, row, got[name], value)


def test_motorola_and_intel_known_values() -> None:
    """Hand-checked: a 12-bit Motorola signal across two bytes and a signed Intel one."""
    moto = Signal("M", 7, 12, byte_order="big_endian")  # MSB = bit 7 of byte 0: 0xABC from AB C0
    intel = Signal("I", 16, 16, byte_order="little_endian", is_signed=True)  # bytes 2..3 little-endian
    msg = Message(1, "K", 8, [moto, intel])
    payload = np.frombuffer(bytes([0xAB, 0xC0, 0xFE, 0xFF, 0, 0, 0, 0]), dtype=np.uint8).reshape(1, 8)
    assert decoded(msg, payload) == [{"M": 0xABC, "I": -2.0}]


@pytest.mark.parametrize("scale", [1, 1.0, 2.0])
def test_negative_zero_float_keeps_its_sign_as_cantools(scale: float) -> None:
    """A float32 payload of -0.0: cantools' identity conversion keeps the sign (events print it); a scale may not."""

    sig = Signal("F", 0, 32, conversion=BaseConversion.factory(scale=scale, offset=0, is_float=True))
    msg = Message(1, "Z", 4, [sig])
    data = bytes([0, 0, 0, 0x80])  # -0.0, little-endian float32
    expected = msg.decode(data, decode_choices=False)["F"]
    [row] = decoded(msg, np.frombuffer(data, dtype=np.uint8).reshape(1, 4))
    assert row is not None
    assert same(row["F"], expected), (row, expected)
    assert math.copysign(1.0, row["F"]) == math.copysign(1.0, float(expected))
