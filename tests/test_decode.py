"""Tests of canguard.decode.decoder: configured frames decode exactly as cantools decodes them."""

from __future__ import annotations

import functools
import math
import random
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canguard.config.loader import load_config
from canguard.config.schema import Config
from canguard.decode.decoder import Decoder
from canguard.io.frame import INVALID_INF, INVALID_LENGTH, INVALID_NAN, INVALID_PAYLOAD, Frame, Sample
from checkout import REPO

HERE = REPO / "tests"
EXOTIC = HERE / "data" / "foundation_exotic.yaml"
BUNDLED = REPO / "config" / "canguard.yaml"

# (message, expected decoding strategy) for every message of the exotic test DBC
EXOTIC_MESSAGES = [
    ("Std_LE", "bits"),
    ("Ext_BE", "bits"),
    ("Floats", "bits"),
    ("Float_BE", "bits"),
    ("Fd_Aligned", "bits"),
    ("Odd", "bits"),
    ("Muxed", "bits"),
    ("Fd_Odd", "bits"),
]


@pytest.fixture(scope="module")
def exotic() -> Config:
    """The exotic test config (every DBC feature)."""
    return load_config(EXOTIC)


@pytest.fixture(scope="module")
def bundled() -> Config:
    """The bundled default config on dbc/robot.dbc."""
    return load_config(BUNDLED)


def expected_samples(cfg: Config, message_name: str, data: bytes, t: float) -> set[tuple[str, str, float]]:
    """What the decoder must yield for ``data``: cantools' values of the message's configured signals."""
    message = cfg.database.get_message_by_name(message_name)
    values = message.decode(data, decode_choices=False, scaling=True)
    out = set()
    for source in cfg.sources.values():
        for ref in source.signals:
            if ref.message == message_name and ref.signal in values:
                v = float(values[ref.signal])
                if ref.role == "present":
                    v = 1.0 if v else 0.0
                out.add((source.name, ref.role, v))
    return out


def frame_of(cfg: Config, message_name: str, data: bytes, t: float = 1.0) -> Frame:
    """A Frame carrying ``data`` with the message's id, id type and FD flag."""
    m = cfg.database.get_message_by_name(message_name)
    return Frame(t, "exotic", m.frame_id, data, m.is_extended_frame, m.is_fd)


def finite_payload(cfg: Config, message_name: str, rng: random.Random) -> bytes:
    """Random bytes of the message's length whose float signals are finite."""
    m = cfg.database.get_message_by_name(message_name)
    while True:
        data = bytes(rng.getrandbits(8) for _ in range(m.length))
        try:
            values = m.decode(data, decode_choices=False)
        except Exception:  # a multiplexer value of no branch: covered by TestDecoderInvalidAndCounters
            continue
        if all(math.isfinite(float(v)) for v in values.values()):
            return data


class TestDecoderMatchesCantools:
    """The fast path and the fallback both give exactly cantools' values."""

    @pytest.mark.parametrize(("message", "strategy"), EXOTIC_MESSAGES)
    def test_random_payloads_match(self, exotic: Config, message: str, strategy: str) -> None:
        """200 random payloads of each message decode to cantools' exact values, through the expected strategy."""
        decoder = Decoder(exotic)
        m = exotic.database.get_message_by_name(message)
        assert dict(decoder.entries())["main", m.frame_id, m.is_extended_frame].strategy == strategy
        rng = random.Random(message)
        for i in range(200):
            data = finite_payload(exotic, message, rng)
            samples = decoder.decode(frame_of(exotic, message, data, t=float(i)), "main")
            assert all(not s.reason and s.t == float(i) for s in samples)
            assert {(s.source, s.signal, s.value) for s in samples} == expected_samples(
                exotic, message, data, i
            )

    def test_extended_big_endian_scaled_offset_values(self, exotic: Config) -> None:
        """A Motorola signed 32-bit value (scale 0.001, offset 1.5, extended id) reads as cantools says."""
        m = exotic.database.get_message_by_name("Ext_BE")
        data = m.encode({"Current_I32": -1234.567, "Volt_U16": 48.2, "Temp_I8": -12})
        samples = {
            s.signal: s.value for s in Decoder(exotic).decode(frame_of(exotic, "Ext_BE", data), "main")
        }
        ref = m.decode(data, decode_choices=False)
        assert samples == {
            "current_i32": ref["Current_I32"],
            "volt_u16": ref["Volt_U16"],
            "temp_i8": float(ref["Temp_I8"]),
        }
        assert samples["temp_i8"] == -12.0

    def test_multiplexed_branch_only(self, exotic: Config) -> None:
        """A multiplexed frame yields only the signals of the branch its multiplexer selects."""
        m = exotic.database.get_message_by_name("Muxed")
        decoder = Decoder(exotic)
        page0 = decoder.decode(frame_of(exotic, "Muxed", m.encode({"Page": 0, "Cur_A": 12.3})), "main")
        page1 = decoder.decode(
            frame_of(exotic, "Muxed", m.encode({"Page": 1, "Cur_B": -4.5, "Temp_B": 30})), "main"
        )
        assert {s.signal: s.value for s in page0} == {"page": 0.0, "cur_a": pytest.approx(12.3)}
        assert {s.signal: s.value for s in page1} == {
            "page": 1.0,
            "cur_b": pytest.approx(-4.5),
            "temp_b": 30.0,
        }

    def test_can_fd_frames(self, exotic: Config) -> None:
        """64-byte and 12-byte CAN FD frames decode, the signal at byte 62 included."""
        decoder = Decoder(exotic)
        m = exotic.database.get_message_by_name("Fd_Aligned")
        data = m.encode({"Fd_Current": 7.25, "Fd_Tail_I16": -100.5})
        got = {s.signal: s.value for s in decoder.decode(frame_of(exotic, "Fd_Aligned", data), "main")}
        assert got == {"fd_current": 7.25, "fd_tail": pytest.approx(-100.5)}
        odd = exotic.database.get_message_by_name("Fd_Odd")
        data = odd.encode({"Fd_Cur20": -321.123, "Fd_Last": 200})
        got = {
            (s.source, s.signal): s.value for s in decoder.decode(frame_of(exotic, "Fd_Odd", data), "main")
        }
        assert got == {("fd_odd", "current"): pytest.approx(-321.123), ("all", "fd_last"): 200.0}

    def test_present_flag_is_one_or_zero(self, exotic: Config) -> None:
        """A battery's present signal becomes 1.0 / 0.0 next to its current."""
        m = exotic.database.get_message_by_name("Odd")
        decoder = Decoder(exotic)
        on = decoder.decode(
            frame_of(
                exotic, "Odd", m.encode({"Cur12": -20.5, "Flag": 1, "Motorola10": 0, "Unaligned_I16": 0})
            ),
            "main",
        )
        off = decoder.decode(
            frame_of(exotic, "Odd", m.encode({"Cur12": 3.0, "Flag": 0, "Motorola10": 0, "Unaligned_I16": 0})),
            "main",
        )
        assert {s.signal: s.value for s in on if s.source == "odd_battery"} == {
            "current": pytest.approx(-20.5),
            "present": 1.0,
        }
        assert {s.signal: s.value for s in off if s.source == "odd_battery"}["present"] == 0.0

    def test_bundled_battery_and_axis(self, bundled: Config) -> None:
        """On the robot DBC BMS_Status gives pack current and presence; an Iq frame gives axis current."""
        decoder = Decoder(bundled)
        bms = bundled.database.get_message_by_name("BMS_Status")
        data = bms.encode(
            {
                "Pack_Current": -123.4,
                "Pack_Voltage": 48.5,
                "State_Of_Charge": 80,
                "Present": 1,
                "Fault": 0,
                "Alive_Counter": 3,
            }
        )
        samples = decoder.decode(Frame(5.0, "can0", bms.frame_id, data, True), "main")
        assert samples == [
            Sample("/battery_state", "current", -123.4, 5.0),
            Sample("/battery_state", "present", 1.0, 5.0),
        ]
        iq = decoder.decode(Frame(6.0, "can0", 0x34, struct.pack("<ff", 2.0, -9.5)), "main")
        assert iq == [Sample("axis1", "current", -9.5, 6.0)]


class TestDecoderInvalidAndCounters:
    """Bad frames become invalid samples and counters; nothing raises."""

    def test_wrong_length_gives_bad_length_for_every_signal(self, bundled: Config) -> None:
        """A 6-byte BMS_Status gives a bad_length NaN sample per configured signal and one invalid frame."""
        decoder = Decoder(bundled)
        samples = decoder.decode(Frame(1.0, "can0", 0x18FF50E5, bytes(6), True), "main")
        assert [(s.signal, s.reason) for s in samples] == [
            ("current", INVALID_LENGTH),
            ("present", INVALID_LENGTH),
        ]
        assert all(math.isnan(s.value) and s.reason for s in samples)
        assert decoder.invalid == 1 and decoder.decoded == 0
        assert decoder.per_bus["main"].reasons == {INVALID_LENGTH: 2}

    @pytest.mark.parametrize(
        ("value", "reason"), [(math.nan, INVALID_NAN), (math.inf, INVALID_INF), (-math.inf, INVALID_INF)]
    )
    def test_nan_and_inf_floats(self, bundled: Config, value: float, reason: str) -> None:
        """A float32 current of NaN or +-inf becomes an invalid sample with that reason."""
        decoder = Decoder(bundled)
        [sample] = decoder.decode(Frame(1.0, "can0", 0x14, struct.pack("<ff", 0.0, value)), "main")
        assert sample.reason == reason and math.isnan(sample.value)
        assert decoder.invalid == 1

    def test_unknown_multiplexer_value_is_undecodable(self, exotic: Config) -> None:
        """A multiplexed frame whose multiplexer selects no branch gives undecodable samples."""
        decoder = Decoder(exotic)
        samples = decoder.decode(frame_of(exotic, "Muxed", bytes([7, 1, 2, 3, 4, 5, 6, 7])), "main")
        assert [(s.signal, s.reason) for s in samples] == [
            ("page", INVALID_PAYLOAD),
            ("cur_a", INVALID_PAYLOAD),
            ("cur_b", INVALID_PAYLOAD),
            ("temp_b", INVALID_PAYLOAD),
        ]

    def test_error_and_remote_frames_are_counted_not_decoded(self, bundled: Config) -> None:
        """Error and remote frames with a configured id give no samples and are counted."""
        decoder = Decoder(bundled)
        assert decoder.decode(Frame(1.0, "can0", 0x14, bytes(8), is_error_frame=True), "main") == []
        assert decoder.decode(Frame(1.0, "can0", 0x14, b"", is_remote_frame=True, dlc=8), "main") == []
        assert (decoder.error_frames, decoder.remote_frames, decoder.decoded, decoder.frames) == (1, 1, 0, 2)

    def test_unconfigured_frames_are_skipped(self, bundled: Config) -> None:
        """Unknown ids, a configured id on another bus and a standard/extended mismatch are all skipped."""
        decoder = Decoder(bundled)
        frames = [
            (Frame(1.0, "can0", 0x15, bytes(8)), "main"),  # no such configured message
            (Frame(1.0, "can0", 0x14, bytes(8)), "other"),  # configured id, wrong bus
            (Frame(1.0, "can0", 0x14, bytes(8), True), "main"),  # extended 0x14 is not Axis0_Get_Iq
            (Frame(1.0, "can0", 0x18FF50E5, bytes(8), False), "main"),  # BMS id as a (bogus) standard frame
        ]
        assert all(decoder.decode(f, bus) == [] for f, bus in frames)
        assert decoder.skipped == 4
        assert decoder.per_bus["other"].skipped == 1 and decoder.per_bus["main"].skipped == 3

    @settings(max_examples=300, deadline=None)
    @given(
        arbitration_id=st.one_of(
            st.sampled_from(
                [0x14, 0x1C, 0x34, 0x18FF50E5, 0x100, 0x103, 0x104, 0x105, 0x19000002, 0x19000003]
            ),
            st.integers(0, 0x1FFFFFFF),
        ),
        data=st.binary(max_size=64),
        extended=st.booleans(),
        fd=st.booleans(),
        error=st.booleans(),
        remote=st.booleans(),
        bus=st.sampled_from(["main", "other"]),
    )
    def test_fuzz_never_raises(
        self,
        arbitration_id: int,
        data: bytes,
        extended: bool,
        fd: bool,
        error: bool,
        remote: bool,
        bus: str,
    ) -> None:
        """Random ids, lengths, payloads and flags never raise; samples are finite or NaN with a reason."""
        for decoder in fuzz_decoders():
            frame = Frame(0.5, "x", arbitration_id, data, extended, fd, error, remote)
            for s in decoder.decode(frame, bus):
                assert (not s.reason and math.isfinite(s.value)) or (s.reason and math.isnan(s.value))


@functools.cache
def fuzz_decoders() -> tuple[Decoder, Decoder]:
    """The bundled and the exotic config's decoders, built once per process when first asked for (not at import:
    every pytest-xdist worker imports this module at collection)."""
    return Decoder(load_config(BUNDLED)), Decoder(load_config(EXOTIC))
