"""Tests of canguard.config.loader: the bundled config loads; each mistake names file, key and a hint."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from canguard.cli.check import describe
from canguard.config.loader import load_config, load_config_text
from canguard.errors import ConfigError
from checkout import REPO

HERE = REPO / "tests"
ROBOT_DBC = REPO / "dbc" / "robot.dbc"
CFG = (
    HERE / "data" / "foundation_test.yaml"
)  # never written: only names the file and the folder paths resolve in

BASE = f"""\
dbc: {ROBOT_DBC}
buses:
  main: {{interface: virtual, channel: can0}}
"""


def load(body: str, buses: str = "") -> object:
    """Load BASE (+ extra buses) + ``body`` as a config file named foundation_test.yaml."""
    text = BASE + textwrap.indent(textwrap.dedent(buses), "  ") + textwrap.dedent(body)
    return load_config_text(text, CFG)


def problems(body: str, buses: str = "") -> list[str]:
    """The problems ConfigError lists for that config."""
    with pytest.raises(ConfigError) as info:
        load(body, buses)
    return info.value.problems


class TestBundledConfig:
    """config/canguard.yaml and dbc/robot.dbc load into the documented objects."""

    def test_bundled_config_loads(self) -> None:
        """The bundled config resolves every source to the robot DBC with units and ranges."""
        cfg = load_config(REPO / "config" / "canguard.yaml")
        assert set(cfg.sources) == {"/battery_state", "/joint_states", "axis0", "axis1", "axis2", "axis3"}
        battery = cfg.sources["/battery_state"]
        current = battery.signal("current")
        assert current is not None
        assert (current.message, current.frame_id, current.is_extended_id) == ("BMS_Status", 0x18FF50E5, True)
        assert (current.unit, current.minimum, current.maximum) == ("A", -500.0, 500.0)
        assert battery.signal("present") is not None and battery.value_roles == ("current",)
        assert cfg.sources["/joint_states"].value_roles == ("axis0", "axis1", "axis2", "axis3")
        assert cfg.sources["axis2"].signals[0].frame_id == 2 << 5 | 0x14
        assert cfg.dbc_files == (ROBOT_DBC,)

    def test_bundled_frames_and_paths(self) -> None:
        """Task, stop, confirm, actions, tree, events and state paths are resolved as documented."""
        cfg = load_config(REPO / "config" / "canguard.yaml")
        assert [(f.label, f.arbitration_id, f.data) for f in cfg.task.frames][:2] == [
            ("Axis0_Set_Axis_State", 0x07, b"\x08\x00\x00\x00"),
            ("Axis1_Set_Axis_State", 0x27, b"\x08\x00\x00\x00"),
        ]
        assert cfg.task.period_s == 0.02 and cfg.stop.repeat_s == 0.05
        assert [f.label for f in cfg.stop.frames] == [f"Axis{i}_Estop" for i in range(4)]
        assert cfg.stop.confirm is not None
        assert (cfg.stop.confirm.source, cfg.stop.confirm.op, cfg.stop.confirm.value) == ("axis0", "<", 1.0)
        assert [f.data for f in cfg.stop.escalate] == [b"\x01\x00\x00\x00"] * 4
        assert [f.label for f in cfg.actions["PerformRecovery"].frames] == [
            f"Axis{i}_Clear_Errors" for i in range(4)
        ]
        assert {"PerformDiagnostics", "NavigateToPose", "FollowPath", "ContinueOperation"} <= set(cfg.actions)
        assert cfg.tree is not None and cfg.tree.file == REPO / "config" / "trees" / "protected_operation.xml"
        assert cfg.events == REPO / "config" / "events.jsonl"
        assert cfg.state.file == REPO / "config" / "i2t_state.json" and cfg.state.save_period_s == 5.0

    def test_describe_lists_sources_ids_units(self) -> None:
        """describe() shows buses, each source -> message with hex id, signal units and ranges, and frames."""
        text = describe(load_config(REPO / "config" / "canguard.yaml"))
        assert "main: interface virtual, channel can0" in text
        assert "-> BMS_Status id 0x18FF50E5 (extended)" in text
        assert "current = Pack_Current A [-500 .. 500]" in text
        assert "-> Axis0_Get_Iq id 0x014" in text
        assert "confirm: axis0.current < 1 within 0.2 s" in text
        assert "Axis0_Estop" in text and "data 08 00 00 00" in text


class TestValidConfigs:
    """Accepted spellings: ids, raw frames, choice names, a single DBC string, an omitted bus."""

    def test_message_by_id_and_raw_frames(self) -> None:
        """Messages given by int or '0x..' id resolve; a raw frame keeps its id, data and hex label."""
        cfg = load(
            """
            sources:
              a: {kind: current, message: 0x14, signal: Iq_Measured}
              b: {kind: battery, message: "0x18FF50E5", current: Pack_Current}
            stop:
              frames: [{id: 0x021, data: "00", bus: main}, {id: "0x18FF0001", data: [1, 2]}]
            """
        )
        assert cfg.sources["a"].signals[0].message == "Axis0_Get_Iq"  # type: ignore[attr-defined]
        assert cfg.sources["b"].signals[0].message == "BMS_Status"  # type: ignore[attr-defined]
        raw = cfg.stop.frames  # type: ignore[attr-defined]
        assert [(f.label, f.arbitration_id, f.data, f.is_extended_id) for f in raw] == [
            ("0x021", 0x21, b"\x00", False),
            ("0x18FF0001", 0x18FF0001, b"\x01\x02", True),
        ]

    def test_confirm_equals_choice_name(self) -> None:
        """stop.confirm equals: accepts a VAL_ choice name of the signal and maps it to its number."""
        cfg = load(
            """
            sources:
              state0: {kind: current, message: Axis0_Heartbeat, signal: Axis_State}
            stop:
              frames: [{message: Axis0_Estop}]
              confirm: {source: state0, equals: IDLE, deadline: 0.3}
            """
        )
        confirm = cfg.stop.confirm  # type: ignore[attr-defined]
        assert (confirm.op, confirm.value, confirm.deadline_s) == ("==", 1.0, 0.3)


class TestConfigErrors:
    """Each kind of mistake is one problem naming file, key path, what was found and what was expected."""

    def test_unknown_key_with_closest(self) -> None:
        """A misspelt key is an error suggesting the right one."""
        assert problems("tre: {file: x.xml}\n") == [
            f"{CFG}: tre: found unknown key 'tre', expected one of dbc, buses, canopen, sources, tree, "
            "task, stop, actions, events, state, simulation, monitor; closest: tree"
        ]

    def test_unknown_nested_key(self) -> None:
        """An unknown key inside a source is an error naming its full path."""
        [p] = problems(
            "sources:\n  axis0: {kind: current, message: Axis0_Get_Iq, signal: Iq_Measured, maxage: 1}\n"
        )
        assert p.startswith(f"{CFG}: sources.axis0.maxage: found unknown key 'maxage', expected one of ")
        assert p.endswith("closest: max_age")

    def test_bad_type(self) -> None:
        """A list where a mapping belongs, and a string where seconds belong, are type errors."""
        ps = problems("sources:\n  axis0: [1, 2]\ntask: {period: fast}\n")
        assert ps == [
            f"{CFG}: sources.axis0: found a list, expected a mapping with kind: battery | joints | current",
            f"{CFG}: task.period: found 'fast', expected a number > 0 in seconds",
        ]

    def test_unknown_message_lists_closest(self) -> None:
        """An unknown message name lists the closest DBC message names."""
        [p] = problems("sources:\n  b: {kind: battery, message: BMS_Stats, current: Pack_Current}\n")
        assert p == (
            f"{CFG}: sources.b.message: found 'BMS_Stats', expected a DBC message name or frame id; "
            "closest: BMS_Status"
        )

    def test_unknown_frame_id(self) -> None:
        """A frame id no DBC message has is an error."""
        [p] = problems("sources:\n  a: {kind: current, message: 0x7FF, signal: Iq_Measured}\n")
        assert p == f"{CFG}: sources.a.message: found 0x7FF, expected the frame id of a DBC message"

    def test_unknown_signal(self) -> None:
        """A misspelt signal names its message and the closest signal."""
        [p] = problems("sources:\n  b: {kind: battery, message: BMS_Status, current: Pack_Curent}\n")
        assert (
            p == f"{CFG}: sources.b.current: found 'Pack_Curent', expected a signal of BMS_Status; "
            "closest: Pack_Current"
        )

    def test_unknown_bus(self) -> None:
        """A bus name that is not configured suggests the closest bus."""
        [p] = problems(
            "sources:\n  a: {kind: current, bus: mian, message: Axis0_Get_Iq, signal: Iq_Measured}\n"
        )
        assert p == f"{CFG}: sources.a.bus: found 'mian', expected a configured bus; closest: main"

    def test_missing_bus_with_several_buses(self) -> None:
        """With two buses a source or frame that leaves out bus: is an error listing them."""
        ps = problems(
            """
            sources:
              a: {kind: current, message: Axis0_Get_Iq, signal: Iq_Measured}
            stop: {frames: [{message: Axis0_Estop}]}
            """,
            buses="aux: {interface: virtual, channel: can1}\n",
        )
        expected = "found nothing, expected one of the buses main, aux (several buses are configured)"
        assert ps == [f"{CFG}: sources.a.bus: {expected}", f"{CFG}: stop.frames[0].bus: {expected}"]

    def test_unknown_interface(self) -> None:
        """A misspelt python-can interface suggests the right one."""
        [p] = problems("", buses="aux: {interface: socketcann, channel: can1}\n")
        assert p.startswith(
            f"{CFG}: buses.aux.interface: found 'socketcann', expected a python-can interface; "
            "closest: socketcan"
        )

    def test_bus_filter_takes_true_or_false(self) -> None:
        """``filter:`` under a bus is a boolean: anything else names the key and the two meanings."""
        [p] = problems("", buses="aux: {interface: virtual, channel: can1, filter: 'no'}\n")
        assert p == (f"{CFG}: buses.aux.filter: found 'no', expected true (receive only the frames the config "
                     "reads) or false (every frame)")
        cfg = load("", buses="aux: {interface: virtual, channel: can1, filter: false}\n")
        assert "  aux: interface virtual, channel can1; filter: false (every frame received)" in describe(cfg)

    def test_built_in_interfaces_are_python_cans(self) -> None:
        """The interface names a config may give without importing python-can are all the installed one's."""
        import can.interfaces

        from canguard.config.sections import _BUILT_IN_INTERFACES

        assert _BUILT_IN_INTERFACES <= can.interfaces.VALID_INTERFACES
        assert {"socketcan", "virtual", "udp_multicast"} <= _BUILT_IN_INTERFACES

    def test_frame_value_out_of_range(self) -> None:
        """A signal value outside the DBC range names the signal key and the range."""
        [p] = problems(
            "task: {frames: [{message: Axis0_Set_Axis_State, signals: {Axis_Requested_State: 99}}]}\n"
        )
        assert p == (
            f"{CFG}: task.frames[0].signals.Axis_Requested_State: found 99, "
            "expected a value of Axis_Requested_State within its DBC range [0, 14]"
        )

    def test_frame_value_not_a_choice(self) -> None:
        """A misspelt choice name lists the closest choices."""
        [p] = problems(
            "task: {frames: [{message: Axis0_Set_Axis_State, "
            "signals: {Axis_Requested_State: CLOSED_LOOP}}]}\n"
        )
        assert p == (
            f"{CFG}: task.frames[0].signals.Axis_Requested_State: found 'CLOSED_LOOP', "
            "expected a number or a choice of Axis_Requested_State; closest: CLOSED_LOOP_CONTROL"
        )

    def test_frame_value_that_does_not_encode(self, tmp_path: Path) -> None:
        """A value inside the DBC range that does not fit the signal's bits is an error naming the signal."""
        dbc = tmp_path / "wide.dbc"
        dbc.write_text('VERSION ""\n\nBU_: N\n\nBO_ 5 Wide: 1 N\n SG_ Small : 0|4@1+ (1,0) [0|100] "" N\n')
        text = (
            f"dbc: {dbc}\nbuses: {{main: {{interface: virtual}}}}\n"
            "task: {frames: [{message: Wide, signals: {Small: 50}}]}\n"
        )
        with pytest.raises(ConfigError) as info:
            load_config_text(text, tmp_path / "c.yaml")
        [p] = info.value.problems
        assert p.startswith(
            f"{tmp_path / 'c.yaml'}: task.frames[0].signals: found Small=50, which does not encode ("
        )
        assert p.endswith("expected values within the ranges of Wide's signals")

    def test_raw_frame_errors(self) -> None:
        """Raw frames: bad hex data, a standard id above 0x7FF and over-long classic data are errors."""
        ps = problems(
            """
            stop:
              frames:
                - {id: 0x21, data: "zz"}
                - {id: 0x800, data: "00", extended: false}
                - {id: 0x22, data: "00 11 22 33 44 55 66 77 88"}
            """
        )
        assert ps == [
            f"{CFG}: stop.frames[0].data: found 'zz', "
            "expected hex bytes ('00 ff') or a list of byte values 0..255",
            f"{CFG}: stop.frames[1].id: found 0x800, "
            "expected a standard frame id 0..0x7FF (or extended: true)",
            f"{CFG}: stop.frames[2].data: found 9 bytes, expected at most 8 bytes (fd: true for more)",
        ]

    @pytest.mark.parametrize(
        ("body", "key"),
        [
            ("task: {period: 0}\n", "task.period"),
            ("stop: {repeat: -0.05}\n", "stop.repeat"),
            (
                "sources:\n  a: {kind: current, message: Axis0_Get_Iq, signal: Iq_Measured, max_age: 0}\n",
                "sources.a.max_age",
            ),
            ("state: {save_period: 0}\n", "state.save_period"),
        ],
    )
    def test_non_positive_seconds(self, body: str, key: str) -> None:
        """Seconds keys (period, repeat, max_age, save_period) must be > 0."""
        [p] = problems(body)
        assert p.startswith(f"{CFG}: {key}: found ") and p.endswith("expected a number > 0 in seconds")

    def test_confirm_errors(self) -> None:
        """stop.confirm needs exactly one comparison, a known source and a positive deadline."""
        ps = problems(
            """
            sources:
              axis0: {kind: current, message: Axis0_Get_Iq, signal: Iq_Measured}
            stop:
              confirm: {source: axis9, below: 1, above: 2, deadline: 0}
            """
        )
        assert ps == [
            f"{CFG}: stop.confirm: found 2 of below/above/equals, "
            "expected exactly one of below, above, equals",
            f"{CFG}: stop.confirm.deadline: found 0, expected a number > 0 in seconds",
            f"{CFG}: stop.confirm.source: found 'axis9', expected a configured source; closest: axis0",
        ]

    def test_yaml_syntax_error_names_line(self, tmp_path: Path) -> None:
        """A YAML syntax error names file:line:column."""
        bad = tmp_path / "broken.yaml"
        bad.write_text("dbc: robot.dbc\nbuses:\n  main: {interface: virtual\nsources: {}\n")
        with pytest.raises(ConfigError) as info:
            load_config(bad)
        [p] = info.value.problems
        assert p.startswith(f"{bad}:4:") and "YAML syntax error" in p

    def test_duplicate_key_is_an_error(self) -> None:
        """A key given twice in one mapping is a syntax error naming its line, not a silent override."""
        with pytest.raises(ConfigError, match=r"foundation_test.yaml:5:.*duplicate key 'sources'"):
            load_config_text(BASE + "sources: {}\nsources: {}\n", CFG)

    def test_missing_dbc_file(self) -> None:
        """A DBC path that does not exist is reported with the resolved path."""
        with pytest.raises(ConfigError) as info:
            load_config_text("dbc: nowhere.dbc\nbuses: {main: {interface: virtual}}\n", CFG)
        assert info.value.problems == [
            f"{CFG}: dbc[0]: found 'nowhere.dbc', "
            f"expected an existing DBC file (no such file: {HERE / 'data' / 'nowhere.dbc'})"
        ]

    def test_broken_dbc_file(self, tmp_path: Path) -> None:
        """A DBC that cantools cannot parse is a problem naming that DBC file."""
        broken = tmp_path / "broken.dbc"
        broken.write_text('VERSION ""\nBO_ 1 X: 8 Y\nBO_ zz\n')
        with pytest.raises(ConfigError, match=rf"dbc\[0\]: found {broken} which does not load"):
            load_config_text(
                f"dbc: [{broken}]\nbuses: {{main: {{interface: virtual}}}}\n", tmp_path / "c.yaml"
            )

    def test_duplicate_message_across_dbc_files(self) -> None:
        """The same DBC twice gives duplicate message names, reported once per message with both files."""
        with pytest.raises(ConfigError) as info:
            load_config_text(
                f"dbc: [{ROBOT_DBC}, {ROBOT_DBC}]\nbuses: {{main: {{interface: virtual}}}}\n", CFG
            )
        assert info.value.problems[0] == (
            f"{CFG}: dbc: found message 'Axis0_Heartbeat' in both {ROBOT_DBC} and {ROBOT_DBC}, "
            "expected unique message names"
        )

    def test_several_errors_reported_together(self) -> None:
        """Independent mistakes in one file are all reported in one ConfigError, in file order."""
        ps = problems(
            """
            sources:
              /battery_state: {kind: battery, message: BMS_Status, current: Pack_Curent, max_age: -1}
              axis0: {kind: curent, message: Axis0_Get_Iq, signal: Iq_Measured}
            task: {period: 0, frames: [{message: Axis0_Set_Axis_Stat}]}
            events: 5
            """
        )
        assert [p.split(": ")[1] for p in ps] == [
            "sources./battery_state.max_age",
            "sources./battery_state.current",
            "sources.axis0.kind",
            "task.period",
            "task.frames[0].message",
            "events",
        ]
        assert str(ConfigError(ps)).count("\n") == 5

    def test_frame_value_not_one_of_the_choices(self) -> None:
        """A number for a signal with VAL_ choices must be one of them: 1.5 is not rounded to 2 (a moving state)."""
        ps = problems(
            """
            task: {frames: [{message: Axis0_Set_Axis_State, signals: {Axis_Requested_State: 5}}]}
            stop:
              frames: [{message: Axis0_Set_Axis_State, signals: {Axis_Requested_State: 1.5}}]
              escalate: [{message: Axis1_Set_Axis_State, signals: {Axis_Requested_State: 1.0000001}}]
            actions:
              Park: {frames: [{message: Axis2_Set_Axis_State, signals: {Axis_Requested_State: 7.5}}]}
            """
        )
        choices = (
            "UNDEFINED (0), IDLE (1), STARTUP_SEQUENCE (2), FULL_CALIBRATION_SEQUENCE (3), "
            "MOTOR_CALIBRATION (4), ENCODER_INDEX_SEARCH (6), ENCODER_OFFSET_CALIBRATION (7), "
            "CLOSED_LOOP_CONTROL (8), LOCKIN_SPIN (9), ENCODER_DIR_FIND (10), HOMING (11), "
            "ENCODER_HALL_POLARITY_CALIBRATION (12), ENCODER_HALL_PHASE_CALIBRATION (13), "
            "ANTICOGGING_CALIBRATION (14)"
        )
        expected = f"expected one of the choices of Axis_Requested_State: {choices}"
        assert ps == [
            f"{CFG}: task.frames[0].signals.Axis_Requested_State: found 5, {expected}",
            f"{CFG}: stop.frames[0].signals.Axis_Requested_State: found 1.5, {expected}",
            f"{CFG}: stop.escalate[0].signals.Axis_Requested_State: found 1.0000001, {expected}",
            f"{CFG}: actions.Park.frames[0].signals.Axis_Requested_State: found 7.5, {expected}",
        ]

    def test_frame_value_not_a_whole_raw_value(self) -> None:
        """An integer signal takes only whole raw values: 1.25 A in 0.1 A steps is refused, not rounded."""
        ps = problems(
            """
            stop:
              frames:
                - {message: BMS_Status, signals: {Pack_Current: 1.25, Alive_Counter: 2.5}}
                - {message: BMS_Temperatures, signals: {Cell_Temp_Min: -39.5}}
            """
        )
        assert ps == [
            f"{CFG}: stop.frames[0].signals.Pack_Current: found 1.25, expected a whole raw value: steps of 0.1",
            f"{CFG}: stop.frames[0].signals.Alive_Counter: found 2.5, expected a whole raw value: steps of 1",
            f"{CFG}: stop.frames[1].signals.Cell_Temp_Min: found -39.5, "
            "expected a whole raw value: steps of 1 from -40",
        ]

    def test_exact_frame_values_still_encode(self) -> None:
        """Values on the signal's grid (0.3 in 0.1 steps despite float rounding), choices and float signals pass."""
        cfg = load(
            """
            stop:
              frames:
                - {message: BMS_Status, signals: {Pack_Current: 0.3, Present: 1}}
                - {message: Axis0_Set_Axis_State, signals: {Axis_Requested_State: 1.0}}
                - {message: Axis0_Get_Iq, signals: {Iq_Setpoint: 1.2345}}
            """
        )
        frames = cfg.stop.frames  # type: ignore[attr-defined]
        assert frames[0].data[:2] == (3).to_bytes(2, "big") and frames[1].data == b"\x01\x00\x00\x00"

    def test_confirm_equals_must_be_a_value_the_signal_carries(self) -> None:
        """stop.confirm equals: a number that is no choice, or no whole raw value, could never match."""
        ps = problems(
            """
            sources:
              state0: {kind: current, message: Axis0_Heartbeat, signal: Axis_State}
              soc: {kind: battery, message: BMS_Status, current: State_Of_Charge}
            stop:
              confirm: {source: state0, equals: 1.5, deadline: 0.3}
            """
        )
        assert ps == [
            f"{CFG}: stop.confirm.equals: found 1.5, expected one of the choices of Axis_State: "
            "UNDEFINED (0), IDLE (1), STARTUP_SEQUENCE (2), FULL_CALIBRATION_SEQUENCE (3), "
            "MOTOR_CALIBRATION (4), ENCODER_INDEX_SEARCH (6), ENCODER_OFFSET_CALIBRATION (7), "
            "CLOSED_LOOP_CONTROL (8), LOCKIN_SPIN (9), ENCODER_DIR_FIND (10), HOMING (11), "
            "ENCODER_HALL_POLARITY_CALIBRATION (12), ENCODER_HALL_PHASE_CALIBRATION (13), "
            "ANTICOGGING_CALIBRATION (14)"
        ]
        [p] = problems(
            """
            sources:
              soc: {kind: battery, message: BMS_Status, current: State_Of_Charge}
            stop:
              confirm: {source: soc, equals: 50.25, deadline: 0.3}
            """
        )
        assert p == f"{CFG}: stop.confirm.equals: found 50.25, expected a whole raw value: steps of 0.5"

    def test_unknown_kind_still_checks_the_rest(self) -> None:
        """A misspelt kind does not hide the source's bus, max_age, message, signal and effort errors."""
        ps = problems(
            """
            sources:
              /battery_state: {kind: batery, bus: mian, max_age: 0, message: BMS_Status, current: Pack_Curent}
              a: {kind: curent, message: Axis0_Get_Iqq, signal: Iq_Measured}
              j:
                effort: [{message: Axis0_Get_Torques, signal: Torque_Estimat, name: axis0}]
                maxage: 1
            """
        )
        assert ps == [
            f"{CFG}: sources./battery_state.kind: found 'batery', "
            "expected one of battery, joints, current; closest: battery",
            f"{CFG}: sources./battery_state.bus: found 'mian', expected a configured bus; closest: main",
            f"{CFG}: sources./battery_state.max_age: found 0, expected a number > 0 in seconds",
            f"{CFG}: sources./battery_state.current: found 'Pack_Curent', expected a signal of BMS_Status; "
            "closest: Pack_Current",
            f"{CFG}: sources.a.kind: found 'curent', expected one of battery, joints, current; closest: current",
            f"{CFG}: sources.a.message: found 'Axis0_Get_Iqq', expected a DBC message name or frame id; "
            "closest: Axis0_Get_Iq, Axis1_Get_Iq, Axis2_Get_Iq",
            f"{CFG}: sources.j.kind: found nothing, expected one of battery, joints, current; "
            "known: battery, current, joints",
            f"{CFG}: sources.j.maxage: found unknown key 'maxage', expected one of kind, bus, max_age, "
            "message, current, signal, present, counter, effort; closest: max_age",
            f"{CFG}: sources.j.effort[0].signal: found 'Torque_Estimat', "
            "expected a signal of Axis0_Get_Torques; closest: Torque_Estimate",
        ]

    def test_confirm_adds_no_follow_on_error_for_a_broken_source(self) -> None:
        """A broken source is reported once: stop.confirm naming it adds no source/signal/equals error."""
        ps = problems(
            """
            sources:
              axis0: {kind: curent, message: Axis0_Get_Iq, signal: Iq_Measured}
              state0: {kind: current, message: Axis0_Heartbeat, signal: Axis_Stat}
            stop:
              confirm: {source: axis0, below: 1, deadline: 0.2}
            """
        )
        assert [p.split(": ")[1] for p in ps] == ["sources.axis0.kind", "sources.state0.signal"]
        ps = problems(
            """
            sources:
              state0: {kind: current, message: Axis0_Heartbeat, signal: Axis_Stat}
            stop:
              confirm: {source: state0, equals: IDLE, deadline: 0.2}
            """
        )
        assert [p.split(": ")[1] for p in ps] == ["sources.state0.signal"]

    def test_confirm_adds_no_follow_on_error_when_the_dbc_fails(self) -> None:
        """With a DBC that does not load, only the DBC is reported, not stop.confirm.signal."""
        with pytest.raises(ConfigError) as info:
            load_config_text(
                "dbc: nowhere.dbc\nbuses: {main: {interface: virtual}}\n"
                "sources:\n  axis0: {kind: current, message: Axis0_Get_Iq, signal: Iq_Measured}\n"
                "stop: {confirm: {source: axis0, signal: current, below: 1, deadline: 0.2}}\n",
                CFG,
            )
        assert [p.split(": ")[1] for p in info.value.problems] == ["dbc[0]"]

    @pytest.mark.parametrize("name", ["ExecuteTask", "IsCurrentSafe", "Sequence", "SubTree"])
    def test_action_named_like_a_builtin_node(self, name: str) -> None:
        """An actions: entry may not reuse a built-in node ID; the loader says so with file and key."""
        ps = problems(f"actions:\n  {name}: {{frames: [{{message: Axis0_Estp}}]}}\n  Park: {{}}\n")
        assert ps == [
            f"{CFG}: actions.{name}: found the ID of a built-in node type, expected a new action name",
            f"{CFG}: actions.{name}.frames[0].message: found 'Axis0_Estp', "
            "expected a DBC message name or frame id; closest: Axis0_Estop, Axis1_Estop, Axis2_Estop",
        ]

    def test_missing_tree_file(self) -> None:
        """A tree.file that does not exist is a config error naming the key and the resolved path."""
        [p] = problems("tree: {file: trees/nowhere.xml}\n")
        missing = HERE / "data" / "trees" / "nowhere.xml"
        assert p == f"{CFG}: tree.file: found '{missing}' (no such file), expected a BehaviorTree.CPP XML file"

    def test_unreadable_file(self, tmp_path: Path) -> None:
        """A config path that does not exist is a ConfigError naming it."""
        with pytest.raises(ConfigError, match=r"missing.yaml: found a file that cannot be read"):
            load_config(tmp_path / "missing.yaml")


def test_tilde_of_an_unknown_user_is_a_config_error(tmp_path: Path) -> None:
    """dbc: [~nosuchuser/x.dbc] is a problem naming the key (found by fuzzing: it was a RuntimeError traceback)."""
    from canguard.config.loader import load_config_text
    from canguard.errors import ConfigError

    with pytest.raises(ConfigError, match=r"dbc.*~nosuchuser-canguard/x\.dbc.*existing user"):
        load_config_text("dbc: [~nosuchuser-canguard/x.dbc]\nbuses: {main: {interface: virtual, channel: c}}\n",
                         tmp_path / "c.yaml")
