"""One sample at a time through the run API (a run of one), as the tests feed models and source health."""

from __future__ import annotations

from canguard.bt.context import Context
from canguard.io.frame import Sample
from canguard.protect.base import ProtectionModel
from canguard.protect.staleness import SourceHealth


def step(model: ProtectionModel, value: float, t: float) -> bool:
    """Feed one sample to ``model`` (a run of one); True when its tripped state changed."""
    return model.advance((t,), (value,)).changed


def observe(health: SourceHealth, sample: Sample) -> bool:
    """Feed one sample to a source's health (a run of one row of one role); True when its reason changed."""
    return health.advance((sample.signal,), (float(sample.t),), ((float(sample.value),),), ((sample.reason,),)).changed


def dispatch(ctx: Context, sample: Sample) -> bool:
    """Feed one decoded sample as the engine does: its source's health, then (unless its decoder found it
    invalid) every model subscribed to its role; True on any edge."""
    health = ctx.health.get(sample.source)
    if health is None:
        return False
    edge = observe(health, sample)
    if sample.reason:
        return edge
    for model in ctx.subscribers(sample.source, sample.signal):
        if step(model, float(sample.value), float(sample.t)):
            edge = True
    return edge
