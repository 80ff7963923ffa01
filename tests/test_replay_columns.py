"""A log in blocks of N against the same frames in blocks of one, byte for byte.

There is one engine path: :meth:`Engine.take <canguard.engine.core.Engine.take>` (the live
daemon's) and :meth:`Engine.run_log <canguard.engine.core.Engine.run_log>` take blocks of
frames; the sources' health and the models advance over the runs of their samples up to the
next due time or edge (:func:`~canguard.engine.blocks.take_runs`), a frame on its own being a
run of one (:meth:`MessagePlan.take_row <canguard.engine.blocks.MessagePlan.take_row>`,
:meth:`MessagePlan.take_samples <canguard.engine.blocks.MessagePlan.take_samples>`). A block
(``LogRun._run_columns``, ``LogRun._cross``) takes N rows at once; the reference gives the
engine every frame on its own, a block of one, as a quiet live bus does. Every test here
replays one log both ways, the blocks at several sizes (so that block boundaries fall
everywhere: at ticks, at trips, inside gaps), the blocks of one once (whatever the reader's
block size), and compares the summary, the ``--events`` file, the ``--emit`` file and the
engine's own state (counters, every source's health, every guard's model) byte for byte: live
and replay agree. Each comparison also checks that blocks of many rows really ran, and rows
taken by the message plans' column step; the reference took blocks of one only.

The logs are written here: a scripted log on a config of many node types and
value kinds (``custom``: trips and recoveries, NaN / inf / out of range / short
payloads, stale sources, presence 0, gaps of 3.5 s and 65 s, repeated and
backward timestamps, letter case, T/R markers, extended and unconfigured ids,
remote and error frames), simulator logs of every scenario on the bundled
configs, and a log of three channels on a two-bus config.
"""

from __future__ import annotations

import bisect
import importlib.util
import itertools
import json
import math
import struct
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cantools
import py_trees
import pytest
import yaml

import canguard.cli.replay
import canguard.engine.blocks
import canguard.io.candump
import canguard.io.logs
import canguard.report.export
from canguard.cli.replay import ReplayOptions, replay_one
from canguard.config.loader import load_config
from canguard.config.schema import Config
from canguard.engine.core import Engine
from canguard.engine.logrun import LogRun
from canguard.io.block import EXT_KEY, Block
from canguard.io.logs import read_log
from canguard.sim import write_log
from checkout import REPO

DBC = REPO / "dbc" / "robot.dbc"
BUNDLED = REPO / "config" / "canguard.yaml"
ROBOT_GUARD = REPO / "config" / "examples" / "robot_guard.yaml"
MULTI = REPO / "config" / "examples" / "multi_current_monitoring.yaml"
TIMED = REPO / "config" / "examples" / "time_windowed_action.yaml"
DEFAULT_CHUNK = canguard.io.candump.CHUNK_CHARS

SMALL_CHUNKS = (97, 300, 1009, 4096)
"""Block sizes (characters) besides the reader's default: 2 lines a block up to about a hundred."""
EXPORT = importlib.util.find_spec("pyarrow") is not None
"""``compare`` also holds ``--export-signals`` to the frame-by-frame export (pyarrow: the fleet extra, in test)."""

_DB = cantools.database.load_file(str(DBC))


# --------------------------------------------------------------------------- replaying both ways


@dataclass
class Outcome:
    """What one replay produced, and how much of it the column path did."""

    summary: str
    events: bytes
    emit: bytes
    state: dict[str, Any]
    column_blocks: int = 0
    """Blocks of more than one row ``LogRun._run_columns`` took."""
    handled_rows: int = 0
    """Rows of column blocks a message plan's step took as decoded by the column decoder."""
    fed_rows: int = 0
    """Rows of column blocks the column decoder left to the frame decoder (an invalid value, a presence flag
    at 0, an alive counter...), taken by :meth:`MessagePlan.take_samples`."""
    handled_ids: set[int] = field(default_factory=set)
    """The arbitration ids of the rows the plans took."""
    quiet_ticks: int = 0
    """Grid ticks counted, not run (:mod:`canguard.engine.quiet`)."""
    widest: int = 0
    """The most rows of one block the engine took."""
    emitted: bool = True
    """An ``--emit`` file was written (:attr:`emit`); else sent frames were only counted."""
    exported: Any = None
    """With ``--export-signals``: the rows written (floats by repr) and the row groups' sizes."""


def _r(x: Any) -> Any:
    """A value made comparable to the bit: floats by repr (-0.0 is not 0.0), containers recursively."""
    if isinstance(x, float):
        return repr(x)
    if isinstance(x, dict):
        return {str(k): _r(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_r(v) for v in x]
    return x


def engine_state(engine: Engine) -> dict[str, Any]:
    """Everything of an engine after a replay that both paths must leave alike."""
    st = engine.stats
    health = {
        name: {
            "latest_t": h._latest_t, "invalid": h._invalid, "value": h._value, "valid_t": h._valid_t,
            "last_reason": h._last_reason,
        }
        for name, h in engine.ctx.health.items()
    }
    models = [
        {"node": g.node, "role": g.role, "snapshot": repr(g.model.snapshot()),
         "last_t": getattr(g.model, "last_t", None)}
        for g in engine.guards()
    ]
    return _r({
        "frames": st.frames, "ticks": st.ticks, "edge_ticks": st.edge_ticks, "skipped_ticks": st.skipped_ticks,
        "tick_errors": st.tick_errors, "backward_frames": st.backward_frames, "trip_count": st.trip_count,
        "samples": st.samples,
        "max_abs": {"/".join(k): v for k, v in st.max_abs.items()}, "max_level_pct": st.max_level_pct,
        "decoder": {bus: asdict(c) for bus, c in engine.decoder.per_bus.items()},
        "health": health, "models": models, "now": engine.clock.now(), "last_tick_t": engine.last_tick_t,
        "first_frame_t": engine.first_frame_t, "gate": engine.gate.state, "stops": engine.gate.stops,
        "next_task": engine.gate.next_task_t, "next_stop": engine.gate._next_stop, "sent": engine.gate.sink.sent,
        "stale": engine.stale, "events_seen": dict(engine.events_seen),
    })


class _OneByOne:
    """A log reader's blocks cut into blocks of one frame each (the reference: a quiet live bus's blocks)."""

    def __init__(self, frames: Any) -> None:
        self.frames = frames
        self.progress = None

    def chunks(self) -> Any:
        return (block.select([i]) for block in self.frames.chunks() for i in range(block.n))


def replay(cfg: Config, log: Path, out: Path, *, columns: bool, chunk: int | BlockCuts,
           channel_map: dict[str, str] | None = None, emit_frames: bool = True,
           export: bool = False) -> Outcome:
    """Replay ``log`` once (in the reader's blocks of ``chunk`` characters, or with ``columns`` False in blocks
    of one frame); instrumented.

    ``emit_frames`` False: no ``--emit`` file, so sent frames are only counted (the quiet runs then
    send the task's periodic frames in one go, :meth:`~canguard.engine.core.Engine._quiet_run`).
    ``export``: also ``--export-signals`` (in row groups of 64 rows), read back into :attr:`Outcome.exported`.
    """
    events, emit = out / "events.jsonl", out / "emit.log"
    out.mkdir(parents=True, exist_ok=True)
    for p in (events, emit):
        p.unlink(missing_ok=True)  # the journal appends
    engines: list[Engine] = []
    counts = {"blocks": 0, "handled": 0, "fed": 0, "widest": 0, "in_block": 0}
    handled_ids: set[int] = set()
    run_columns = LogRun._run_columns
    take_samples = canguard.engine.blocks.MessagePlan.take_samples
    take_runs = canguard.engine.blocks.take_runs
    build_summary = canguard.cli.replay.build_summary

    def counted_run_columns(self: LogRun, block: Block, cursor: Any) -> None:
        counts["in_block"] = block.n > 1
        try:
            run_columns(self, block, cursor)
        finally:
            counts["in_block"] = 0
        counts["blocks"] += block.n > 1
        counts["widest"] = max(counts["widest"], block.n)

    def counted_take_samples(plan: Any, samples: Any) -> bool:
        counts["fed"] += counts["in_block"]
        return take_samples(plan, samples)

    def counted_take_runs(runs: Any) -> tuple[int, bool]:
        last, edge = take_runs(runs)
        for plan, rows, *_rest in runs:  # a block's rows
            counts["handled"] += bisect.bisect_right(rows, last)
            handled_ids.add(int(plan.entry.message.frame_id))
        return last, edge

    boards: list[dict[str, Any]] = []

    def capturing_build_summary(cfg: Config, log_path: Path, engine: Engine, *args: Any) -> dict[str, Any]:
        engines.append(engine)
        boards.append({k: _r(v) for k, v in py_trees.blackboard.Blackboard.storage.items()
                       if "__const" not in k})  # the keys the tree wrote (not the constants), before the clear
        return build_summary(cfg, log_path, engine, *args)

    with pytest.MonkeyPatch.context() as mp:
        if not columns:
            mp.setattr(canguard.io.logs, "read_log", lambda *a, **k: _OneByOne(read_log(*a, **k)))
        mp.setattr(LogRun, "_run_columns", counted_run_columns)
        mp.setattr(canguard.engine.blocks.MessagePlan, "take_samples", counted_take_samples)
        mp.setattr(canguard.engine.blocks, "take_runs", counted_take_runs)
        mp.setattr(canguard.cli.replay, "build_summary", capturing_build_summary)
        mp.setattr(canguard.io.candump, "CHUNK_CHARS", chunk)
        py_trees.blackboard.Blackboard.clear()  # global: the two runs must not see each other's keys
        parquet = out / "signals.parquet" if export else None
        if export:
            mp.setattr(canguard.report.export, "BATCH_ROWS", 64)
        summary = replay_one(cfg, log, ReplayOptions(events=events, emit=emit if emit_frames else None,
                                                     channel_map=channel_map or {}, export=parquet,
                                                     export_log=log.name))
        py_trees.blackboard.Blackboard.clear()
    [engine] = engines
    state = engine_state(engine)
    state["blackboard"] = boards[0]  # what the tree wrote (I²t levels...): quiet ticks must write it too
    exported = None
    if parquet is not None:
        import pyarrow.parquet as pq

        table = pq.ParquetFile(parquet)
        groups = [table.metadata.row_group(i).num_rows for i in range(table.num_row_groups)]
        exported = (_r(table.read().to_pylist()), groups)
    return Outcome(json.dumps(summary, sort_keys=True), events.read_bytes(), emit.read_bytes() if emit_frames else b"",
                   state, counts["blocks"], counts["handled"], counts["fed"], handled_ids,
                   engine.stats.quiet_ticks, counts["widest"], emit_frames, exported)


def _first_difference(a: bytes | str, b: bytes | str, what: str) -> str:
    """The first differing line of two outputs, for an assertion message."""
    la, lb = a.splitlines(), b.splitlines()
    for i, (x, y) in enumerate(zip(la, lb, strict=False)):
        if x != y:
            return f"{what} line {i + 1}:\n  reference: {x!r}\n  columns:   {y!r}"
    return f"{what}: {len(la)} lines (reference) vs {len(lb)} (columns)"


_REFERENCES: dict[tuple[Any, ...], Outcome] = {}
"""Reference runs of this process, by config, log and options (:func:`reference`); the last sixteen only (this
file replays ten config, log and option pairs: none is replayed twice in one process, whatever the test order)."""


def reference(cfg: Config, log: Path, out: Path, *, channel_map: dict[str, str] | None = None,
              export: bool = False) -> Outcome:
    """The reference replay of ``log``: in blocks of one frame (a quiet live bus's), every tick run; once per
    config, log and options.

    The reference feeds the engine one frame at a time whatever the reader's block size, so
    one run (at the reader's default size) is the truth for every block size the column path
    is compared at, and for every test on the same log: a reader or reference whose result
    depended on the block size would fail the comparison. A run with ``--export-signals``
    also stands for one without. Held by the log's path, size and modification time.
    """
    stat = log.stat()
    where = (str(cfg.path), Path(str(cfg.path)).read_bytes(), str(log), stat.st_size, stat.st_mtime_ns,
             tuple(sorted((channel_map or {}).items())))
    ref = _REFERENCES.get((*where, True)) or _REFERENCES.get((*where, export))
    if ref is None:
        ref = replay(cfg, log, out / "ref", columns=False, chunk=DEFAULT_CHUNK, channel_map=channel_map,
                     export=export)
        assert ref.widest == 1, "the reference took blocks of more than one frame"
        while len(_REFERENCES) >= 16:
            del _REFERENCES[next(iter(_REFERENCES))]
        _REFERENCES[(*where, export)] = ref
    return ref


def assert_same(ref: Outcome, col: Outcome, label: str) -> None:
    """Byte-identical summary, events and emitted frames, and the same engine state (and export, if ``col`` has one)."""
    for what in ("summary", "events", "emit"):
        a, b = getattr(ref, what), getattr(col, what)
        if what == "emit" and not col.emitted:
            continue  # a run without --emit (its frames counted in the summary and the state)
        assert a == b, f"{label}: {_first_difference(a, b, what)}"
    if col.exported is not None:
        assert ref.exported is not None, f"{label}: the reference exported nothing to compare with"
        a_rows, b_rows = ref.exported[0], col.exported[0]
        pairs = enumerate(zip(a_rows, b_rows, strict=False))
        first = next((k for k, (a, b) in pairs if a != b), min(len(a_rows), len(b_rows)))
        assert ref.exported == col.exported, (
            f"{label}: --export-signals differs at row {first} of {len(a_rows)} / {len(b_rows)}: "
            f"{a_rows[first:first + 2]} vs {b_rows[first:first + 2]}")
    diffs = [k for k in ref.state if ref.state[k] != col.state.get(k)]
    detail = {k: (ref.state[k], col.state.get(k)) for k in diffs}
    assert not diffs, f"{label}: engine state differs in {diffs}: {json.dumps(detail)[:2000]}"


def compare(cfg: Config, log: Path, out: Path, chunks: tuple[int | BlockCuts, ...] = SMALL_CHUNKS, *,
            channel_map: dict[str, str] | None = None, min_handled: int = 1, variant: int = 0) -> list[Outcome]:
    """Replay ``log`` through both paths at each block size: equal outputs; returns the column runs.

    The reference goes frame by frame and ticks every tick (the live daemon's way);

    Every column run is compared with one reference run (:func:`reference`).
    The column path must have run (blocks taken, and at least ``min_handled`` rows
    taken by the handlers) at every block size but the reader's default, where a
    small log is one block.

    The column runs at the second, fourth... block size write no ``--emit`` file: their frames
    are only counted, as a replay without ``--emit`` does (emitted frames are compared at the others).
    ``variant``: the first block size
    runs as the ``variant``-th (0 first, 1 second...), and the next ones as the next, so that a test
    comparing at one block size can choose which of these ways it runs.
    """
    outcomes = []
    ref = reference(cfg, log, out, channel_map=channel_map, export=EXPORT and variant <= 1 < variant + len(chunks))
    for k, chunk in enumerate(chunks, start=variant):
        export = k == 1 and EXPORT  # the second block size also exports every sample (--export-signals)
        col = replay(cfg, log, out / f"col-{chunk}", columns=True, chunk=chunk, channel_map=channel_map,
                     emit_frames=k % 2 == 0, export=export)
        assert_same(ref, col, f"{log.name} with {Path(str(cfg.path)).name}, blocks of {chunk} chars")
        if chunk != DEFAULT_CHUNK:
            assert col.column_blocks > 0, f"blocks of {chunk}: the column path never ran, so this proves nothing"
            assert col.handled_rows >= min_handled, f"blocks of {chunk}: the row handlers took {col.handled_rows} rows"
        outcomes.append(col)
    return outcomes


# --------------------------------------------------------------------------- writing logs


@dataclass(order=True)
class Row:
    """One candump -L line to write."""

    t: float
    seq: int = field(compare=True)
    chan: str = field(compare=False, default="can0")
    cid: str = field(compare=False, default="")
    data: str = field(compare=False, default="")
    marker: str = field(compare=False, default="")

    def line(self) -> str:
        return f"({self.t:.6f}) {self.chan} {self.cid}#{self.data}" + (f" {self.marker}" if self.marker else "")


def msg_id(name: str, db: Any = _DB) -> str:
    """The candump id text of a DBC message (3 hex digits, or 8 for extended ids)."""
    m = db.get_message_by_name(name)
    return f"{m.frame_id:08X}" if m.is_extended_frame else f"{m.frame_id:03X}"


def iq_data(measured: float, setpoint: float = 0.0) -> str:
    """An ODrive Get_Iq payload (two little-endian float32: setpoint, measured)."""
    return struct.pack("<ff", setpoint, measured).hex().upper()


def torques_data(estimate: float, target: float = 0.0) -> str:
    """An ODrive Get_Torques payload (two little-endian float32: target, estimate)."""
    return struct.pack("<ff", target, estimate).hex().upper()


def bms_data(current: float, present: int = 1) -> str:
    """A BMS_Status payload."""
    m = _DB.get_message_by_name("BMS_Status")
    return bytes(m.encode({"Pack_Current": current, "Pack_Voltage": 48.0, "State_Of_Charge": 80.0,
                           "Present": present, "Fault": 0, "Alive_Counter": 0})).hex().upper()


def write_rows(path: Path, rows: list[Row], *, sort: bool = True) -> Path:
    """Write rows as a candump -L log (in time order unless ``sort`` is False)."""
    path.write_text("".join(r.line() + "\n" for r in (sorted(rows) if sort else rows)), encoding="ascii")
    return path


def mixed_case(text: str, k: int) -> str:
    """``text`` with letters alternately lower and upper case (phase ``k``)."""
    return "".join(c.lower() if (i + k) % 2 else c.upper() for i, c in enumerate(text))


def chunks_of(log: Path, chunk: int | BlockCuts) -> list[Block]:
    """The reader's blocks of ``log`` at ``chunk`` characters (what run_log receives)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(canguard.io.candump, "CHUNK_CHARS", chunk)
        return list(read_log(log).chunks())


# --------------------------------------------------------------------------- the custom config and log

EXTRA_DBC = """VERSION ""

NS_ :

BS_:

BU_: Probe Canguard

BO_ 1280 Probe_Multi: 8 Probe
 SG_ Scaled_A : 0|16@1- (0.1,-5) [-3000|3000] "A" Canguard
 SG_ Int_Scaled_B : 16|16@1+ (2,-100) [-100|1000] "" Canguard
 SG_ Identity_C : 32|32@1- (1,0) [-1000|1000] "" Canguard

BO_ 1281 Probe_Big: 8 Probe
 SG_ Big_U : 0|64@1+ (1,0) [0|18446744073709551615] "" Canguard

BO_ 1282 Probe_BE: 8 Probe
 SG_ BE_Float : 7|32@0- (1,0) [-100|100] "A" Canguard
 SG_ BE_Int : 39|16@0- (1,0) [-500|500] "" Canguard

BO_ 1283 Probe_Odd: 8 Probe
 SG_ Odd_12 : 0|12@1- (0.5,0) [-1000|1000] "A" Canguard

BO_ 1284 Probe_Mixed: 8 Probe
 SG_ Mixed_LE : 0|16@1- (1,0) [-1000|1000] "" Canguard
 SG_ Mixed_BE : 39|16@0- (1,0) [-1000|1000] "" Canguard

BO_ 1285 Probe_Step: 2 Probe
 SG_ Step_Count : 0|16@1+ (3,10) [10|150000] "" Canguard

BO_ 2365521918 Probe_Ext: 8 Probe
 SG_ Ext_Double : 0|64@1- (1,0) [-1000|1000] "A" Canguard

SIG_VALTYPE_ 1282 BE_Float : 1;
SIG_VALTYPE_ 2365521918 Ext_Double : 2;
"""
"""Messages of every value kind the row handlers know (scaled, integer scaled, identity int and
float, big-endian, 64-bit, extended id), alone in their message or not, and two that were left
to the general path when this was written (a 12-bit signal; two byte orders in one message)."""

CUSTOM_TREE = """<root BTCPP_format="4" main_tree_to_execute="Custom">
  <BehaviorTree ID="Custom">
    <ReactiveSequence name="Guards">
      <IsCurrentSafe name="Pack" topic_name="/battery_state" overcurrent_threshold="35.0"
                     recovery_threshold="25.0" trip_after="0.02" recover_after="0.03"/>
      <IsJointEffortNormal name="Efforts" topic_name="/joint_states" max_effort="40.0"/>
      <IsCurrentSafe name="Axis0" topic_name="axis0" overcurrent_threshold="25.0" recovery_threshold="15.0"
                     start_current="2.0" inrush_time="0.15" inrush_threshold="40.0"/>
      <IsCurrentNormal name="ProbeA" topic_name="probe_a" max_current="200.0"/>
      <IsCurrentNormal name="ProbeB" topic_name="probe_b" max_current="900.0"/>
      <IsCurrentSafe name="ProbeBE" topic_name="probe_be" overcurrent_threshold="50.0" recovery_threshold="40.0"/>
      <IsCurrentNormal name="ProbeExt" topic_name="probe_ext" max_current="500.0"/>
      <IsCurrentNormal name="ProbeBig" topic_name="probe_big" max_current="1000000.0"/>
      <IsCurrentNormal name="ProbeStep" topic_name="probe_step" max_current="5000.0"/>
      <IsCurrentSafe name="Axis1" topic_name="axis1" overcurrent_threshold="30.0" recovery_threshold="20.0"/>
      <IsI2tSafe name="Axis1Heat" topic_name="axis1" model="leaky" continuous_current="10.0"
                 peak_current="20.0" peak_time="1.0"/>
      <IsI2tSafe name="Axis0Heat" topic_name="axis0" model="thermal" continuous_current="10.0"
                 peak_current="20.0" peak_time="1.0"/>
      <Sequence name="Task">
        <PerformRecovery name="Clear"/>
        <ExecuteTask/>
      </Sequence>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""
"""Hysteresis with trip/recover delays and inrush blanking, thermal and leaky I²t, thresholds on a
joints source of two signals of one message, on scaled, big-endian and float64 signals. No I²t ``level`` is
wired: a block's rows run on across the quiet ticks, the I²t models' among them (robot_guard.yaml wires every
``level``: there the rows stop at each tick, which writes the levels again)."""


HANDLED = {"Axis0_Get_Iq", "Axis1_Get_Iq", "Axis1_Get_Torques", "Axis2_Get_Torques", "Probe_Multi", "Probe_Big",
           "Probe_BE", "Probe_Step", "Probe_Ext"}
"""Messages of the custom log that the row handlers must take (read by the tree: a handler per value kind)."""


def custom_config(directory: Path) -> Path:
    """A one-bus config over robot.dbc + EXTRA_DBC whose sources cover every row handler case."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "extra.dbc").write_text(EXTRA_DBC, encoding="ascii")
    (directory / "custom.xml").write_text(CUSTOM_TREE, encoding="utf-8")

    def cur(message: str, signal: str, max_age: float = 0.1) -> dict[str, Any]:
        return {"kind": "current", "message": message, "signal": signal, "max_age": max_age}

    doc = {
        "dbc": [str(DBC), str(directory / "extra.dbc")],
        "buses": {"main": {"interface": "virtual", "channel": "can0"}},
        "sources": {
            "/battery_state": {"kind": "battery", "message": "BMS_Status", "current": "Pack_Current",
                               "present": "Present", "max_age": 0.5},
            "/joint_states": {"kind": "joints", "max_age": 0.2, "effort": [
                {"message": "Axis1_Get_Torques", "signal": "Torque_Estimate", "name": "est1"},
                {"message": "Axis1_Get_Torques", "signal": "Torque_Target", "name": "tgt1"},
                {"message": "Axis2_Get_Torques", "signal": "Torque_Estimate", "name": "est2"},
            ]},
            "axis0": cur("Axis0_Get_Iq", "Iq_Measured"),
            "axis0_sp": cur("Axis0_Get_Iq", "Iq_Setpoint"),  # a second source in axis0's message
            "axis1": cur("Axis1_Get_Iq", "Iq_Measured"),
            "probe_a": cur("Probe_Multi", "Scaled_A"),
            "probe_b": cur("Probe_Multi", "Int_Scaled_B"),
            "probe_c": cur("Probe_Multi", "Identity_C"),
            "probe_big": cur("Probe_Big", "Big_U"),
            "probe_be": cur("Probe_BE", "BE_Float"),
            "probe_be16": cur("Probe_BE", "BE_Int"),
            "probe_odd": cur("Probe_Odd", "Odd_12"),
            "probe_mixed_le": cur("Probe_Mixed", "Mixed_LE"),
            "probe_mixed_be": cur("Probe_Mixed", "Mixed_BE"),
            "probe_ext": cur("Probe_Ext", "Ext_Double"),
            "probe_step": cur("Probe_Step", "Step_Count"),
            "axis3": cur("Axis3_Get_Iq", "Iq_Measured"),  # read by no node, no model
        },
        "tree": {"file": str(directory / "custom.xml"), "main": "Custom", "tick_hz": 100},
        "task": {"period": 0.02, "frames": [
            {"message": "Axis0_Set_Axis_State", "signals": {"Axis_Requested_State": "CLOSED_LOOP_CONTROL"}}]},
        "stop": {
            "repeat": 0.05, "frames": [{"message": "Axis0_Estop"}],
            "confirm": {"source": "axis0", "signal": "current", "below": 1.0, "deadline": 0.2},
            "escalate": [{"message": "Axis0_Set_Axis_State", "signals": {"Axis_Requested_State": "IDLE"}}],
        },
        "actions": {"PerformRecovery": {"frames": [{"message": "Axis0_Clear_Errors"}]}},
        "events": str(directory / "events.jsonl"),
        "state": {"file": str(directory / "i2t_state.json"), "on_corrupt": "hot", "save_period": 5},
    }
    path = directory / "custom.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


CUSTOM_T0 = 9995.0
"""The custom log starts here: at step 500 its timestamps grow a digit (10000.000000)."""
STEPS = 800
TRIP_STEP = 102
"""The step whose BMS row trips Pack (60 A since step 100, trip_after 0.02 s)."""
GAPS = {700: 3.5, 760: 65.0}
"""Quiet seconds before a step: a gap just past MAX_CATCH_UP_S, and one that skips thousands of ticks."""
BACKWARD = 10**9
"""Row sequence numbers from here on: rows written after rows with later timestamps."""


def _probe_multi(a_raw: int, b_raw: int, c_raw: int) -> str:
    return struct.pack("<hHi", a_raw, b_raw, c_raw).hex().upper()


def _axis0_rows(add: Callable[..., None], rows: list[Row], cid: str, t: float, k: int) -> None:
    """Step ``k`` of :func:`custom_rows` for axis0 + axis0_sp (one message, two sources)."""
    # axis0 + axis0_sp (one message, two sources): inrush, -0.0 while stopped (the stop
    # confirmation reports it), a hysteresis trip, NaN / inf / out of range / short payloads,
    # a setpoint out of range, short and long silences, repeated and backward timestamps.
    meas: float = 5.0
    sp = 1.0
    if k < 40:
        meas = 0.0
    elif k < 52:
        meas = 30.0
    elif 100 <= k < 130 or 600 <= k < 620:
        meas = -0.0
    elif 200 <= k < 215:
        meas = 28.0
    elif 215 <= k < 240:
        meas = 12.0
    special = {250: math.nan, 251: math.inf, 252: -math.inf, 253: 100.0}
    if k in special:
        meas = special[k]
    if 300 <= k < 310:
        sp = 100.0
    if not (420 <= k < 425 or 430 <= k < 445):
        data = iq_data(meas, sp)
        if k == 254:
            data = data[:8]
        elif k == 255:
            data = ""
        add(t + 0.001, cid, data, k)
    if k == 460:  # the same timestamp again, twice
        add(t + 0.001, cid, iq_data(3.0), k)
        add(t + 0.001, "7E5", "00", k)
    if k in (470, 475):  # older than axis0's latest sample: out of order for its health and models
        rows.append(Row(round(t - 0.0093, 6), BACKWARD + k, cid=cid, data=iq_data(4.0)))
    if k == 485:  # older than the unconfigured row before it only (written after it, see custom_log)
        rows.append(Row(round(t + 0.0022, 6), BACKWARD + k, cid=cid, data=iq_data(4.5)))


def custom_rows() -> list[Row]:
    """The scripted log of :func:`custom_config` (see the comments for what each step range does)."""
    xdb = cantools.database.load_string(EXTRA_DBC, "dbc")
    ids = {name: msg_id(name) for name in ("BMS_Status", "Axis0_Get_Iq", "Axis1_Get_Iq", "Axis3_Get_Iq",
                                           "Axis1_Get_Torques", "Axis2_Get_Torques", "Axis0_Heartbeat")}
    ids.update({name: msg_id(name, xdb) for name in ("Probe_Multi", "Probe_Big", "Probe_BE", "Probe_Odd",
                                                     "Probe_Mixed", "Probe_Step", "Probe_Ext")})
    nan, inf = math.nan, math.inf
    rows: list[Row] = []
    seq = 0
    shift = 0.0

    def add(t: float, cid: str, data: str, k: int, **kw: Any) -> None:
        nonlocal seq
        seq += 1
        if 100 <= k < 200:  # lower-case ids and data
            cid, data = cid.lower(), data.lower()
        elif 200 <= k < 300:  # mixed case
            cid, data = mixed_case(cid, k), mixed_case(data, k + 1)
        marker = "R" if 650 <= k < 690 else ("T" if k == 695 else "")  # a stretch of T/R-marked lines
        rows.append(Row(round(t, 6), seq, cid=cid, data=data, marker=marker, **kw))

    for k in range(STEPS):
        shift += GAPS.get(k, 0.0)
        t = CUSTOM_T0 + k * 0.01 + shift
        # /battery_state every 20 ms (odd steps have no row at the tick): hysteresis trip at 102,
        # held between the thresholds, recovery after 0.03 s; present 0; a short frame; stale and back.
        if k % 2 == 0 and not 560 <= k < 640:
            amps = 60.0 if 100 <= k < 130 else 30.0 if 130 <= k < 160 else 10.0
            data = bms_data(amps, present=0 if 500 <= k < 520 else 1)
            add(t, ids["BMS_Status"], data[:6] if k == 540 else data, k)
        add(t + 0.0005, "7E5", "0102030405060708", k)  # unconfigured, letters in the id
        _axis0_rows(add, rows, ids["Axis0_Get_Iq"], t, k)
        # axis1: leaky I²t heats from 250, trips near 328, cools from 330; silent (stale) 450..480.
        if not 450 <= k < 480:
            add(t + 0.002, ids["Axis1_Get_Iq"], iq_data(22.0 if 250 <= k < 330 else 0.0 if k >= 330 else 3.0), k)
        add(t + 0.0025, "00000014", "AA", k)  # the extended twin of Axis0_Get_Iq's id: not configured
        # /joint_states: two signals of Axis1_Get_Torques (a threshold trip on the target, an estimate
        # out of the DBC range, NaN, inf) and Axis2's estimate (a trip; stale 380..410).
        est, tgt = 0.9, 1.0
        if 300 <= k < 305:
            tgt = 45.0
        est = {320: 60.0, 321: nan}.get(k, est)
        tgt = {322: inf}.get(k, tgt)
        add(t + 0.003, ids["Axis1_Get_Torques"], torques_data(est, tgt), k)
        if not 380 <= k < 410:
            add(t + 0.004, ids["Axis2_Get_Torques"], torques_data(41.0 if k == 350 else 2.0), k)
        # Probe_Multi: scaled (0.1, -5), integer scaled (2, -100), identity int; a trip and a value
        # out of range.
        a_raw = 3000 if 150 <= k < 152 else 100
        b_raw = 600 if k == 160 else 60
        add(t + 0.005, ids["Probe_Multi"], _probe_multi(a_raw, b_raw, -7), k)
        add(t + 0.0055, ids["Axis0_Heartbeat"], "0000000008000000", k)  # in the DBC, not configured
        # Probe_Big: a uint64 of the DBC range [0|2^64-1]; 2^64-1 itself becomes 2^64.0 as a float
        # (in the range as configured: trips ProbeBig once).
        big = 2**64 - 1 if k == 400 else 12345 + k
        add(t + 0.006, ids["Probe_Big"], struct.pack("<Q", big).hex().upper(), k)
        # Probe_BE: big-endian float32 (trip at 55, held at 45, recovery) and int16; NaN once.
        be = 55.0 if 200 <= k < 206 else 45.0 if 206 <= k < 220 else nan if k == 230 else 10.0
        add(t + 0.007, ids["Probe_BE"], struct.pack(">fh", be, -100).hex().upper() + "0000", k)
        add(t + 0.008, ids["Probe_Odd"], "FE0F000000000000", k)
        add(t + 0.0082, ids["Probe_Mixed"], "0500" + "0000" + "0006" + "0000", k)
        # axis3: a source nobody reads (only stale / fresh events); NaN once, silent 600..640.
        if not 600 <= k < 640:
            add(t + 0.0087, ids["Axis3_Get_Iq"], iq_data(nan if k == 333 else 2.5), k)
        # Probe_Step: one integer scaled signal (3, 10); above its range once.
        add(t + 0.0085, ids["Probe_Step"], struct.pack("<H", 65535 if k == 170 else k).hex().upper(), k)
        # Probe_Ext: float64 on an extended id, -0.0 for a while.
        add(t + 0.009, ids["Probe_Ext"], struct.pack("<d", -0.0 if 100 <= k < 130 else 3.0).hex().upper(), k)
        if k == 610:  # a remote frame on axis0's id, then an error frame: blocks the line parser reads
            add(t + 0.0095, ids["Axis0_Get_Iq"], "R", k)
            add(t + 0.0096, "20000080", "0000000000000000", k)
        if k % 37 == 5:  # a burst of unconfigured rows: ticks fall due among them
            for j in range(25):
                add(t + 0.0091 + j * 0.00003, "321" if j % 2 else "1ABCDEF0", "DEADBEEF", k)
    for j in range(80):  # the log ends in unconfigured rows: blocks with no sample to take (nor to export)
        add(CUSTOM_T0 + STEPS * 0.01 + shift + j * 0.0001, "7E5", "0102030405060708", STEPS)
    return rows


def custom_log(path: Path) -> Path:
    """Write :func:`custom_rows`: in time order, but each backward row where its step is."""
    rows = custom_rows()
    ordered = sorted(r for r in rows if r.seq < BACKWARD)
    for r in (r for r in rows if r.seq >= BACKWARD):
        after = 0.0004 if r.seq == BACKWARD + 485 else 0.009  # after the 00000014 row / the step before
        ordered.insert(next(i for i, o in enumerate(ordered) if o.t > r.t + after), r)
    return write_rows(path, ordered, sort=False)


@pytest.fixture(scope="module")
def custom(tmp_path_factory: pytest.TempPathFactory) -> tuple[Config, Path]:
    """The custom config and its log."""
    d = tmp_path_factory.mktemp("columns_custom")
    return load_config(custom_config(d / "cfg")), custom_log(d / "custom.log")


# --------------------------------------------------------------------------- more logs and configs


def line_offsets(log: Path) -> list[int]:
    """The character offset of each line of ``log``."""
    offsets, pos = [], 0
    for line in log.read_text(encoding="ascii").splitlines(keepends=True):
        offsets.append(pos)
        pos += len(line)
    return offsets


def custom_line(log: Path, pred: Callable[[str], bool]) -> int:
    """The index of the first line of ``log`` for which ``pred`` holds."""
    return next(i for i, line in enumerate(log.read_text(encoding="ascii").splitlines()) if pred(line))


def chunk_starting_at(log: Path, i: int) -> int:
    """A block size (4,000 to 12,000 characters: about 100 lines) at which a block of ``log`` starts at line ``i``.

    A block is the next ``size`` characters and the rest of the line the last of them is in
    (:func:`canguard.io.candump.candump_blocks`): the next block starts at the line after it.
    """
    offsets = line_offsets(log)
    target = offsets[i]

    def starts_at(size: int) -> bool:
        start = 0
        while start < target:
            start = offsets[bisect.bisect_right(offsets, start + size - 1)] if start + size < offsets[-1] else -1
            if start < 0:
                return False
        return start == target

    return next(c for c in range(4000, 12000) if starts_at(c))


class BlockCuts:
    """Block sizes for the reader that start a block at each of the given lines, in blocks of about ``size``
    characters between them: a stand-in for :data:`canguard.io.candump.CHUNK_CHARS`, which the reader reads
    once a block (:meth:`__index__`), so that one replay has a block starting at every one of these lines.

    The sizes repeat after the whole log (and the reader's last, empty read), so each replay reads the same blocks.
    """

    def __init__(self, log: Path, starts: list[int], size: int = 4096) -> None:
        offsets = [*line_offsets(log), log.stat().st_size]
        bounds = sorted({offsets[i] for i in starts} | {offsets[-1]})
        sizes, pos = [], 0
        for bound in bounds:
            while bound - pos > size:  # whole lines of about `size` characters up to the next start
                step = offsets[bisect.bisect_left(offsets, pos + size)] - pos
                if pos + step >= bound:
                    break
                sizes.append(step)
                pos += step
            sizes.append(bound - pos)
            pos = bound
        self.sizes = [*sizes, size]  # the last: the read that finds the end of the log
        self.starts = starts
        self.calls = 0

    def __index__(self) -> int:
        size = self.sizes[self.calls % len(self.sizes)]
        self.calls += 1
        return size

    def __rmul__(self, k: int) -> int:
        return k * max(self.sizes)  # the reader's bound on a line: 4 blocks

    def __repr__(self) -> str:
        return f"cuts-{len(self.starts)}"


def sim_lines(seconds: float, channel: str, scenarios: list[str], seed: int) -> list[tuple[float, str]]:
    """(t, candump -L line) of a simulated robot on ``channel``."""
    from canguard.io.candump import format_candump_line
    from canguard.sim import SimRobot

    robot = SimRobot(cantools.database.load_file(DBC), channel=channel, scenarios=scenarios, seed=seed)
    return [(f.t, format_candump_line(f)) for f in robot.frames(seconds)]


def two_channel_log(path: Path) -> Path:
    """can0 and can1 robots (and a can2 stranger): interleaved, then in windows of one channel each.

    0-1.5 s: every channel interleaved line by line (blocks of several channels);
    1.5-4 s: windows of 0.1 s that carry only can0, only can1 or only can2 (blocks of
    one channel, whose sources stay fresh across the others' windows);
    4-5 s: interleaved again. can0 has a BMS spike (at 2.01 s, in a can0 window), can1 an inrush
    on axis 1 (1.5 s) and an overload on axis 0 (from 2 s: I²t trips at 3 s)
    """
    a = sim_lines(5.0, "can0", ["spike@0.5"], 11)
    b = sim_lines(5.0, "can1", ["overload", "inrush"], 12)
    c = [(t, line) for t, line in sim_lines(5.0, "can2", ["normal"], 13) if int(t * 1000) % 7 == 0]
    t0 = a[0][0]
    merged = sorted(a + b + c, key=lambda x: x[0])
    out = []
    for t, line in merged:
        rel = t - t0
        if 1.5 <= rel < 4.0:
            window = ("can0", "can1", "can0", "can2")[int(rel * 10) % 4]
            if f" {window} " not in line:
                continue
        out.append(line)
    path.write_text("".join(line + "\n" for line in out), encoding="ascii")
    return path


def two_bus_config(directory: Path) -> Path:
    """robot_guard.yaml with a second bus ``aux`` on can1, where the sources of axes 0 and 1 are."""
    doc = yaml.safe_load(ROBOT_GUARD.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((ROBOT_GUARD.parent / doc["tree"]["file"]).resolve())
    doc["buses"]["aux"] = {"interface": "virtual", "channel": "can1"}
    for name in ("axis0", "axis1"):
        doc["sources"][name]["bus"] = "aux"
    for item in doc["sources"]["/joint_states"]["effort"]:
        if item["name"] in ("axis0", "axis1"):
            item["bus"] = "aux"
    for source in doc["sources"].values():
        source.setdefault("bus", "main")
    frame_lists = [doc["task"]["frames"], doc["stop"]["frames"], doc["stop"].get("escalate") or []]
    frame_lists += [a["frames"] for a in doc["actions"].values()]
    for frames in frame_lists:
        for frame in frames:
            frame["bus"] = "main"
    doc["events"] = str(directory / "events.jsonl")
    doc["state"]["file"] = str(directory / "i2t_state.json")
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "two-bus.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every simulator scenario at once, on a loaded bus (4 s, about 32,000 frames: the last event of the bundled
    configs' replays is at 3.5 s, the end of the BMS dropout)."""
    path = tmp_path_factory.mktemp("columns_sim") / "all.log"
    write_log(path, 4.0, db=cantools.database.load_file(DBC), seed=5,
              scenarios=["load", "overload", "inrush", "spike", "dropout", "garbage", "errorburst"])
    return path


@pytest.fixture(scope="module")
def channels(tmp_path_factory: pytest.TempPathFactory) -> tuple[Config, Path]:
    """The two-bus config and the two-channel log."""
    d = tmp_path_factory.mktemp("columns_channels")
    return load_config(two_bus_config(d / "cfg")), two_channel_log(d / "channels.log")


# --------------------------------------------------------------------------- tests


class TestCustomLog:
    """The scripted log on the custom config: every handler case, at many block sizes."""

    def test_a_block_export_sees_each_frames_samples_in_log_order(self, custom: tuple[Config, Path]) -> None:
        """The block export (``Engine.sample_block``: ``--export-signals``, plots) gets every sample the frame
        decoder makes of the log's frames, with its reason, in log order, from blocks that mix messages and go
        back in time: the column rows' samples and the rows the frame decoder took, merged by row."""
        from canguard.decode.decoder import Decoder
        from canguard.decode.rows import valued_table
        from canguard.engine.gate import LogSink
        from canguard.io.clock import ManualClock
        from canguard.io.frame import Sample

        cfg, log = custom
        [bus] = cfg.buses
        frames = list(read_log(log))
        decoder = Decoder(cfg)
        want = [repr(sample) for frame in frames for sample in decoder.decode(frame, bus)]
        clock = ManualClock()
        engine = Engine(cfg, clock, LogSink(clock.now, cfg.buses, out=None, keep=False), durable=False,
                        save_heat=False)
        seen: list[str] = []

        def block(times: Any, taken: Any, fed: list[tuple[int, Sample]]) -> None:
            fed_rows = {row for row, _sample in fed}
            out = [(row, 1, sample) for row, sample in fed]
            for names, group, decoded in taken:
                keep, table = valued_table(decoded, len(names))
                rows = group if type(group) is list else group.tolist()
                for row, kept, values in zip(rows, keep.tolist(), table.tolist(), strict=True):
                    if kept and row not in fed_rows:
                        out.extend((row, 0, Sample(source, role, v, float(times[row])))
                                   for (source, role), v in zip(names, values, strict=True))
            out.sort(key=lambda r: r[:2])  # stable: each row's samples in output order
            seen.extend(repr(sample) for _row, _k, sample in out)

        engine.sample_block = block
        blocks = [Block.of_frames(frames[i:i + 97]) for i in range(0, len(frames), 97)]
        assert not all(block.ordered for block in blocks)
        engine.run_log(blocks, {}, bus, {})
        assert len(want) > 10_000 and any("nan" in sample for sample in want)
        assert seen == want

    def test_log_covers_what_it_should(self, custom: tuple[Config, Path], tmp_path: Path) -> None:
        """The reference run trips, recovers and complains as the script says (else the comparison tests little)."""
        cfg, log = custom
        ref = reference(cfg, log, tmp_path, export=EXPORT)  # the one reference of this log: one test exports
        events = [json.loads(line) for line in ref.events.splitlines()]
        tripped = {e["node"] for e in events if e["event"] == "trip"}
        recovered = {e["node"] for e in events if e["event"] == "recover"}
        for node in ("Pack", "Efforts", "Axis0", "ProbeA", "ProbeB", "ProbeBE", "ProbeBig", "ProbeStep", "Axis1Heat",
                     "Axis0Heat"):
            assert node in tripped and node in recovered, (node, tripped, recovered)
        assert {"stale", "fresh", "confirmed", "escalate", "stop", "resume"} <= {e["event"] for e in events}
        reasons = {e["reason"] for e in events if e["event"] == "stale"}
        assert {"stale", "nan", "inf", "out_of_range", "bad_length", "not_present"} <= reasons, reasons
        assert any(e["event"] == "confirmed" and repr(e["value"]) == "-0.0" for e in events)
        summary = json.loads(ref.summary)
        assert summary["frames"]["backward_timestamps"] == 3 and summary["frames"]["repeated_timestamps"] >= 2
        assert summary["frames"]["remote_frames"] == 1 and summary["frames"]["error_frames"] == 1
        assert ref.state["skipped_ticks"] > 6000  # the 65 s gap was jumped

    def test_blocks_cover_what_they_should(self, custom: tuple[Config, Path]) -> None:
        """In blocks of 300 characters the reader gives every kind of block run_log tells apart."""
        _, log = custom
        cols = chunks_of(log, 300)
        assert any(not c.ordered for c in cols)  # a row back in time inside a block
        assert any(c.time_s[0] < 10000.0 for c in cols) and any(c.time_s[0] >= 10000.0 for c in cols)
        keys = {int(k) for c in cols for k in c.keys.tolist()}
        assert {0x18FF50E5 + EXT_KEY, 0x014, 0x0CFEFFFE + EXT_KEY} <= keys
        marked = [ln for ln in log.read_text(encoding="ascii").splitlines() if ln.endswith(" R")]
        first, last = (float(ln[1:ln.index(")")]) for ln in (marked[0], marked[-1]))
        assert any(first <= float(c.time_s[0]) and float(c.time_s[-1]) <= last for c in cols)  # marked lines
        assert any(c.special.size for c in cols)  # remote and error frames in a block

    @pytest.mark.parametrize("chunk", [300, 4096, DEFAULT_CHUNK])
    def test_same_output(self, custom: tuple[Config, Path], tmp_path: Path, chunk: int) -> None:
        """Both paths give the same summary, events, frames and engine state."""
        cfg, log = custom
        [col] = compare(cfg, log, tmp_path, (chunk,))
        if chunk != DEFAULT_CHUNK:
            assert col.fed_rows > 0  # and the column decoder left rows to the frame decoder
            handled = {cfg.database.get_message_by_frame_id(i).name for i in col.handled_ids}
            assert handled >= HANDLED, HANDLED - handled

    def test_block_starting_at(self, custom: tuple[Config, Path], tmp_path: Path) -> None:
        """Blocks starting right at a trip, a row at a tick, a row back in time, the first row after a gap...: the same.

        One replay whose blocks start at each of these rows (:class:`BlockCuts`), about 100 lines a block between them.
        """
        cfg, log = custom
        lines = log.read_text(encoding="ascii").splitlines()
        bms = msg_id("BMS_Status").lower()

        def at(k: int, dt: float = 0.0) -> str:
            return f"({CUSTOM_T0 + k * 0.01 + dt + sum(g for s, g in GAPS.items() if s <= k):.6f})"

        preds: dict[str, Callable[[str], bool]] = {
            "trip": lambda line: line.startswith(at(TRIP_STEP)) and bms in line.lower(),
            "at_tick": lambda line: line.startswith(at(50)),  # a BMS row on the 100 Hz grid
            "inside_burst": lambda line: line.startswith(at(42, 0.0091 + 12 * 0.00003)),
            "backward": lambda line: line.startswith(at(470, -0.0093)),
            "backward_after_unconfigured": lambda line: line.startswith(at(485, 0.0022)),
            "stale_source_back": lambda line: line.startswith(at(480, 0.002)),  # axis1 after 0.3 s
            "after_gap": lambda line: line.startswith(at(700)),
            "after_long_gap": lambda line: line.startswith(at(760)),
            "not_present_new_digit": lambda line: line.startswith(at(500)),  # 10000.000000, Present 0
            "present_again": lambda line: line.startswith(at(520)),
        }
        starts = {what: custom_line(log, pred) for what, pred in preds.items()}
        cuts = BlockCuts(log, sorted(starts.values()))
        blocks = chunks_of(log, cuts)
        firsts = list(itertools.accumulate((b.n for b in blocks), initial=0))
        for what, i in starts.items():
            j = firsts.index(i)  # the block that starts with line i
            start = blocks[j]
            stamp = float(lines[i][1:lines[i].index(")")])
            assert float(start.time_s[0]) == stamp, what
            if what.startswith("backward"):
                assert float(start.time_s[0]) < float(blocks[j - 1].time_s[-1])
        compare(cfg, log, tmp_path, (cuts,))


class TestSimulator:
    """Simulator logs (every scenario on a loaded bus) on the bundled configs."""

    # The bundled config at two block sizes and ways of reading (compare's variant: with --export-signals, then
    # numpy from the second block on), the other two at one each. Blocks of 300 characters, which fall everywhere,
    # are the scripted log's (TestCustomLog): on this 48,000-frame log they cost several times all the rest.
    @pytest.mark.parametrize(("config", "chunks", "variant"), [
        (BUNDLED, (4096, DEFAULT_CHUNK), 1), (ROBOT_GUARD, (4096,), 2), (MULTI, (1009,), 0),
    ], ids=["canguard", "robot_guard", "multi_current_monitoring"])
    def test_same_output(self, sim_log: Path, tmp_path: Path, config: Path, chunks: tuple[int, ...],
                         variant: int) -> None:
        """Trips (hysteresis, inrush, I²t, thresholds), stale BMS, garbage and error frames: the same."""
        cfg = load_config(config)
        cols = compare(cfg, sim_log, tmp_path, chunks, variant=variant)
        summary = json.loads(cols[0].summary)
        assert summary["trip_count"] > 0 and summary["frames"]["error_frames"] == 32

    def test_no_source_config(self, custom: tuple[Config, Path], tmp_path: Path) -> None:
        """A tree that reads no source (ticks only, at 10 Hz): every row is crossed by bisection; gaps jumped."""
        _, log = custom
        [col, _] = compare(load_config(TIMED), log, tmp_path, (300, DEFAULT_CHUNK), min_handled=0)
        assert col.handled_rows == 0 and col.state["skipped_ticks"] > 0


def replay_watched(cfg: Config, log: Path, out: Path, watched: bool) -> tuple[str, bytes, bytes, int]:
    """Replay ``log`` in blocks of 4096 characters, every tick run when ``watched`` (an observer looks at each, as
    the live monitors do): (summary, events, emitted frames, quiet ticks counted)."""
    engines: list[Engine] = []

    class Looking:
        def publish(self, engine: Engine, now: float) -> None:
            pass

    class Watched(Engine):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            if watched:
                self.observer = Looking()
            engines.append(self)

    out.mkdir()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(canguard.cli.replay, "Engine", Watched)
        mp.setattr(canguard.io.candump, "CHUNK_CHARS", 4096)
        summary = replay_one(cfg, log, ReplayOptions(events=out / "events.jsonl", emit=out / "emit.log"))
    py_trees.blackboard.Blackboard.clear()
    [engine] = engines
    return (json.dumps(summary, sort_keys=True), (out / "events.jsonl").read_bytes(), (out / "emit.log").read_bytes(),
            engine.stats.quiet_ticks)


class TestQuietTicks:
    """Counting the grid ticks proven quiet instead of running them changes nothing a user sees."""

    def test_every_tick_run_gives_the_same(self, custom: tuple[Config, Path], tmp_path: Path) -> None:
        """The custom log (trips, stale gaps, I²t across skipped ticks) with every tick run (an observer
        watches each) gives the summary, events and frames it gives with the quiet ticks counted."""
        cfg, log = custom
        quiet = replay_watched(cfg, log, tmp_path / "quiet", False)
        every = replay_watched(cfg, log, tmp_path / "every", True)
        assert quiet[3] > 0 and every[3] == 0  # quiet ticks counted; every tick run
        assert quiet[:3] == every[:3]


class TestChannels:
    """Several channels: in one block and in blocks of their own, on two buses, mapped and unmapped."""

    @pytest.mark.parametrize("chunk", [1009, 4096])
    def test_two_buses(self, channels: tuple[Config, Path], tmp_path: Path, chunk: int) -> None:
        """can0 -> main, can1 -> aux (by channel name), can2 unmapped (in blocks of can2 alone too)."""
        cfg, log = channels
        [col] = compare(cfg, log, tmp_path, (chunk,))
        summary = json.loads(col.summary)
        assert summary["unmapped_channels"]["can2"] > 0
        assert {t["source"] for t in summary["trips"]} >= {"/battery_state", "axis0"}
        blocks = chunks_of(log, chunk)
        singles = {None if b.only_channel is None else b.channels[b.only_channel] for b in blocks}
        assert {"can0", "can1", None} <= singles  # blocks of one channel each, and mixed ones
        assert chunk > 1009 or "can2" in singles

    def test_map(self, channels: tuple[Config, Path], tmp_path: Path) -> None:
        """--map can2=aux can1=main: can2 blocks reach aux, can1's go to main."""
        cfg, log = channels
        [col] = compare(cfg, log, tmp_path, (1009,), channel_map={"can2": "aux", "can1": "main"})
        assert json.loads(col.summary)["unmapped_channels"] == {}

    def test_only_bus_merges_channels(self, channels: tuple[Config, Path], tmp_path: Path) -> None:
        """One bus, no --map: every channel goes to it, counted per channel (merged_channels)."""
        _, log = channels
        [col] = compare(load_config(BUNDLED), log, tmp_path, (1009,))
        assert set(json.loads(col.summary)["merged_channels"]) == {"can0", "can1", "can2"}

    def test_map_leaves_a_channel_unmapped(self, channels: tuple[Config, Path], tmp_path: Path) -> None:
        """One bus with --map can2=main: can0 goes to it by its channel, can1 to no bus (whole blocks unmapped)."""
        _, log = channels
        [col] = compare(load_config(BUNDLED), log, tmp_path, (1009,), channel_map={"can2": "main"})
        assert set(json.loads(col.summary)["unmapped_channels"]) == {"can1"}


class TestTheComparison:
    """The comparison itself: it must see a column path that goes wrong."""

    def test_catches_a_handler_that_drops_edges(self, custom: tuple[Config, Path], tmp_path: Path) -> None:
        """Message plans that never report an edge (no edge tick): the comparison fails."""
        cfg, log = custom
        reference(cfg, log, tmp_path)  # the truth, before the step goes wrong (blocks of one take it too)
        take_runs = canguard.engine.blocks.take_runs

        def edgeless(runs: Any) -> tuple[int, bool]:
            return take_runs(runs)[0], False

        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(canguard.engine.blocks, "take_runs", edgeless)
            with pytest.raises(AssertionError):
                compare(cfg, log, tmp_path, (4096,))

    def test_catches_a_tick_missed_between_rows(self, custom: tuple[Config, Path], tmp_path: Path) -> None:
        """A _cross that brings no tick among unconfigured rows (ticks come late, at the next configured row)."""
        _, log = custom
        reference(load_config(TIMED), log, tmp_path)  # the truth, before the step goes wrong (blocks of one cross too)
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(LogRun, "_cross", lambda self, ts, lo, hi: None)
            with pytest.raises(AssertionError):
                compare(load_config(TIMED), log, tmp_path, (300,), min_handled=0)
