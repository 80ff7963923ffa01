"""Quiet ticks (:mod:`canguard.engine.quiet`): a replay that skips proven-quiet ticks equals one that ticks them all.

The reference ticks every grid tick, as the live daemon does; the replay under test
counts the ticks proven to repeat the last one instead of running them. Both must
write the same summary, events and frames and leave the same engine state
(``tests/test_replay_columns.assert_same``), and the quiet ticks must really have
happened, or the comparison proves nothing. ``tests/test_replay_random_logs.py``
makes the same comparison on random DBCs and logs, through ``compare``.
"""

from __future__ import annotations

import gzip
from pathlib import Path

import pytest
import yaml

from canguard.config.loader import load_config
from checkout import REPO
from test_replay_columns import BUNDLED, DEFAULT_CHUNK, ROBOT_GUARD, assert_same, replay
from test_replay_random_logs import write_case

EXAMPLES = REPO / "examples"
PROTECTED = REPO / "config" / "examples" / "protected_operation.yaml"
LOGS = sorted(EXAMPLES.glob("*.log.gz"))
NORMAL = EXAMPLES / "normal.log.gz"
BUNDLED_LOGS = [EXAMPLES / f"{name}.log.gz" for name in ("dropout", "errorburst", "garbage", "normal", "overload",
                                                         "spike")]


def quiet_and_reference(cfg_path: Path, log: Path, out: Path, *, columns: bool = True) -> tuple[int, int]:
    """Replay with and without quiet ticks, assert the same outputs; (quiet ticks, all ticks) of the quiet run."""
    cfg = load_config(cfg_path)
    ref = replay(cfg, log, out / "ref", columns=False, chunk=DEFAULT_CHUNK, quiet=False)
    run = replay(cfg, log, out / "quiet", columns=columns, chunk=DEFAULT_CHUNK, quiet=True)
    assert_same(ref, run, f"{log.name} with {cfg_path.name}, quiet ticks on (columns {columns})")
    ticks = int(run.state["ticks"])
    return run.quiet_ticks, ticks


class TestSameAsTickingEveryTick:
    """Example logs (trips, recoveries, dropouts, garbage, error bursts) on the trees that may have quiet ticks."""

    # The example logs that trip, go stale, carry bad values or error frames, and the one that does none of these:
    # the motor start and the background load add no line or branch of canguard to these (nor to the file's).
    @pytest.mark.parametrize("log", BUNDLED_LOGS, ids=[p.name.split(".")[0] for p in BUNDLED_LOGS])
    def test_bundled_config(self, tmp_path: Path, log: Path) -> None:
        """The bundled config: every example log replays the same, most ticks quiet."""
        quiet, ticks = quiet_and_reference(BUNDLED, log, tmp_path)
        assert quiet > ticks // 2, f"only {quiet} of {ticks} ticks were quiet: the comparison proves little"

    @pytest.mark.parametrize("log", [LOGS[0], LOGS[2]], ids=[p.name.split(".")[0] for p in (LOGS[0], LOGS[2])])
    def test_protected_operation_frame_by_frame(self, tmp_path: Path, log: Path) -> None:
        """Quiet ticks on the frame-by-frame path too (formats without column blocks) give the same replay."""
        quiet, _ = quiet_and_reference(PROTECTED, log, tmp_path, columns=False)
        assert quiet > 0

    def test_the_start_window_closes_at_the_same_tick(self, tmp_path: Path) -> None:
        """A stop held back by the start window comes at the tick the window closes, rounding included.

        Found by the random-log test: the window's end ``start + max_age`` rounded to the
        tick's own time, and the quiet path took the window as closed one tick early,
        so the stop came 20 ms late.
        """
        spec = {
            "messages": [{"id": 16, "ext": False, "fd": False, "length": 8, "muxed": False, "name": "M0",
                          "signals": [{"name": "S0_0", "start": 0, "length": 16, "motorola": False,
                                       "signed": False, "float": False, "scale": 1, "offset": 0,
                                       "page": None}]}],
            "max_age": 0.03, "over": 5.0, "seed": 0, "frames": 50,
        }
        cfg_path, log = write_case(spec, tmp_path / "case")
        quiet, _ = quiet_and_reference(cfg_path, log, tmp_path)
        assert quiet > 0


def write_tree_config(tmp_path: Path, tree_body: str) -> Path:
    """The bundled config with its tree replaced by ``tree_body`` (inside a BehaviorTree ID="M")."""
    doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
    doc["dbc"] = [str((BUNDLED.parent / d).resolve()) for d in doc["dbc"]]
    tree = tmp_path / "tree.xml"
    tree.write_text(f'<root BTCPP_format="4" main_tree_to_execute="M"><BehaviorTree ID="M">{tree_body}'
                    "</BehaviorTree></root>\n", encoding="utf-8")
    doc["tree"] = {"file": str(tree), "main": "M", "tick_hz": 100}
    doc.pop("events", None)
    doc.setdefault("state", {})["file"] = str(tmp_path / "state.json")
    path = tmp_path / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


GUARD = '<IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="35" recovery_threshold="25"/>'


class TestTaskDeadlinesBetweenTicks:
    """The task's periodic frames due at, between and several times within tick periods (a fast heartbeat)."""

    # Each period once, on either log: one with a battery near its threshold (edge ticks), one without.
    @pytest.mark.parametrize(("log", "period"), [
        (NORMAL, 0.005), (EXAMPLES / "overload.log.gz", 0.004), (EXAMPLES / "overload.log.gz", 0.0125),
    ], ids=["normal-0.005", "overload-0.004", "overload-0.0125"])
    def test_same_replay(self, tmp_path: Path, period: float, log: Path) -> None:
        """Task periods below and above the 10 ms tick: the frames sent, their times, all else as the reference."""
        doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
        doc["dbc"] = [str((BUNDLED.parent / d).resolve()) for d in doc["dbc"]]
        doc["tree"]["file"] = str((BUNDLED.parent / doc["tree"]["file"]).resolve())
        doc["task"]["period"] = period
        doc.pop("events", None)
        doc.setdefault("state", {})["file"] = str(tmp_path / "state.json")
        path = tmp_path / "canguard.yaml"
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        quiet, ticks = quiet_and_reference(path, log, tmp_path)
        assert quiet > ticks // 2


    def test_task_due_again_between_the_tick_and_the_row(self, tmp_path: Path) -> None:
        """A 4 ms heartbeat on 10 ms ticks, rows 12 and 8 ms apart: a row often comes after a quiet tick whose
        own task deadline was serviced at the tick and the next one is already due (rows at 17 and 25 ms, the
        tick at 20 ms, task deadlines at 20 and 24 ms), once with an overcurrent that stops the task. The
        frames sent (the task's at 24 ms among them) and all else are those of ticking every tick.

        (``_quiet_advance`` services that second deadline at once; left due, the next step would
        service it at its own time, with the same result: this log reaches that line ~50 times, and
        removing it alone is not caught.)
        """
        from test_replay_columns import Row, bms_data, iq_data, msg_id, write_rows

        doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
        doc["dbc"] = [str((BUNDLED.parent / d).resolve()) for d in doc["dbc"]]
        doc["tree"]["file"] = str((BUNDLED.parent / doc["tree"]["file"]).resolve())
        doc["task"]["period"] = 0.004
        doc.pop("events", None)
        doc.setdefault("state", {})["file"] = str(tmp_path / "state.json")
        path = tmp_path / "canguard.yaml"
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        bms, axis0 = msg_id("BMS_Status"), msg_id("Axis0_Get_Iq")
        rows = [Row(0.0, 0, cid=bms, data=bms_data(5.0))]  # the first frame: ticks and task deadlines count from it
        for k in range(300):  # a healthy battery and axis0 at 5 and 17 ms of every 20 ms
            for j, offset in enumerate((0.005, 0.017)):
                t = 0.02 * k + offset
                amps = 80.0 if k == 150 and j == 0 else 5.0  # an overcurrent at 3.005 s: the row after such a tick
                rows += [Row(t, 4 * k + 2 * j + 1, cid=bms, data=bms_data(amps)),
                         Row(t + 0.0001, 4 * k + 2 * j + 2, cid=axis0, data=iq_data(0.5))]
        log = write_rows(tmp_path / "heartbeat.log", rows)
        quiet, ticks = quiet_and_reference(path, log, tmp_path)
        assert quiet > ticks // 2


@pytest.fixture(scope="module")
def normal_start(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 1.5 s of the normal example log (about 150 ticks)."""
    with gzip.open(NORMAL, "rt", encoding="ascii") as f:
        lines = f.readlines()
    t0 = float(lines[0][1:lines[0].index(")")])
    path = tmp_path_factory.mktemp("quiet") / "normal-start.log"
    path.write_text("".join(line for line in lines if float(line[1:line.index(")")]) < t0 + 1.5), encoding="ascii")
    return path


class TestWhichTreesMayBeQuiet:
    """Only ticks that reach nodes repeating themselves exactly may be quiet; the rest tick every tick."""

    @pytest.mark.parametrize(("why", "body"), [
        ("a timer of its own", f"<ReactiveSequence>{GUARD}<Delay delay_msec=\"100\"><ExecuteTask/></Delay>"
                               "</ReactiveSequence>"),
        ("a threshold read from the blackboard",
         '<ReactiveSequence><IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="{limit}" '
         'recovery_threshold="25"/><ExecuteTask/></ReactiveSequence>'),
        ("a pre-condition script", f'<ReactiveSequence>{GUARD}<ExecuteTask _skipIf="false"/></ReactiveSequence>'),
        ("frames sent at every tick", f"<ReactiveSequence>{GUARD}<PerformRecovery/></ReactiveSequence>"),
    ])
    def test_not_quiet(self, tmp_path: Path, why: str, body: str, normal_start: Path) -> None:
        """A tree that reaches, at every tick of a clean log, a node that may change or act over time ticks every tick.

        (On a log that trips, the ticks where a failing guard keeps the tree from reaching
        that node may be quiet: ``quiet_and_reference`` holds them to the reference too.)
        """
        quiet, ticks = quiet_and_reference(write_tree_config(tmp_path, body), normal_start, tmp_path)
        assert ticks > 100 and quiet == 0, why

    @pytest.mark.parametrize("log", [p for p in LOGS if p.name.startswith(("overload", "spike", "dropout"))],
                             ids=lambda p: p.name.split(".")[0])
    def test_a_once_only_action_and_i2t_guards(self, tmp_path: Path, log: Path) -> None:
        """The README's robot guard (I²t guards; PerformRecovery once, then ExecuteTask): the same, mostly quiet."""
        quiet, ticks = quiet_and_reference(ROBOT_GUARD, log, tmp_path)
        assert quiet > ticks // 2

    def test_guards_sequences_and_task_are_quiet(self, tmp_path: Path) -> None:
        """Sequences, fallbacks, decorators, guards and ExecuteTask: quiet ticks, the same replay."""
        body = (f"<ReactiveSequence><Fallback>{GUARD}<ForceFailure><AlwaysSuccess/></ForceFailure></Fallback>"
                f'<Inverter><Inverter><IsCurrentNormal topic_name="axis0" max_current="1000"/></Inverter></Inverter>'
                '<Sequence><IsJointEffortNormal topic_name="/joint_states" max_effort="150"/></Sequence>'
                "<ExecuteTask/></ReactiveSequence>")
        quiet, ticks = quiet_and_reference(write_tree_config(tmp_path, body), LOGS[0], tmp_path)
        assert quiet > ticks // 2
