"""The models' run methods against the per-sample reference maths: same edges at the same samples, same state."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tests.reference_models import RefHealth, RefHysteresis, RefI2t, RefInrush, RefLatched, RefThreshold

from canguard.config.schema import SignalRef, SourceConfig
from canguard.protect import Hysteresis, InrushBlanking, LeakyI2t, SourceHealth, ThermalI2t, Threshold
from canguard.protect.base import CHUNK, LatchedModel
from canguard.protect.staleness import COUNTER, PRESENT

REL = 1e-9

# A time step: mostly a regular one, sometimes repeated, backwards, huge, or not a number.
STEPS = st.one_of(
    st.floats(0.001, 0.05),
    st.floats(0.001, 0.05),
    st.floats(0.001, 0.05),
    st.just(0.0),
    st.floats(-2.0, -1e-6),
    st.floats(1.0, 1e7),
    st.sampled_from([math.nan, math.inf, -math.inf]),
)
# A value: around the thresholds the factories use, sometimes exactly on one, huge, or not a number.
VALUES = st.one_of(
    st.floats(-40.0, 40.0),
    st.floats(-40.0, 40.0),
    st.sampled_from([0.0, 5.0, 6.0, 10.0, 12.0, -10.0, 1e200, math.nan, math.inf, -math.inf]),
)


@st.composite
def streams(draw: st.DrawFn, max_size: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """Times (running sums of random steps; a bad step gives one bad time) and values of one signal."""
    steps = draw(st.lists(STEPS, min_size=1, max_size=max_size))
    values = draw(st.lists(VALUES, min_size=len(steps), max_size=len(steps)))
    times, t = [], 0.0
    for step in steps:
        if math.isfinite(step):
            t += step
            times.append(t)
        else:
            times.append(step)
    return np.array(times), np.array(values)


@st.composite
def calm_streams(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """Long runs mostly on the quiet side of every model (small currents, regular times), now and then a sample
    of :data:`STEPS` and :data:`VALUES`: the runs a model takes whole from their last sample."""
    n = draw(st.integers(49, 300))
    odd = draw(st.lists(st.integers(0, n - 1), max_size=3))
    times = np.cumsum(np.full(n, draw(st.sampled_from([0.001, 0.01, 0.04]))))
    values = np.array(draw(st.lists(st.floats(-5.0, 5.0), min_size=n, max_size=n)))
    for i in odd:
        step, value = draw(STEPS), draw(VALUES)
        times[i:] += step if math.isfinite(step) else 0.0
        if not math.isfinite(step):
            times[i] = step
        values[i] = value
    return times, values


Pair = tuple[Callable[[], LatchedModel], Callable[[], RefLatched]]


@st.composite
def pairs(draw: st.DrawFn) -> tuple[str, Pair]:
    """A model kind with random parameters, and the reference with the same ones."""
    kind = draw(st.sampled_from(["threshold", "hysteresis", "inrush", "leaky", "thermal"]))
    if kind == "threshold":
        limit = draw(st.sampled_from([0.0, 10.0, 12.5]))
        return kind, (lambda: Threshold(limit), lambda: RefThreshold(max_value=limit))
    gap = draw(st.sampled_from([math.inf, 0.1, 2.0]))
    if kind in ("hysteresis", "inrush"):
        over = draw(st.sampled_from([10.0, 12.0]))
        rec = draw(st.sampled_from([5.0, over]))
        trip_after = draw(st.sampled_from([0.0, 0.02, 0.1]))
        rec_after = draw(st.sampled_from([0.0, 0.03, 0.2]))
        if kind == "hysteresis":
            return kind, (lambda: Hysteresis(over, rec, trip_after, rec_after, max_gap_s=gap),
                          lambda: RefHysteresis(overcurrent_a=over, recovery_a=rec, trip_after_s=trip_after,
                                                recover_after_s=rec_after, max_gap_s=gap))
        inrush_thr = draw(st.sampled_from([None, 3.0, 20.0]))
        start, window = draw(st.sampled_from([2.0, 6.0])), draw(st.sampled_from([0.0, 0.05, 0.2]))
        return kind, (
            lambda: Hysteresis(over, rec, trip_after, rec_after, InrushBlanking(start, window, inrush_thr),
                               max_gap_s=gap),
            lambda: RefHysteresis(overcurrent_a=over, recovery_a=rec, trip_after_s=trip_after,
                                  recover_after_s=rec_after, max_gap_s=gap,
                                  inrush=RefInrush(start, window, inrush_thr)),
        )
    frac = draw(st.sampled_from([0.5, 0.9]))
    if kind == "leaky":
        peak_time = draw(st.sampled_from([0.05, 1.0, 3.0]))
        return kind, (lambda: LeakyI2t(6.0, 12.0, peak_time, frac, gap),
                      lambda: RefI2t(kind="leaky", peak_time_s=peak_time, recover_fraction=frac, max_gap_s=gap))
    tau, cool = draw(st.sampled_from([0.05, 1.0])), draw(st.sampled_from([None, 0.3, 5.0]))
    return kind, (lambda: ThermalI2t(6.0, tau_s=tau, tau_cool_s=cool, recover_fraction=frac, max_gap_s=gap),
                  lambda: RefI2t(kind="thermal", tau_s=tau, tau_cool_s=tau if cool is None else cool,
                                 recover_fraction=frac, max_gap_s=gap))


def reference_edges(ref: Any, times: np.ndarray, values: np.ndarray) -> list[int]:
    """The samples at which the reference's tripped state changed."""
    return [i for i, (t, v) in enumerate(zip(times.tolist(), values.tolist(), strict=True)) if ref.update(v, t)]


def feed(model: LatchedModel, times: np.ndarray, values: np.ndarray, cuts: list[int], until_edge: bool) -> list[int]:
    """Feed the samples as runs split at ``cuts``, stopping at each edge if asked; the edges' positions."""
    edges: list[int] = []
    bounds = [0, *sorted(set(cuts)), len(times)]
    for lo, hi in itertools.pairwise(bounds):
        pos = lo
        while pos < hi:
            was = model.tripped
            run = model.advance(times[pos:hi], values[pos:hi], until_edge=until_edge)
            assert run.tripped.tolist() == [was == (k % 2 == 1) for k in range(run.index.size)]
            assert run.changed == bool(run.index.size) and (not until_edge or run.index.size <= 1)
            edges.extend((pos + run.index).tolist())
            assert run.taken > 0
            pos += run.taken
    return edges


def assert_ways_follow_the_reference(pair: tuple[str, Pair], stream: tuple[np.ndarray, np.ndarray],
                                     data: st.DataObject, ways: tuple[tuple[str, bool], ...]) -> None:
    """Feed ``stream`` to fresh models each way (whole, as runs of one, cut at drawn points; with or without
    until_edge): every way gives the reference's edges and ends in its state."""
    _kind, (make, make_ref) = pair
    times, values = stream
    ref = make_ref()
    want = reference_edges(ref, times, values)
    n = len(times)
    cuts = data.draw(st.lists(st.integers(1, max(1, n - 1)), max_size=8)) if n > 1 else []
    splits = {"whole": [], "ones": list(range(1, n)), "cuts": cuts}
    for way, until_edge in ways:
        model = make()
        assert feed(model, times, values, splits[way], until_edge) == want
        assert_same_state(model, ref)


def close(a: float | None, b: float | None, scale: float = 1.0) -> bool:
    """Equal within 1e-9 relative (of the larger or of ``scale``), None and NaN equal to themselves."""
    if a is None or b is None:
        return a is b
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return math.isclose(a, b, rel_tol=REL, abs_tol=REL * scale)


def assert_same_state(model: LatchedModel, ref: Any) -> None:
    """The model's state is the reference's: tripped, edge time, latest sample, maths state."""
    assert model.tripped == ref.tripped
    assert close(model.since, ref.since)
    assert close(model.last_t, ref.last_t)
    assert close(model.snapshot().value, ref.value)
    if isinstance(model, (LeakyI2t, ThermalI2t)):
        assert close(model.accumulator, ref.acc, model.trip_level)
        assert close(model.held_a, ref.held)
        assert close(model.peak_level_pct, 100.0 * ref.peak / ref.trip_level, 100.0)  # over every sample taken
    if isinstance(model, Hysteresis):
        over, under = model.timers
        assert close(over, ref.over_since) and close(under, ref.under_since)
        if model.inrush is not None:
            assert close(model.inrush.running()[1], ref.inrush.window_start)


SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(pair=pairs(), stream=st.one_of(streams(), calm_streams()), data=st.data())
def test_runs_match_the_per_sample_reference(pair: tuple[str, Pair], stream: tuple[np.ndarray, np.ndarray],
                                             data: st.DataObject) -> None:
    """Runs of one, one long run and a run split at random points all trip and recover where the reference does."""
    assert_ways_follow_the_reference(pair, stream, data, (("whole", False), ("ones", False), ("cuts", False),
                                                          ("cuts", True)))


@st.composite
def long_streams(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """Over three of the screen's chunks: a quiet current with bursts over the thresholds at drawn places (across
    a chunk's edge among them), a repeated time, a gap and a not-a-number."""
    n = 3 * CHUNK + draw(st.integers(0, 100))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    times = np.cumsum(np.full(n, 0.01))
    values = rng.uniform(-3.0, 3.0, n)
    for start in (CHUNK - 5, *draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=4))):
        values[start:start + draw(st.integers(1, 300))] = draw(st.sampled_from([15.0, -40.0, 11.0, 7.0]))
    at = draw(st.integers(1, n - 2))
    times[at] = times[at - 1]
    times[at + 1:] += draw(st.sampled_from([0.0, 2.0]))
    values[draw(st.integers(0, n - 1))] = math.nan
    return times, values


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(pair=pairs(), stream=long_streams(), data=st.data())
def test_long_runs_match_the_per_sample_reference(pair: tuple[str, Pair], stream: tuple[np.ndarray, np.ndarray],
                                                  data: st.DataObject) -> None:
    """A run longer than the screen's chunk, whole or cut, edge by edge or not, trips and recovers where the
    reference does (a quiet chunk taken whole, a busy one walked)."""
    assert_ways_follow_the_reference(pair, stream, data, (("whole", False), ("whole", True), ("cuts", True)))


@SETTINGS
@given(pair=pairs(), stream=streams(max_size=120), data=st.data())
def test_a_reload_carries_mid_run(pair: tuple[str, Pair], stream: tuple[np.ndarray, np.ndarray],
                                  data: st.DataObject) -> None:
    """A model that takes over another's state between two runs continues as if nothing happened."""
    _kind, (make, make_ref) = pair
    times, values = stream
    ref = make_ref()
    want = reference_edges(ref, times, values)
    cut = data.draw(st.integers(0, len(times)))
    first = make()
    edges = (first.advance(times[:cut], values[:cut]).index).tolist()
    second = make()
    second.carry_from(first)
    edges += (cut + second.advance(times[cut:], values[cut:]).index).tolist()
    assert edges == want
    assert second.tripped == ref.tripped


def test_until_edge_stops_right_after_the_edge() -> None:
    """With until_edge a run stops at the first edge, so a poll there sees the trip, and the rest continues."""
    model = Threshold(10.0)
    t = np.arange(1000) * 0.01
    v = np.where((t > 5.0) & (t < 5.05), 20.0, 1.0)
    first = model.advance(t, v, until_edge=True)
    assert first.index.tolist() == [501] and first.taken == 502 and first.tripped.tolist() == [True]
    assert model.poll(t[501]).tripped
    rest = model.advance(t[first.taken:], v[first.taken:], until_edge=True)
    assert (first.taken + rest.index).tolist() == [505] and not model.tripped
    assert rest.tripped.tolist() == [False]


def test_mismatched_columns_are_refused() -> None:
    """Times and values of different lengths raise a ValueError naming both shapes; the state is untouched."""
    model = Hysteresis(10.0, 5.0)
    with pytest.raises(ValueError, match=r"\(3,\) and \(2,\)"):
        model.advance([0.0, 1.0, 2.0], [1.0, 2.0])
    assert model.last_t is None


def test_inrush_run_matches_per_sample() -> None:
    """The inrush helper finds the same starts over a run as sample by sample."""
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.0, 0.05, 3000))
    a = rng.choice([0.0, 1.0, 8.0, 30.0], 3000)
    ref = RefInrush(2.0, 0.1, 20.0)
    want = [i for i in range(3000) if ref.observe(float(a[i]), float(t[i]))]
    helper = InrushBlanking(2.0, 0.1, 20.0)
    assert np.flatnonzero(helper.advance(t, a)).tolist() == want
    assert helper.running()[1] == ref.window_start


def health_run(health: SourceHealth, role: str, times: Any, values: Any, until_edge: bool = False,
               lists: bool = True) -> Any:
    """A run of one role's samples through :meth:`SourceHealth.advance` (rows of one sample), as lists or (``lists``
    False, given numpy columns) as the numpy columns of a block's column decode."""
    if lists:
        times = times.tolist() if hasattr(times, "tolist") else list(times)
        values = values.tolist() if hasattr(values, "tolist") else list(values)
    return health.advance((role,), times, (values,), until_edge=until_edge)


def _health_ref(role_names: tuple[str, ...], present: bool) -> tuple[SourceHealth, RefHealth]:
    roles = (*role_names, *((PRESENT,) if present else ()), COUNTER)
    signals = tuple(SignalRef(r, "can0", "M", 0x10, False, r.upper(), "", -50.0 if r == "current" else None,
                              50.0 if r == "current" else None) for r in roles)
    cfg = SourceConfig("src", "current", "can0", signals, 0.1)
    health = SourceHealth(cfg)
    ranges = {r: (-50.0, 50.0) for r in roles if r == "current"}
    return health, RefHealth(0.1, cfg.value_roles, present, ranges)


@SETTINGS
@given(stream=streams(), present=st.booleans(), data=st.data())
def test_source_health_runs_match_the_reference(stream: tuple[np.ndarray, np.ndarray], present: bool,
                                                data: st.DataObject) -> None:
    """Runs of one role's samples find the reason edges of the sample-by-sample reference, at the same samples."""
    roles = data.draw(st.lists(st.sampled_from(["current", PRESENT, COUNTER]), min_size=len(stream[0]),
                               max_size=len(stream[0])))  # one role a sample
    assert_health_runs_follow_the_reference(stream, roles, present, data.draw(st.booleans()))


def _long_run(bad_at: int, value: float, gap_at: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """60 samples 10 ms apart at 1 A (a run past the short-run screen), ``value`` at ``bad_at``, and from ``gap_at``
    on every time 0.3 s later (a gap longer than the source's 0.1 s ``max_age``)."""
    t = np.round(np.arange(60) * 0.01, 6)
    if gap_at >= 0:
        t[gap_at:] += 0.3
    v = np.ones(60)
    v[bad_at] = value
    return t, v


@pytest.mark.parametrize("stream", [_long_run(10, math.nan), _long_run(30, 99.0), _long_run(59, math.inf),
                                    _long_run(20, math.nan, gap_at=21), _long_run(20, 1.0, gap_at=40)],
                         ids=["nan then good", "out of range then good", "inf last", "nan then a gap", "a gap"])
def test_source_health_long_runs_of_one_role_match_the_reference(stream: tuple[np.ndarray, np.ndarray]) -> None:
    """In one long run of one role (judged as columns), a good sample after an invalid one or after a gap is the
    edge back to fresh, as sample by sample."""
    assert_health_runs_follow_the_reference(stream, ["current"] * 60, False, False)


def assert_health_runs_follow_the_reference(stream: tuple[np.ndarray, np.ndarray], roles: list[str], present: bool,
                                            until_edge: bool) -> None:
    """``SourceHealth.advance`` over each run of consecutive samples of one role gives the reference's reason
    edges at the same samples, and ends in its counts, reason and value."""
    times, values = stream
    with np.errstate(invalid="ignore"):  # few distinct counter values; NaN and inf stay
        values = np.where(np.isfinite(values), np.round(values) % 3.0, values)
    roles = [r if present or r != PRESENT else "current" for r in roles]
    health, ref = _health_ref(("current",), present)
    want = [i for i, (r, t, v) in enumerate(zip(roles, times.tolist(), values.tolist(), strict=True))
            if ref.observe(r, t, v)]
    got: list[int] = []
    start = 0
    while start < len(times):  # runs of consecutive samples of one role
        end = start
        while end < len(times) and roles[end] == roles[start]:
            end += 1
        pos = start
        while pos < end:
            run = health_run(health, roles[start], times[pos:end], values[pos:end], until_edge)
            got.extend((pos + run.index).tolist())
            pos += run.taken
        start = end
    assert got == want
    now = float(np.nanmax(np.where(np.isfinite(times), times, np.nan))) if np.isfinite(times).any() else 0.0
    assert health.reason(now) == ref.reason(now)
    assert close(health.value("current"), ref.values.get("current", math.nan))


@pytest.mark.parametrize("cuts", [[], [12], list(range(1, 40))])
def test_a_timer_starts_after_the_edge_that_stopped_it(cuts: list[int]) -> None:
    """A sample that both recovers and overcurrents (equal thresholds) restarts the trip timer at the next sample."""
    t = np.round(np.arange(40) * 0.01, 6)
    v = np.where(t <= 0.1, 20.0, 10.0)
    ref = RefHysteresis(overcurrent_a=10.0, recovery_a=10.0, trip_after_s=0.1)
    want = reference_edges(ref, t, v)
    assert want[:2] == [10, 11]  # tripped after 0.1 s at 20 A, recovered at 10 A (<= recovery_a)
    model = Hysteresis(10.0, 10.0, trip_after_s=0.1)
    assert feed(model, t, v, cuts, False) == want
    assert_same_state(model, ref)


def test_source_health_says_its_state_publicly() -> None:
    """The latest time, invalid reason and last reason of a role are readable without touching private state."""
    health, _ref = _health_ref(("current",), False)
    assert health.value_roles == ("current",) and health.latest_t("current") is None
    run = health_run(health, "current", [0.0, 0.01, 0.02, 0.03], [1.0, 2.0, 99.0, 3.0])
    assert run.index.tolist() == [0, 2, 3] and run.tripped.tolist() == [False, True, False]
    assert health.latest_t("current") == 0.03 and health.reason(0.03, "current") == ""
    assert health.value("current") == 3.0
    assert health.latest_times() == {"current": 0.03}
    health_run(health, "current", [0.04], [math.nan])
    assert health.reason(0.04, "current") == "nan" and health.value("current") == 3.0


def test_heat_after_a_long_run_survives_a_restart() -> None:
    """The heat a long run leaves is what the reference reaches, and a restored model starts from that level."""
    t, v = np.arange(200_000) * 1e-3, np.where(np.arange(200_000) % 20_000 < 9_000, 13.0, 2.0)
    for make, make_ref in ((lambda: LeakyI2t(6.0, 12.0, 3.0), lambda: RefI2t(kind="leaky", peak_time_s=3.0)),
                           (lambda: ThermalI2t(6.0, tau_s=3.0, tau_cool_s=6.0),
                            lambda: RefI2t(kind="thermal", tau_s=3.0, tau_cool_s=6.0))):
        model, ref = make(), make_ref()
        assert model.advance(t, v).index.tolist() == reference_edges(ref, t, v)
        assert close(model.accumulator, ref.acc, model.trip_level) and model.level > 0.1
        restored = make()
        restored.restore(model.export(), 0.0)
        assert close(restored.level, model.level) and restored.tripped == model.tripped


def feed_lists(model: LatchedModel, times: np.ndarray, values: np.ndarray, lengths: list[int],
               until_edge: bool) -> list[int]:
    """Feed the samples as Python lists in runs of the given lengths (cycled), stopping at edges if asked."""
    tl, vl = times.tolist(), values.tolist()
    edges: list[int] = []
    pos, k = 0, 0
    while pos < len(tl):
        end = min(len(tl), pos + lengths[k % len(lengths)])
        k += 1
        while pos < end:
            run = model.advance(tl[pos:end], vl[pos:end], until_edge=until_edge)
            edges.extend((pos + run.index).tolist())
            pos += run.taken
    return edges


class TestShortRuns:
    """The differential tests on short runs (1..70 samples), which a model takes without its numpy screen."""

    @SETTINGS
    @given(pair=pairs(), stream=streams(max_size=70), data=st.data())
    def test_short_runs_match_the_per_sample_reference(self, pair: tuple[str, Pair],
                                                       stream: tuple[np.ndarray, np.ndarray],
                                                       data: st.DataObject) -> None:
        """A short stream whole, as runs of one, split and stopped at edges trips where the reference does."""
        assert_ways_follow_the_reference(pair, stream, data, (("whole", False), ("whole", True), ("ones", False),
                                                              ("cuts", True)))

    @SETTINGS
    @given(pair=pairs(), stream=streams(max_size=300),
           lengths=st.lists(st.integers(1, 70), min_size=1, max_size=6), until_edge=st.booleans())
    def test_runs_either_side_of_the_screen_agree(self, pair: tuple[str, Pair], stream: tuple[np.ndarray, np.ndarray],
                                                  lengths: list[int], until_edge: bool) -> None:
        """Runs of 1..70 samples as lists, some short (no screen) and some long (screened), follow the reference."""
        _kind, (make, make_ref) = pair
        times, values = stream
        ref = make_ref()
        want = reference_edges(ref, times, values)
        model = make()
        assert feed_lists(model, times, values, lengths, until_edge) == want
        assert_same_state(model, ref)


def test_a_short_run_makes_no_numpy_call(monkeypatch: pytest.MonkeyPatch) -> None:
    """A run of one sample (the live bus) reaches every model's kernel without building a numpy column."""
    models = [Threshold(10.0), Hysteresis(10.0, 5.0, 0.01, 0.01, InrushBlanking(2.0, 0.1, 20.0), max_gap_s=0.5),
              LeakyI2t(6.0, 12.0, 1.0), ThermalI2t(6.0, tau_s=1.0)]

    def refuse(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("a numpy column was built for a short run")

    monkeypatch.setattr(np, "asarray", refuse)
    monkeypatch.setattr(np, "isfinite", refuse)
    for model in models:
        assert not model.advance((0.0,), (1.0,)).changed
        assert model.advance((0.01, 0.02), (30.0, 30.0)).taken == 2
        assert model.tripped == isinstance(model, (Threshold, Hysteresis))


@SETTINGS
@given(stream=streams(), lengths=st.lists(st.integers(1, 120), min_size=1, max_size=4), until_edge=st.booleans(),
       lists=st.booleans())
def test_source_health_long_and_short_runs_match_the_reference(stream: tuple[np.ndarray, np.ndarray],
                                                               lengths: list[int], until_edge: bool,
                                                               lists: bool) -> None:
    """One role's samples in runs of 1..120 (short ones one by one, long ones screened), as lists or numpy columns,
    find the reference's edges; the latest value stays a Python float."""
    times, values = stream
    health, ref = _health_ref(("current",), False)
    want = [i for i, (t, v) in enumerate(zip(times.tolist(), values.tolist(), strict=True))
            if ref.observe("current", t, v)]
    got: list[int] = []
    pos, k = 0, 0
    while pos < len(times):
        end = min(len(times), pos + lengths[k % len(lengths)])
        k += 1
        while pos < end:
            run = health_run(health, "current", times[pos:end], values[pos:end], until_edge, lists)
            got.extend((pos + run.index).tolist())
            pos += run.taken
    assert got == want
    assert close(health.value("current"), ref.values.get("current", math.nan))
    assert type(health.value("current")) is float


@SETTINGS
@given(stream=streams(), present=st.lists(st.sampled_from([1.0, 1.0, 1.0, 0.0]), min_size=300, max_size=300),
       lengths=st.lists(st.integers(1, 60), min_size=1, max_size=4), until_edge=st.booleans(), lists=st.booleans())
def test_source_health_rows_of_two_roles_match_the_reference(stream: tuple[np.ndarray, np.ndarray],
                                                             present: list[float], lengths: list[int],
                                                             until_edge: bool, lists: bool) -> None:
    """Rows of a current and its presence flag (one message), in runs of 1..60 rows, find the reference's edges at
    the same rows: a run whose flag stays set and whose currents are fresh and valid is taken whole."""
    times, values = stream
    tl, vl, pl = times.tolist(), values.tolist(), present[:len(times)]
    health, ref = _health_ref(("current",), True)
    health = SourceHealth(SourceConfig("src", "battery", "can0", health.source.signals[:2], 0.1))
    want = [i for i in range(len(tl)) if ref.observe("current", tl[i], vl[i]) | ref.observe(PRESENT, tl[i], pl[i])]
    got: list[int] = []
    pos, k = 0, 0
    while pos < len(tl):
        end = min(len(tl), pos + lengths[k % len(lengths)])
        k += 1
        while pos < end:
            cols: Any = (tl[pos:end], (vl[pos:end], pl[pos:end])) if lists else (
                times[pos:end], (values[pos:end], np.array(pl[pos:end])))
            run = health.advance(("current", PRESENT), *cols, until_edge=until_edge)
            got.extend((pos + run.index).tolist())
            pos += run.taken
    assert got == want
    assert health.reason(tl[-1] if tl else 0.0) == ref.reason(tl[-1] if tl else 0.0)


MOSTLY_QUIET = st.lists(st.integers(0, 15).flatmap(lambda k: st.tuples(
    STEPS if k == 0 else st.floats(0.0, 0.04), VALUES if k == 1 else st.floats(-40.0, 40.0), st.sampled_from([0, 1]))),
    min_size=2, max_size=60)
"""Rows of a source fed by two messages: (time step, value, which message), mostly fresh and valid."""


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(drawn=MOSTLY_QUIET)
def test_quiet_runs_of_two_messages_are_taken_whole_or_not_at_all(drawn: list[tuple[float, float, int]]) -> None:
    """A source fed by two messages (a role each, rows interleaved): ``take_quiet`` takes both runs whole only when
    the reference, fed the rows in time order, finds no edge among them, and leaves it where the reference does;
    else nothing is taken."""
    signals = tuple(SignalRef(r, "can0", m, 0x10 + k, False, r.upper(), "", -50.0, 50.0)
                    for k, (r, m) in enumerate((("j0", "M0"), ("j1", "M1"))))
    cfg = SourceConfig("src", "joints", "can0", signals, 0.1)
    health, ref = SourceHealth(cfg), RefHealth(0.1, cfg.value_roles, False, {"j0": (-50.0, 50.0), "j1": (-50.0, 50.0)})
    roles = ["j0", "j1"]
    for role in roles:  # both fresh and valid before the runs
        assert health.advance((role,), [0.0], ([1.0],)).changed == ref.observe(role, 0.0, 1.0)
    rows, t = [], 0.0
    for i, (step, value, k) in enumerate(drawn):  # in arrival order (a bad step: one bad time); both messages
        k = i if i < 2 else k
        t += step if math.isfinite(step) else 0.0
        rows.append((t if math.isfinite(step) else step, value, k))
    parts = [((role,), np.array([r[0] for r in rows if r[2] == k]), (np.array([r[1] for r in rows if r[2] == k]),))
             for k, role in enumerate(roles)]
    before = health.latest_times()
    took = health.take_quiet(parts)
    edges = [ref.observe(roles[k], t, v) for t, v, k in rows]
    if took:
        assert not any(edges)
        assert health.reason(0.0) == ref.reason(0.0)
        for role in roles:
            assert health.latest_t(role) == ref.latest_t[role] and health.value(role) == ref.values[role]
            assert type(health.value(role)) is float
    else:
        assert health.latest_times() == before
