"""A bus that refuses every frame: stderr and the journal say so once a second per bus and origin, with counts.

The daemon runs on a virtual channel through :class:`test_faults.FaultyBus`
(``fail_sends``: every send refused), as in tests/test_faults.py.
"""

from __future__ import annotations

import logging
import math
import re
import time

import pytest

from canguard.engine.ratelimit import RateLimit
from test_daemon import BmsFeeder, read_events
from test_faults import Rig, rig
from waitkit import wait_until

__all__ = ["rig"]  # the fixture, imported for its name


class TestRateLimit:
    """One report per key per interval; the next one says how many it stands for."""

    def test_first_passes_rest_counted(self) -> None:
        """Within a second only the first report of a key passes; after it, the next passes with the count."""
        limit = RateLimit()
        assert limit.allow("a", 10.0) == 0
        assert [limit.allow("a", 10.0 + i / 100) for i in range(1, 6)] == [None] * 5
        assert limit.allow("b", 10.5) == 0  # another key is not held back by the first
        assert limit.allow("a", 11.0) == 5 and limit.allow("a", 12.0) == 0


class TestRefusedFlood:
    """Hundreds of refused frames a second give a few lines, not hundreds."""

    def test_stderr_and_journal_limited(self, rig: Rig, caplog: pytest.LogCaptureFixture) -> None:
        """Every refusal is counted, stderr warns at most once a second per bus and origin, and says how many more."""
        caplog.set_level(logging.WARNING, logger="canguard.engine.gate")
        sink = rig.daemon.sink
        with BmsFeeder(rig.peer):
            wait_until(what="the task runs", predicate=lambda: sink.sent >= 8)
            rig.faults.fail_sends = -1
            start = time.monotonic()
            wait_until(what="a warning counting the held-back refusals", predicate=
                  lambda: any("more like it held back" in r.getMessage() for r in caplog.records))
            rig.faults.fail_sends = 0
            seconds = time.monotonic() - start
            sent = sink.sent
            # no refusal after this: the counts hold still
            wait_until(what="a frame sent again", predicate=lambda: sink.sent > sent)
            wait_until(what="the refusal journalled", predicate=
                  lambda: any("send refused" in str(e.get("reason")) for e in read_events(rig.events)))
        warnings = [r.getMessage() for r in caplog.records if r.getMessage().startswith("could not send")]
        assert rig.faults.refused_sends >= 50
        # per origin (task, perhaps stop): the first refusal, then one a second
        assert 2 <= len(warnings) <= 2 * (seconds + 1), (seconds, warnings)
        held = sum(int(m.group(1)) for w in warnings if (m := re.search(r"; (\d+) more like it held back", w)))
        said = (re.match(r"could not send .* \((\w+)\) on bus (\w+)", w) for w in warnings)
        keys = {(m.group(2), m.group(1)) for m in said if m}  # (bus, origin)
        pending = sum(sink.reports.allow(key, math.inf) or 0 for key in keys)  # held back since each key's last line
        assert len(warnings) + held + pending == rig.faults.refused_sends  # every refusal is accounted for
        refused = [e for e in read_events(rig.events) if "send refused" in str(e.get("reason"))]
        assert len(refused) <= len(warnings)
