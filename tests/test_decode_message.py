"""One message's decoder (canguard.decode.message): its strategy, its rows and why a row is not valid.

A :class:`MessageDecoder` compiles its message once into one kernel over a block. Random
messages of random DBC shapes (the generator of ``test_columns_vs_cantools``) with random
configured outputs (presence flags, ranges) are decoded as a block and one payload at a
time; each row must be what cantools' value and the documented checks say it is.
"""

from __future__ import annotations

import math
import os
import warnings
from typing import Any

import numpy as np
import pytest
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canguard.decode.message import (
    ABSENT,
    NO_SIGNAL,
    OTHER_PAGE,
    MessageDecoder,
    Output,
)
from canguard.decode.rows import EMPTY, OneRow, Row, Verdict
from canguard.io.frame import INVALID_INF, INVALID_LENGTH, INVALID_NAN, INVALID_PAYLOAD, INVALID_RANGE
from test_columns_vs_cantools import message_and_payloads

EXAMPLES = int(os.environ.get("CANGUARD_FUZZ_EXAMPLES", "120"))


def explain(decoder: MessageDecoder, data: bytes) -> Verdict:
    """Why one payload's row is what the decoder gives, with each value as a sample carries it."""
    rows = decoder.decode(*decoder.one(data))
    if rows[0]:
        return Verdict("", [(j, v, "") for j, v in enumerate(rows[0])])
    assert isinstance(rows, OneRow)
    return rows.verdict(0)


def _key(rows: Any) -> list[Any]:
    """Rows compared to the bit (``-0.0`` is not ``0.0``)."""
    return [row if not row else tuple(float(v).hex() for v in row) for row in list(rows)]


def _expected(msg: Message, outputs: list[Output], data: bytes) -> Row:
    """The row the documented checks make of cantools' decoding of ``data``."""
    try:
        values = msg.decode(data, decode_choices=False, scaling=True)
    except Exception:  # cantools refuses the payload: the row is invalid
        return None
    on = [o for o in outputs if o.signal in values]
    if not on:
        return EMPTY
    if len(on) < len(outputs):
        return None
    row = []
    for o in outputs:
        v = float(values[o.signal])
        if not math.isfinite(v) or (o.present and v == 0.0):
            return None
        v = (1.0 if v else 0.0) if o.present else v
        if not o.lo <= v <= o.hi:
            return None
        row.append(v)
    return tuple(row)


@st.composite
def configured(draw: Any) -> tuple[Message, np.ndarray, list[Output]]:
    """A random message and payloads, with random outputs: some signals, one maybe a presence flag, some ranged."""
    msg, payload = draw(message_and_payloads())
    names = [s.name for s in msg.signals]
    chosen = draw(st.lists(st.sampled_from(names), min_size=1, max_size=len(names), unique=True))
    outputs = []
    for k, name in enumerate(chosen):
        present = draw(st.booleans()) and draw(st.booleans())
        lo, hi = (-1.7976931348623157e308, 1.7976931348623157e308)
        if draw(st.booleans()):
            lo, hi = sorted((draw(st.sampled_from([-100.0, 0.0, 0.5, 10.0])), draw(st.sampled_from([1.0, 50.0, 1e6]))))
        outputs.append(Output(f"s{k}", "present" if present else f"r{k}", name, present, lo, hi))
    return msg, payload, outputs


def _one(decoder: MessageDecoder, data: bytes) -> Any:
    """The rows of one payload, a block of one."""
    return decoder.decode(*decoder.one(data))


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=configured())
def test_rows_are_cantools_rows(case: tuple[Message, np.ndarray, list[Output]]) -> None:
    """A block's rows and each payload's row alone are each what cantools' values and the checks make."""
    msg, payload, outputs = case
    decoder = MessageDecoder(msg, outputs)
    n = payload.shape[0]
    want = _key([_expected(msg, outputs, bytes(row)) for row in payload])
    assert _key([_one(decoder, bytes(row))[0] for row in payload]) == want, decoder.strategy
    assert _key(decoder.decode(payload, np.full(n, payload.shape[1]))) == want, decoder.strategy
    if n > 1:  # a block whose first payload is a byte short: that row alone is invalid
        lengths = np.full(n, payload.shape[1])
        lengths[0] -= 1
        rows = decoder.decode(payload, lengths)
        assert rows[0] is None and rows.verdict(0) == (INVALID_LENGTH, [])  # type: ignore[attr-defined]
        assert _key(list(rows)[1:]) == want[1:]


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=configured())
def test_explain_agrees_with_the_row(case: tuple[Message, np.ndarray, list[Output]]) -> None:
    """A valid row has reason "" and its values; any other row says why, alike in a block and alone."""
    msg, payload, outputs = case
    decoder = MessageDecoder(msg, outputs)
    block = decoder.decode(payload, np.full(payload.shape[0], payload.shape[1]))
    for k, raw in enumerate(payload):
        data = bytes(raw)
        rows = _one(decoder, data)
        row = rows[0]
        reason, cells = explain(decoder, data)
        if not row:
            assert rows.verdict(0) == (reason, cells)
            if len(block) > 1:
                assert block.verdict(k) == (reason, cells)  # type: ignore[attr-defined]
        if row:
            assert reason == ""
            assert [float(v).hex() for _j, v, _w in cells] == [float(v).hex() for v in row]
        elif row is EMPTY:
            assert reason == NO_SIGNAL and cells == []
        else:
            assert reason not in ("", NO_SIGNAL)


def _message(*signals: Signal, length: int = 8, fd: bool = False) -> Message:
    msg = Message(0x123, "M", length, list(signals), is_fd=fd, strict=False)
    Database(messages=[msg])
    return msg


def _sig(name: str, start: int, length: int, **kw: Any) -> Signal:
    scale, offset = kw.pop("scale", 1), kw.pop("offset", 0)
    is_float = kw.pop("is_float", False)
    return Signal(name, start, length, conversion=BaseConversion.factory(scale=scale, offset=offset,
                                                                          is_float=is_float), **kw)


class TestStrategy:
    """The strategy is chosen once, from the DBC: the bit maths, cantools only where it cannot."""

    def test_aligned_odd_fd_and_multiplexed_take_bits(self) -> None:
        """Byte-aligned fields, a 12-bit signal, a CAN FD Motorola 20-bit signal and a multiplexed one are bit
        fields, not cantools."""
        aligned = _message(_sig("A", 0, 16, is_signed=True, scale=0.1), _sig("B", 23, 16, byte_order="big_endian"),
                           _sig("C", 32, 32, is_float=True))
        odd = _message(_sig("A", 3, 12))
        fd = _message(_sig("A", 7, 20, byte_order="big_endian", is_signed=True), length=12, fd=True)
        mux = _message(Signal("Sel", 0, 8, is_multiplexer=True),
                       _sig("P", 8, 16, multiplexer_ids=[1], multiplexer_signal="Sel"))
        for msg, name in ((aligned, "C"), (odd, "A"), (fd, "A"), (mux, "P")):
            assert MessageDecoder(msg, [Output("x", "a", name, False)]).strategy == "bits"

    def test_a_scaled_multiplexer_takes_cantools(self) -> None:
        """cantools picks a page by the scaled multiplexer value: that message is left to cantools."""
        msg = _message(_sig("Sel", 0, 8, is_multiplexer=True, scale=2),
                       _sig("P", 8, 16, multiplexer_ids=[2], multiplexer_signal="Sel"))
        decoder = MessageDecoder(msg, [Output("x", "a", "P", False)])
        assert decoder.strategy == "cantools"
        assert _one(decoder, bytes([1, 5, 0, 0, 0, 0, 0, 0])) == [(5.0,)]  # raw 1 -> page 2
        assert _one(decoder, bytes([2, 5, 0, 0, 0, 0, 0, 0])) == [None]  # raw 2 -> page 4: refused

    def test_a_payload_cantools_raises_on_is_undecodable(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """A cantools message whose decode raises gives an invalid row and ``undecodable``, never an exception."""
        msg = _message(_sig("Sel", 0, 8, is_multiplexer=True, scale=2),
                       _sig("P", 8, 16, multiplexer_ids=[2], multiplexer_signal="Sel"))

        def broken(*args: object, **kwargs: object) -> dict[str, float]:
            raise ValueError("corrupt")

        monkeypatch.setattr(msg, "decode_simple", broken)
        decoder = MessageDecoder(msg, [Output("x", "a", "P", False)])
        assert list(decoder.decode(np.zeros((2, 8), dtype=np.uint8), np.array([8, 8]))) == [None, None]
        assert explain(decoder, bytes(8)) == (INVALID_PAYLOAD, [])


class TestReasons:
    """Each invalid row says why, as the per-frame path reports it."""

    @pytest.fixture
    def decoder(self) -> MessageDecoder:
        """A battery-like message: a ranged current, a float, a presence flag, and a multiplexed pair."""
        msg = _message(_sig("I", 0, 16, is_signed=True, scale=0.1), _sig("F", 16, 32, is_float=True),
                       _sig("Pr", 48, 8))
        return MessageDecoder(msg, [Output("b", "current", "I", False, -100.0, 100.0),
                                    Output("b", "volts", "F", False), Output("b", "present", "Pr", True)])

    @pytest.mark.parametrize(("data", "reason"), [
        ((10).to_bytes(2, "little", signed=True) + np.float32(1.5).tobytes() + b"\x01\x00", ""),
        (b"\x00" * 7, INVALID_LENGTH),
        ((2000).to_bytes(2, "little", signed=True) + np.float32(1.5).tobytes() + b"\x01\x00", INVALID_RANGE),
        (b"\x00\x00" + np.float32("nan").tobytes() + b"\x01\x00", INVALID_NAN),
        (b"\x00\x00" + np.float32("inf").tobytes() + b"\x01\x00", INVALID_INF),
        (b"\x00\x00" + np.float32(1.0).tobytes() + b"\x00\x00", ABSENT),
    ])
    def test_reasons(self, decoder: MessageDecoder, data: bytes, reason: str) -> None:
        """Length, range, NaN, inf and a presence flag at 0 are each named; a valid row has none."""
        row = _one(decoder, data)[0]
        assert explain(decoder, data).reason == reason
        assert bool(row) is (reason == "")

    def test_a_float32_signalling_nan_is_nan_without_a_warning(self, decoder: MessageDecoder) -> None:
        """A float32 signalling NaN (which numpy flags as it widens it) is ``nan``, in a block and alone, and
        prints no numpy warning on the replay's stderr."""
        data = b"\x00\x00" + bytes.fromhex("0100807f") + b"\x01\x00"
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert list(decoder.decode(np.frombuffer(data * 2, np.uint8).reshape(2, 8), np.array([8, 8]))) == [
                None, None]
            assert _one(decoder, data) == [None]
            assert explain(decoder, data).reason == INVALID_NAN

    def test_multiplexer_pages(self) -> None:
        """A page with some configured signals is ``other_page``, with none EMPTY, an unknown one undecodable."""
        msg = _message(Signal("Sel", 0, 8, is_multiplexer=True),
                       _sig("A", 8, 8, multiplexer_ids=[0], multiplexer_signal="Sel"),
                       _sig("B", 8, 8, multiplexer_ids=[1], multiplexer_signal="Sel"),
                       _sig("C", 8, 8, multiplexer_ids=[2], multiplexer_signal="Sel"))
        decoder = MessageDecoder(msg, [Output("x", "a", "A", False), Output("x", "b", "B", False)])
        payload = np.array([[0, 9, 0, 0, 0, 0, 0, 0], [2, 9, 0, 0, 0, 0, 0, 0], [3, 9] + [0] * 6], dtype=np.uint8)
        assert list(decoder.decode(payload, np.array([8, 8, 8]))) == [None, EMPTY, None]
        assert explain(decoder, bytes([0, 9, 0, 0, 0, 0, 0, 0])) == (OTHER_PAGE, [(0, 9.0, "")])
        assert explain(decoder, bytes([2, 9, 0, 0, 0, 0, 0, 0])) == (NO_SIGNAL, [])
        assert explain(decoder, bytes([3, 9, 0, 0, 0, 0, 0, 0])).reason == INVALID_PAYLOAD


def test_a_padded_can_fd_payload_reads_as_cantools_reads_it() -> None:
    """A CAN FD message of 10 bytes sent padded to 12: the bit fields read the DBC's 10, as cantools does."""
    msg = _message(_sig("M", 7, 20, byte_order="big_endian", is_signed=True, scale=0.5),
                   _sig("L", 60, 12), length=10, fd=True)
    decoder = MessageDecoder(msg, [Output("x", "m", "M", False), Output("x", "l", "L", False)])
    assert decoder.strategy == "bits" and decoder.lengths == (10, 12)
    data = bytes(range(0xA1, 0xAB)) + b"\xff\xff"
    want = msg.decode(data, decode_choices=False)
    assert _one(decoder, data) == [(float(want["M"]), float(want["L"]))]
    assert explain(decoder, data[:11]).reason == INVALID_LENGTH
