"""Current and effort guards (design note 004): IsCurrentNormal, IsCurrentSafe, IsI2tSafe, IsJointEffortNormal.

A guard's models, subscribed to its source at load, see every sample; at tick it fails when the source cannot be
trusted or a model tripped since the last tick (its peak latch), and journals ``trip`` / ``recover`` edges.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterable
from typing import Any, ClassVar

import py_trees

from canguard.bt.nodes.base import FAILURE, SUCCESS, CanguardNode, PortError, port_info
from canguard.config.schema import SourceConfig, SourceKind
from canguard.protect.base import REASON_I2T, REASON_NO_DATA, ProtectionModel, Snapshot
from canguard.protect.hysteresis import Hysteresis
from canguard.protect.i2t import RATED_OVERLOAD, RATED_OVERLOAD_S, LeakyI2t, ThermalI2t
from canguard.protect.inrush import InrushBlanking
from canguard.protect.staleness import SourceHealth
from canguard.protect.threshold import Threshold
from canguard.units import quantity

REASON_BAD_THRESHOLD = "bad_threshold"


class GuardNode(CanguardNode, py_trees.behaviour.Behaviour):
    """Base of the guard conditions: source lookup, health check, edge journal."""

    KIND = "Condition"
    CONST_PORTS = frozenset({"topic_name"})
    SOURCE_KINDS: ClassVar[tuple[SourceKind, ...]] = ("battery", "current")
    MODEL_KIND: ClassVar[str] = "threshold"
    ROLE: ClassVar[str] = "current"  # the source signal a single-signal guard reads
    QUIET_RETICK = True  # it answers from its source's health and its sample-driven models
    QUIET_OUTPUTS: ClassVar[frozenset[str]] = frozenset()
    """Output ports a quiet re-tick writes again (:meth:`quiet_retick`); another wired output makes it loud."""
    _NAMES: ClassVar[dict[str, str]] = {}  # the models' parameter names -> the ports that give them
    LIMITS: ClassVar[tuple[tuple[str, ...], Callable[[Any], tuple], Callable[..., None]]]
    """The threshold ports a tick reads again when wired to ``{key}``s, the model's values of them, its setter."""
    model: ProtectionModel
    source: SourceConfig | None = None
    health: SourceHealth | None = None
    ok: bool | None = None  # the last tick's status (None before the first)
    reason = ""  # why the last tick failed
    judged_t = math.nan  # when last ticked: a running task's guards must keep being ticked

    @property
    def topic_name(self) -> str:
        """The source name given in ``topic_name``."""
        return str(self.port("topic_name"))

    def bind(self) -> None:
        """Resolve the source, then build and subscribe the model(s)."""
        name = self.topic_name
        try:
            self.source = self.ctx.source(name, self.SOURCE_KINDS)
        except (KeyError, ValueError) as exc:
            raise PortError("topic_name", str(exc.args[0])) from None
        self.health = self.ctx.health[name]
        self._clock = self.ctx.clock
        try:
            self._build(self.source)
        except ValueError as exc:  # a model refused a value: said in the names of the ports
            if isinstance(exc, PortError) or not self._NAMES:
                raise
            raise self._model_error(exc) from None

    def _build(self, source: SourceConfig) -> None:
        raise NotImplementedError

    def quiet_retick(self, now: float) -> None:
        """What a tick that repeats the last one does besides answering the same (:mod:`canguard.engine.quiet`)."""
        self.judged_t = now

    def guarded(self) -> list[tuple[str, ProtectionModel, str]]:
        """``(role, model, kind)`` per guarded signal; kind is ``threshold`` or ``i2t`` (reports, plots)."""
        return [(self.ROLE, self.model, self.MODEL_KIND)]

    def _model_error(self, exc: ValueError) -> PortError:
        """A model's ValueError as a PortError on the first port it names, said in port names (``_NAMES``)."""
        names = self._NAMES
        params = re.compile(r"\b(" + "|".join(sorted(names, key=len, reverse=True)) + r")\b")
        first = params.search(str(exc))
        text = params.sub(lambda m: names[m[1]], str(exc))
        return PortError(names[first[1]] if first else next(iter(names.values())), text)

    def update(self) -> py_trees.common.Status:
        """The model's latch and the source's health, judged (thresholds read again first)."""
        now = self._clock.now()
        reason = self._reread((self.model,))
        return self._judge(now, self.model.poll(now), reason)

    def _reread(self, models: Iterable[Any]) -> str:
        """:data:`LIMITS` wired to ``{key}``s, read again: a change is applied to ``models`` and their latest
        sample judged again; REASON_BAD_THRESHOLD when one holds nothing or a value the model refuses."""
        if not self._dynamic:
            return ""
        ports, limits, apply = self.LIMITS
        values = tuple(self.port(p) for p in ports)
        try:
            if None in values:
                raise ValueError
            for model in models:
                if limits(model) != values:
                    apply(model, *values)
                    if model.last_t is not None:
                        model.advance((model.last_t,), (model.snapshot().value,))
        except ValueError:
            return REASON_BAD_THRESHOLD
        return ""

    def _judge(self, now: float, snap: Snapshot, reason: str, value: float | None = None) -> py_trees.common.Status:
        """SUCCESS or FAILURE (see :meth:`_why`), status changes journalled; ``value``: the events' value."""
        self.judged_t = now
        reason = self._why(now, self.ROLE, snap, reason)
        ok = not reason
        if ok is not self.ok or reason != self.reason:
            self._edge(ok, reason, self.ROLE, snap.value if value is None else value, snap.threshold)
        return SUCCESS if ok else FAILURE

    def _why(self, now: float, role: str, snap: Snapshot, bad: str = "") -> str:
        """Why ``role`` fails now: a port problem (``bad``), else its source's health, else its model's latch."""
        assert self.health is not None
        return bad or self.health.reason(now, role) or (snap.reason if snap.tripped else "")

    def _units(self, role: str) -> tuple[str, str]:
        """The unit of ``role``'s signal and of its model's threshold (the same, or A²s / θ for I²t)."""
        unit = self.ctx.unit(self.source.name, role) if self.source is not None else ""
        model = next((m for r, m, _ in self.guarded() if r == role), None)
        return unit, (model.THRESHOLD_UNIT if model is not None else None) or unit

    def _feedback(self, reason: str, role: str, value: float, threshold: float) -> str:
        """Why the guard fails, in words, each figure with its unit (feedback message, stop events)."""
        unit = self._units(role)[1]
        return f"{reason}: {role} |{quantity(value, unit)}| (threshold {quantity(threshold, unit)})"

    def _edge(self, ok: bool, reason: str, role: str, value: float, threshold: float) -> None:
        """Keep a readable feedback message; journal status changes (trip / recover)."""
        prev = self.ok
        self.reason = reason
        self.feedback_message = "" if ok else self._feedback(reason, role, value, threshold)
        if prev is None and not ok and reason == REASON_NO_DATA:
            # Before the source's first sample the guard fails (fail safe) but nothing tripped:
            # the status stays "never judged", and a source that never speaks is a `stale` event.
            return
        self.ok = ok
        if ok is prev or (prev is None and ok):
            return  # same status, another reason: feedback only
        assert self.source is not None
        self.ctx.record("recover" if ok else "trip", node=self.name, source=self.source.name, signal=role,
                        value=value, threshold=threshold, reason=reason)


class IsCurrentNormal(GuardNode):
    """SUCCESS while |current| <= max_current and the source is present, fresh and finite"""

    INPUT_PORTS = {  # noqa: RUF012 - py_trees reads ports as plain class dicts
        "topic_name": port_info(str, "source name (battery or current kind) from the config"),
        "max_current": port_info(float, "maximum allowed |current| (A)", 30.0),
    }
    _NAMES = {"max_value": "max_current"}  # noqa: RUF012
    LIMITS = (("max_current",), lambda m: (m.max_value,), Threshold.set_max)
    model: Threshold

    def _build(self, source: SourceConfig) -> None:
        self.model = Threshold(self.port("max_current"))
        self.ctx.subscribe(source.name, self.ROLE, self.model)


class IsCurrentSafe(GuardNode):
    """hysteresis overcurrent guard: FAILURE from |I| >= overcurrent_threshold until |I| <= recovery_threshold; optional
    persistence and inrush blanking"""

    INPUT_PORTS = {  # noqa: RUF012
        "topic_name": port_info(str, "source name (battery or current kind) from the config"),
        "overcurrent_threshold": port_info(float, "trip at |I| >= this (A)", 35.0),
        "recovery_threshold": port_info(float, "recover at |I| <= this (A); <= overcurrent_threshold", 25.0),
        "trip_after": port_info(float, "the overcurrent must last this long to trip (s)", 0.0),
        "recover_after": port_info(float, "the recovery must last this long to recover (s)", 0.0),
        "inrush_time": port_info(float, "inrush blanking window after a motor start (s); 0: off", 0.0),
        "inrush_threshold": port_info(float, "threshold inside the inrush window (A); absent: no check there",
                                      required=False),
        "start_current": port_info(float, "|I| above this counts as a motor start (A); needed with inrush_time",
                                   required=False),
    }
    CONST_PORTS = frozenset({"topic_name", "trip_after", "recover_after", "inrush_time", "inrush_threshold",
                             "start_current"})
    _NAMES: ClassVar[dict[str, str]] = {
        "overcurrent_a": "overcurrent_threshold", "recovery_a": "recovery_threshold", "trip_after_s": "trip_after",
        "recover_after_s": "recover_after", "inrush_time_s": "inrush_time", "inrush_threshold_a": "inrush_threshold",
        "start_current_a": "start_current"}
    LIMITS = (("overcurrent_threshold", "recovery_threshold"), lambda m: (m.overcurrent_a, m.recovery_a),
              Hysteresis.set_thresholds)
    model: Hysteresis

    def _build(self, source: SourceConfig) -> None:
        inrush = None
        inrush_time = self.port("inrush_time")
        if inrush_time:
            start = self.port("start_current")
            if start is None:
                raise PortError("start_current", "required when inrush_time > 0 (|I| of a motor start)")
            inrush = InrushBlanking(start, inrush_time, self.port("inrush_threshold"))
        over = self.port("overcurrent_threshold")
        rec = self.port("recovery_threshold")
        if over is None or rec is None:  # wired to keys not written yet: the defaults until they are
            over, rec = 35.0, 25.0
        self.model = Hysteresis(over, rec, trip_after_s=self.port("trip_after"),
                                recover_after_s=self.port("recover_after"), inrush=inrush, max_gap_s=source.max_age_s)
        self.ctx.subscribe(source.name, self.ROLE, self.model)


class IsI2tSafe(GuardNode):
    """I²t guard (leaky bucket or thermal image): FAILURE at 100 % heat until cooled"""

    INPUT_PORTS = {  # noqa: RUF012
        "topic_name": port_info(str, "source name (battery or current kind) from the config"),
        "model": port_info(str, "leaky (servo-drive bucket) or thermal (IEC 60255-8 image)", "leaky"),
        "continuous_current": port_info(float, "rated continuous current I_rated (A); I_cont = k * I_rated"),
        "peak_current": port_info(float, "datasheet peak current (A); default 1.5 × continuous_current (IEC 60034-1)",
                                  required=False),
        "peak_time": port_info(float, "how long the peak current is allowed from cold (s); default 120 without peak",
                               required=False),
        "tau": port_info(float, "thermal time constant (s), thermal model; default from the peak figures",
                         required=False),
        "tau_cool": port_info(float, "cooling time constant (s), thermal model; default tau", required=False),
        "k": port_info(float, "IEC k factor: I_cont = k * continuous_current", 1.0),
        "recover_fraction": port_info(float, "recover below this fraction of the trip level", 0.5),
    }
    OUTPUT_PORTS = {  # noqa: RUF012
        "level": port_info(float, "heat in % of the trip level (100 = trip)", required=False),
    }
    CONST_PORTS = frozenset(INPUT_PORTS)
    CHOICES = {"model": ("leaky", "thermal")}  # noqa: RUF012
    MODEL_KIND = "i2t"
    QUIET_OUTPUTS = frozenset({"level"})
    _NAMES: ClassVar[dict[str, str]] = {
        "continuous_a": "continuous_current", "peak_a": "peak_current", "peak_time_s": "peak_time",
        "tau_cool_s": "tau_cool", "tau_s": "tau", "recover_fraction": "recover_fraction"}

    def _build(self, source: SourceConfig) -> None:
        kind = self.port("model")
        cont = self.port("continuous_current")
        k = self.port("k")
        if not (isinstance(k, float) and math.isfinite(k) and k > 0):
            raise PortError("k", f"must be a finite number > 0, got {k!r}")
        if not (isinstance(cont, float) and math.isfinite(cont) and cont > 0):
            # said here, before a peak is derived from it (else the error blamed peak_current)
            raise PortError("continuous_current", f"continuous_current must be a finite number > 0, got {cont!r}")
        peak, peak_t = self.port("peak_current"), self.port("peak_time")
        if peak is not None and peak_t is None:
            raise PortError("peak_time", "required with peak_current (a datasheet peak is a current and a time)")
        if peak is None and not (kind == "thermal" and self.port("tau") is not None):
            # No datasheet peak: IEC 60034-1's occasional excess current, 1.5 × the rating for 120 s.
            peak = RATED_OVERLOAD * cont
            peak_t = RATED_OVERLOAD_S if peak_t is None else peak_t
            if peak <= cont * k:
                raise PortError("peak_current", f"required when k >= {RATED_OVERLOAD:g} (the derived peak {peak:g} "
                                f"A = {RATED_OVERLOAD:g} × continuous_current must exceed I_cont = k × "
                                f"continuous_current = {cont * k:g} A)")
        if kind == "leaky":
            self.model = LeakyI2t(cont * k, peak, peak_t, self.port("recover_fraction"), source.max_age_s)
        else:
            self.model = ThermalI2t(cont * k, peak, peak_t, tau_s=self.port("tau"), tau_cool_s=self.port("tau_cool"),
                                    recover_fraction=self.port("recover_fraction"), max_gap_s=source.max_age_s)
        self.ctx.subscribe(source.name, self.ROLE, self.model)
        self.ctx.heat_models[self.name] = self.model
        self._write_level = self.is_wired("level")

    def _feedback(self, reason: str, role: str, value: float, threshold: float) -> str:
        """I²t speaks of heat: the accumulator against its trip level, and the current that drives it."""
        if reason != REASON_I2T:
            return super()._feedback(reason, role, value, threshold)
        current = abs(self.health.value(role)) if self.health is not None else math.nan
        amps, heat = self._units(role)
        return (f"i2t: heat {quantity(value, heat)} of trip level {quantity(threshold, heat)} "
                f"({role} |{quantity(current, amps)}|)")

    def quiet_retick(self, now: float) -> None:
        """``level`` is written again (the heat moved with the samples)."""
        super().quiet_retick(now)
        if self._write_level:
            self.write("level", float(self.model.snapshot().level_pct))

    def update(self) -> py_trees.common.Status:
        now = self._clock.now()
        snap = self.model.poll(now)
        if self._write_level:
            self.write("level", float(snap.level_pct))
        # The event compares like with like: the accumulator (A²s, or θ) against its trip level.
        return self._judge(now, snap, "", float(getattr(self.model, "accumulator", snap.value)))


class IsJointEffortNormal(GuardNode):
    """SUCCESS while every joint's |effort| <= max_effort and every joint is fresh and finite"""

    INPUT_PORTS = {  # noqa: RUF012 - py_trees reads ports as plain class dicts
        "topic_name": port_info(str, "source name (joints kind) from the config"),
        "max_effort": port_info(float, "maximum allowed |effort| of any joint (N·m or N)", 100.0),
    }
    SOURCE_KINDS = ("joints",)
    _NAMES = {"max_value": "max_effort"}  # noqa: RUF012
    LIMITS = (("max_effort",), lambda m: (m.max_value,), Threshold.set_max)
    failed_joint = ""  # the first failing joint, named by the feedback

    def _build(self, source: SourceConfig) -> None:
        self.models: list[tuple[str, Threshold]] = [(role, Threshold(self.port("max_effort")))
                                                    for role in source.value_roles]
        for role, model in self.models:
            self.ctx.subscribe(source.name, role, model)

    def guarded(self) -> list[tuple[str, ProtectionModel, str]]:
        """One ``(joint, model, "threshold")`` per joint."""
        return [(role, model, "threshold") for role, model in self.models]

    def update(self) -> py_trees.common.Status:
        now = self._clock.now()
        self.judged_t = now  # the engine checks that a running task's guards keep being ticked (T4)
        bad = self._reread(m for _, m in self.models)
        failed: tuple[str, str, float, float] | None = None  # (reason, joint, value, threshold)
        for role, model in self.models:
            snap = model.poll(now)  # poll every joint: each latch restarts at every tick
            reason = "" if failed is not None else self._why(now, role, snap, bad)
            if reason:
                failed = (reason, role, snap.value, snap.threshold)
        if not self.models:
            failed = (REASON_NO_DATA, "", math.nan, math.nan)
        ok = failed is None
        # Another joint failing for the same reason is a new cause too (its feedback names the joint).
        if ok is not self.ok or (failed is not None and failed[:2] != (self.reason, self.failed_joint)):
            self.failed_joint = failed[1] if failed is not None else ""
            if failed is None:
                seen = [(m.snapshot(), role) for role, m in self.models if m.last_t is not None]
                snap, role = max(seen, key=lambda sr: sr[0].value)
                self._edge(True, "", role, snap.value, snap.threshold)
            else:
                self._edge(False, *failed)
        return SUCCESS if ok else FAILURE
