"""The contract every protection model passes (Threshold, Hysteresis, LeakyI2t, ThermalI2t)."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tests.feed import step

from canguard.protect import Hysteresis, LeakyI2t, ProtectionModel, ThermalI2t, Threshold
from canguard.protect.base import REASON_I2T, REASON_OK, REASON_OVERCURRENT

FACTORIES: dict[str, tuple[Callable[[], ProtectionModel], str]] = {
    "threshold": (lambda: Threshold(10.0), REASON_OVERCURRENT),
    "hysteresis": (lambda: Hysteresis(10.0, 5.0), REASON_OVERCURRENT),
    "leaky_i2t": (lambda: LeakyI2t(6.0, 12.0, 1.0), REASON_I2T),
    "thermal_i2t": (lambda: ThermalI2t(6.0, 12.0, 1.0), REASON_I2T),
}

DT = 0.01


MODES = ("runs_of_one", "long_runs")
"""How the tests feed the models: sample by sample (``update``), or whole runs (``advance``)."""


def feed(model: ProtectionModel, mode: str, values: list[float], times: list[float]) -> list[bool]:
    """Feed the samples as ``mode`` says; per sample, True where the tripped state changed."""
    if mode == "runs_of_one":
        return [step(model, v, t) for v, t in zip(values, times, strict=True)]
    edges = [False] * len(values)
    for i in model.advance(times, values).index.tolist():
        edges[i] = True
    return edges


def run_until(model: ProtectionModel, mode: str, current: float, t: float, want: bool, limit_s: float) -> float:
    """Feed ``current`` every DT from ``t`` until ``model.tripped == want``; return the time it did.

    ``long_runs``: one run over the whole time limit, stopped at its first edge.
    """
    times = [t + DT * k for k in range(1, round(limit_s / DT) + 1)]
    if mode == "runs_of_one":
        for now in times:
            step(model, current, now)
            if model.tripped == want:
                return now
    else:
        run = model.advance(times, [current] * len(times), until_edge=True)
        if run.changed and model.tripped == want:
            return float(run.t[0])
    raise AssertionError(f"model did not reach tripped={want} within {limit_s} s")


@pytest.fixture(params=sorted(FACTORIES))
def case(request: pytest.FixtureRequest) -> tuple[ProtectionModel, str]:
    factory, reason = FACTORIES[request.param]
    return factory(), reason


@pytest.fixture(params=MODES)
def mode(request: pytest.FixtureRequest) -> str:
    return str(request.param)


class TestProtectionModelContract:
    """Every protection model behaves the same way towards the engine and the nodes."""

    def test_is_a_protection_model(self, case: tuple[ProtectionModel, str]) -> None:
        """Each model implements the ProtectionModel interface."""
        model, _ = case
        assert isinstance(model, ProtectionModel)
        assert model.tripped is False

    def test_edges_match_tripped_state(self, case: tuple[ProtectionModel, str]) -> None:
        """update returns True exactly when tripped changes, through a trip and a recovery."""
        model, _ = case
        seq = [0.0] * 50 + [30.0] * 30 + [0.0] * 1000
        prev = model.tripped
        edges = 0
        for i, current in enumerate(seq):
            edge = step(model, current, i * DT)
            assert isinstance(edge, bool)
            assert edge == (model.tripped != prev)
            edges += edge
            prev = model.tripped
        assert edges == 2

    def test_a_long_run_finds_the_same_edges(self, case: tuple[ProtectionModel, str]) -> None:
        """advance over the whole run reports the trip and the recovery at the samples update does."""
        model, _ = case
        seq = [0.0] * 50 + [30.0] * 30 + [0.0] * 1000
        times = [i * DT for i in range(len(seq))]
        fresh = copy.deepcopy(model)
        run = model.advance(times, seq)
        per_sample = [i for i, (v, t) in enumerate(zip(seq, times, strict=True)) if step(fresh, v, t)]
        assert run.index.tolist() == per_sample and len(per_sample) == 2
        assert run.tripped.tolist() == [True, False] and run.t.tolist() == [times[i] for i in per_sample]
        assert model.snapshot() == fresh.snapshot()

    def test_poll_latches_a_trip_between_polls(self, case: tuple[ProtectionModel, str], mode: str) -> None:
        """A trip and recovery between two polls is reported once at the next poll, then cleared."""
        model, reason = case
        assert model.poll(0.0).tripped is False
        t = run_until(model, mode, 30.0, 0.0, True, 5.0)
        t = run_until(model, mode, 0.0, t, False, 60.0)
        assert model.snapshot().tripped is False
        latched = model.poll(t)
        assert latched.tripped is True
        assert latched.reason == reason
        again = model.poll(t + DT)
        assert again.tripped is False
        assert again.reason == REASON_OK

    def test_poll_keeps_reporting_while_tripped(self, case: tuple[ProtectionModel, str], mode: str) -> None:
        """While the model stays tripped every poll reports it, and snapshot never resets the latch."""
        model, _ = case
        t = run_until(model, mode, 30.0, 0.0, True, 5.0)
        assert model.snapshot().tripped is True
        assert model.poll(t).tripped is True
        assert model.poll(t).tripped is True
        assert model.snapshot().since == t

    def test_snapshots_are_finite(self, case: tuple[ProtectionModel, str], mode: str) -> None:
        """After samples, value, threshold and level are finite numbers and level grows with current."""
        model, _ = case
        feed(model, mode, [1.0, 1.0], [0.0, 0.5])
        low = model.snapshot()
        feed(model, mode, [30.0, 30.0], [0.6, 0.62])
        high = model.snapshot()
        for snap in (low, high):
            assert math.isfinite(snap.value) and math.isfinite(snap.threshold)
            assert math.isfinite(snap.level_pct) and snap.level_pct >= 0
        assert high.level_pct > low.level_pct
        assert high.value == 30.0

    def test_out_of_order_samples_are_harmless(self, case: tuple[ProtectionModel, str], mode: str) -> None:
        """Samples older than the latest one change nothing and never report an edge."""
        model, _ = case
        feed(model, mode, [1.0] * 20, [10.0 + i * DT for i in range(20)])
        before = model.snapshot()
        assert feed(model, mode, [1e6] * 4, [0.0, 5.0, 10.0, 10.1]) == [False] * 4
        assert model.snapshot() == before

    def test_non_finite_values_are_ignored(self, case: tuple[ProtectionModel, str], mode: str) -> None:
        """NaN or infinite values and times never raise nor change the state."""
        model, _ = case
        feed(model, mode, [1.0], [0.0])
        before = model.snapshot()
        bad = feed(model, mode, [math.nan, math.inf, 1.0, -math.inf], [1.0, 1.0, math.nan, math.inf])
        assert bad == [False] * 4
        assert model.snapshot() == before

    # differing_executors: pytest makes a new instance of the class per run; mutmut runs the
    # suite several times in one process (scripts/mutation.sh). The test keeps no state on self.
    @settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.differing_executors])
    @given(
        name=st.sampled_from(sorted(FACTORIES)),
        samples=st.lists(
            st.tuples(st.floats(-100, 100), st.floats(0, 10)), min_size=1, max_size=60
        ),
    )
    def test_shuffled_and_duplicated_timestamps_never_raise(
        self, name: str, samples: list[tuple[float, float]]
    ) -> None:
        """Any order of timestamps, duplicates included, keeps edges consistent and snapshots finite."""
        model = FACTORIES[name][0]()
        prev = model.tripped
        for value, t in samples + samples:
            edge = step(model, value, t)
            assert edge == (model.tripped != prev)
            prev = model.tripped
            snap = model.poll(t)
            assert math.isfinite(snap.level_pct) and snap.level_pct >= 0


class TestTimeMovesModelsOnlyThroughSamples:
    """The engine counts a quiet grid tick instead of running it only because no model changes with time alone."""

    @pytest.mark.parametrize("current", [0.0, 8.0, 30.0])
    def test_polls_without_samples_answer_the_same(self, case: tuple[ProtectionModel, str], current: float) -> None:
        """After any history, polls at later and later times (no sample between) give the same state."""
        model, _ = case
        for k in range(60):
            step(model, current if k >= 20 else 0.0, k * DT)
        model.poll(60 * DT)  # the peak latch is reset by a poll: compare the polls after it
        first = model.poll(61 * DT)
        for later in (62 * DT, 1.0, 10.0, 1000.0):
            again = model.poll(later)
            assert (again.tripped, again.reason, again.value, again.threshold) == (
                first.tripped, first.reason, first.value, first.threshold)
            assert again.level_pct == first.level_pct or (math.isnan(again.level_pct) and math.isnan(first.level_pct))
        assert model.snapshot().tripped == model.tripped
