"""DBC files as teams and vendors export them: what cantools loads without strict checks loads, a config
that reads a signal the DBC gets wrong is refused naming it, and everything else is a ``check -v`` note.

Every DBC here is written by the test: two signals of one name, two that share bits, one past its message's
end, Vector's pseudo-message with a ``VAL_`` table, all in one file whose sound signals a config reads.
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import cantools
import pytest
from tests.clikit import cli

from canguard.config.loader import load_config_text
from canguard.errors import ConfigError

pq = pytest.importorskip("pyarrow.parquet")

HEAD = 'VERSION ""\n\nNS_ :\n\tCM_\n\tBA_DEF_\n\tVAL_\n\tSIG_VALTYPE_\n\nBS_:\n\nBU_: BMS INV\n\n'
MESSAGES = """\
BO_ 1712 Pack: 8 BMS
 SG_ Pack_Current : 0|16@1- (0.1,0) [-3276.8|3276.7] "A" INV
 SG_ Pack_Voltage : 16|16@1+ (0.1,0) [0|6553.5] "V" INV

BO_ 1713 Cells: 8 BMS
 SG_ Spare : 0|8@1+ (1,0) [0|255] "" INV
 SG_ Cell_High : 8|16@1+ (0.0001,0) [0|6.5535] "V" INV
 SG_ Spare : 24|8@1+ (1,0) [0|255] "" INV
 SG_ Cell_Low : 32|16@1+ (0.0001,0) [0|6.5535] "V" INV

BO_ 1714 Drive: 8 INV
 SG_ Temp_Stator : 0|16@1- (0.1,0) [-3276.8|3276.7] "degC" BMS
 SG_ Temp_Rotor : 8|16@1- (0.1,0) [-3276.8|3276.7] "degC" BMS
 SG_ Iq : 32|16@1- (0.1,0) [-3276.8|3276.7] "A" BMS
 SG_ Id : 55|16@0- (0.1,0) [-3276.8|3276.7] "A" BMS

BO_ 1715 Command: 4 INV
 SG_ Torque_Cmd : 0|16@1- (0.1,0) [-300|300] "Nm" BMS
 SG_ Enable : 16|1@1+ (1,0) [0|1] "" BMS
 SG_ Reserved : 24|16@1+ (1,0) [0|65535] "" BMS

BO_ 1716 Phases: 8 INV
 SG_ Page M : 0|8@1- (1,0) [-128|127] "" BMS
 SG_ Phase_A m0 : 8|16@1- (0.1,0) [-3276.8|3276.7] "A" BMS
 SG_ Glitch m0 : 16|16@1- (0.1,0) [-3276.8|3276.7] "A" BMS
 SG_ Phase_B m1 : 8|13@1- (0.5,-2) [-2050|2045.5] "A" BMS
 SG_ Phase_C m0 : 40|16@0+ (0.01,-100) [-100|555.35] "A" BMS

BO_ 3221225472 VECTOR__INDEPENDENT_SIG_MSG: 0 Vector__XXX
 SG_ Unplaced : 0|8@1+ (1,0) [0|255] "" Vector__XXX

CM_ SG_ 1714 Iq "quadrature current; the one to guard
 (a comment of two lines)";
BA_DEF_ SG_ "GenSigStartValue" INT 0 65535;
BA_DEF_DEF_ "GenSigStartValue" 0;
VAL_ 3221225472 Unplaced 0 "Off" 1 "On" ;
VAL_ 1715 Enable 0 "Off" 1 "On" ;
"""
BROKEN = ("Spare", "Temp_Stator", "Temp_Rotor", "Reserved", "Phase_A", "Glitch", "Unplaced",
          "VECTOR__INDEPENDENT_SIG_MSG")


def line_of(text: str, needle: str, nth: int = 0) -> int:
    """The 1-based line of the ``nth`` line of ``text`` that holds ``needle``."""
    return [i for i, line in enumerate(text.splitlines(), 1) if needle in line][nth]


def vendor_dbc(tmp_path: Path, extra: str = "", drop: str = "") -> tuple[Path, str]:
    """The DBC with every pattern (``extra`` statements added, the lines holding ``drop`` left out), and its text."""
    text = HEAD + MESSAGES + extra
    if drop:
        text = "".join(line for line in text.splitlines(keepends=True) if drop not in line)
    path = tmp_path / "vendor.dbc"
    path.write_text(text, encoding="cp1252")
    (tmp_path / "guard.xml").write_text(
        '<root BTCPP_format="4" main_tree_to_execute="M"><BehaviorTree ID="M"><ReactiveSequence>'
        '<IsCurrentNormal topic_name="drive"/><ExecuteTask/></ReactiveSequence></BehaviorTree></root>',
        encoding="utf-8")
    return path, text


def sound_db() -> cantools.database.can.Database:
    """The reference: cantools (strict) over the same file without the signals it gets wrong."""
    lines = [line for line in (HEAD + MESSAGES).splitlines() if not any(name in line for name in BROKEN)]
    return cantools.database.load_string("\n".join(lines) + "\n", database_format="dbc")


CONFIG = """\
dbc: vendor.dbc
buses: {main: {interface: virtual}}
sources:
  pack: {kind: battery, message: Pack, current: Pack_Current}
  drive: {kind: current, message: Drive, signal: Iq}
  other:
    kind: joints
    effort:
      - {message: Drive, signal: Id, name: id}
      - {message: Cells, signal: Cell_High, name: cell}
      - {message: Phases, signal: Phase_B, name: phase_b}
      - {message: Phases, signal: Phase_C, name: phase_c}
tree: {file: guard.xml, main: M, tick_hz: 100}
task: {frames: [{message: Command, signals: {Torque_Cmd: -12.5, Enable: "On"}}]}
"""


def problems(tmp_path: Path, config: str, extra: str = "", drop: str = "") -> list[str]:
    """The located problems of ``config`` over the vendor DBC (none: it loaded)."""
    vendor_dbc(tmp_path, extra, drop)
    try:
        load_config_text(config, tmp_path / "c.yaml")
    except ConfigError as exc:
        return list(exc.located)
    return []


class TestLoads:
    """A DBC with every pattern loads; each pattern is a note naming its file and line."""

    def test_cantools_refuses_the_file(self, tmp_path: Path) -> None:
        """The file is one cantools refuses when strict (recent cantools also without: the pseudo-message's VAL_)."""
        path, _ = vendor_dbc(tmp_path)
        with pytest.raises(cantools.database.UnsupportedDatabaseFormatError, match="overlapping"):
            cantools.database.load_file(str(path))

    def test_notes_name_each_pattern_with_its_line(self, tmp_path: Path) -> None:
        """The config of sound signals loads; its notes list each pattern once, at the file's line."""
        path, text = vendor_dbc(tmp_path)
        cfg = load_config_text(CONFIG, tmp_path / "c.yaml")
        at = {needle: f"{path}:{line_of(text, needle)}" for needle in
              ("Temp_Stator", "Temp_Rotor", "Reserved", "Glitch", "Phase_A", "BO_ 3221225472", "VAL_ 3221225472")}
        assert cfg.dbc_notes == (
            f"{at['BO_ 3221225472']}: skipped BO_ VECTOR__INDEPENDENT_SIG_MSG (Vector's pseudo-message for the "
            "signals of no message; signals: 1)",
            f"{at['VAL_ 3221225472']}: skipped VAL_ of signal Unplaced of message 3221225472: it belongs to "
            "VECTOR__INDEPENDENT_SIG_MSG, Vector's pseudo-message for the signals of no message",
            f"{path}:{line_of(text, 'Spare')}: signal Spare is defined 2 times in message Cells "
            f"(again at {path}:{line_of(text, 'Spare', 1)})",
            f"{at['Temp_Stator']}: signals Temp_Stator and Temp_Rotor ({at['Temp_Rotor']}) overlap in message "
            "Drive (bits 8..15)",
            f"{at['Reserved']}: signal Reserved (bits 24..39) does not fit in message Command (4 bytes)",
            f"{at['Phase_A']}: signals Phase_A and Glitch ({at['Glitch']}) overlap in message Phases (bits 16..23)",
        )

    def test_multiplexed_signals(self, tmp_path: Path) -> None:
        """Phase_A overlaps Glitch on page 0 and is refused; Phase_B shares its bits on page 1 only and loads."""
        assert problems(tmp_path, CONFIG) == []
        [p] = problems(tmp_path, CONFIG.replace("Phase_B", "Phase_A"))
        assert "sources.other.effort[2].signal: found 'Phase_A', which the DBC gets wrong" in p

    def test_a_page_of_only_broken_signals(self, tmp_path: Path) -> None:
        """Without Phase_C, Page = 0 selects only signals left out: no frame on it decodes, so the message's
        signals are refused where a source reads them."""
        [p] = problems(tmp_path, CONFIG.replace("      - {message: Phases, signal: Phase_C, name: phase_c}\n", ""),
                       drop="Phase_C")
        path, text = vendor_dbc(tmp_path, drop="Phase_C")
        assert p.startswith(f"{tmp_path / 'c.yaml'}:11: sources.other.effort[2].signal: found 'Phase_B', of a "
                            f"message whose frames do not all decode ({path}:{line_of(text, 'Page M')}: multiplexer "
                            "Page of message Phases = 0 selects only signals left out, so no frame on it decodes)")

    def test_statements_of_messages_the_file_does_not_define_are_skipped(self, tmp_path: Path) -> None:
        """VAL_, SIG_VALTYPE_ and attributes of an undefined message or signal are notes, not errors."""
        extra = ('SIG_VALTYPE_ 999 Ghost : 1;\nBA_ "GenSigStartValue" SG_ 999 Ghost 3;\n'
                 'VAL_ 1712 Nope 0 "x" ;\n')
        path, text = vendor_dbc(tmp_path, extra)
        cfg = load_config_text(CONFIG, tmp_path / "c.yaml")
        assert [n for n in cfg.dbc_notes if "999" in n or "Nope" in n] == [
            f"{path}:{line_of(text, 'SIG_VALTYPE_ 999')}: skipped SIG_VALTYPE_ of signal Ghost of message 999: "
            "the file defines no message of that id (0x3E7)",
            f"{path}:{line_of(text, 'SG_ 999')}: skipped BA_ \"GenSigStartValue\" of signal Ghost of message 999: "
            "the file defines no message of that id (0x3E7)",
            f"{path}:{line_of(text, 'Nope')}: skipped VAL_ of signal Nope of message 1712: message Pack has no "
            "signal Nope",
        ]

    def test_a_syntax_error_keeps_its_line(self, tmp_path: Path) -> None:
        """Skipped statements keep the lines of the file: cantools' syntax error names the line in the file."""
        ps = problems(tmp_path, CONFIG, "BO_ zz\n")
        path, text = vendor_dbc(tmp_path, "BO_ zz\n")
        assert len(ps) == 1 and f"{path} which does not load" in ps[0]
        assert f"line {len(text.splitlines())}" in ps[0]


class TestRefused:
    """A config that reads a signal the DBC gets wrong is refused, naming both signals, the message and the line."""

    @pytest.mark.parametrize(("message", "signal", "words"), [
        ("Cells", "Spare", "signal Spare is defined 2 times in message Cells"),
        ("Drive", "Temp_Rotor", "signals Temp_Stator and Temp_Rotor ({dbc}:{rotor}) overlap in message Drive"),
        ("Command", "Reserved", "signal Reserved (bits 24..39) does not fit in message Command (4 bytes)"),
    ])
    def test_source_reading_a_broken_signal(self, tmp_path: Path, message: str, signal: str, words: str) -> None:
        """The source's key is refused at the config's line, with the DBC's file:line of the problem."""
        path, text = vendor_dbc(tmp_path)
        config = CONFIG.replace(
            "{kind: current, message: Drive, signal: Iq}", f"{{kind: current, message: {message}, signal: {signal}}}")
        [p] = problems(tmp_path, config)
        first = "Temp_Stator" if signal == "Temp_Rotor" else signal
        assert p.startswith(f"{tmp_path / 'c.yaml'}:5: sources.drive.signal: found {signal!r}, which the DBC gets "
                            f"wrong ({path}:{line_of(text, first)}: "
                            + words.format(dbc=path, rotor=line_of(text, "Temp_Rotor")))

    def test_frame_setting_a_broken_signal(self, tmp_path: Path) -> None:
        """A task frame that sets a signal past its message's end is refused at that signal."""
        config = CONFIG.replace("Enable: \"On\"", "Reserved: 1")
        [p] = problems(tmp_path, config)
        assert "task.frames[0].signals.Reserved: found 'Reserved', which the DBC gets wrong" in p

    def test_frame_leaving_a_broken_signal_at_a_value_it_cannot_send(self, tmp_path: Path) -> None:
        """A frame leaving out a broken signal whose initial value is not 0 is refused; at 0 it is sent."""
        config = CONFIG
        cfg = load_config_text(config, vendor_dbc(tmp_path)[0].parent / "c.yaml")
        msg = sound_db().get_message_by_name("Command")
        assert cfg.task.frames[0].data == msg.encode({"Torque_Cmd": -12.5, "Enable": 1})
        [p] = problems(tmp_path, config, 'BA_ "GenSigStartValue" SG_ 1715 Reserved 7;\n')
        assert "found Command, whose signal Reserved the frame would send at its initial value 7" in p

    def test_frame_of_a_message_with_two_signals_of_one_name(self, tmp_path: Path) -> None:
        """A frame of Cells that sets Cell_High loads; its payload is cantools' (both Spare at their initial 3)."""
        extra = 'BA_ "GenSigStartValue" SG_ 1713 Spare 3;\n'
        _, text = vendor_dbc(tmp_path, extra)
        task = 'task: {frames: [{message: Command, signals: {Torque_Cmd: -12.5, Enable: "On"}}]}'
        cfg = load_config_text(CONFIG.replace(task, "task: {frames: [{message: Cells, signals: {Cell_High: 3.3}}]}"),
                               tmp_path / "c.yaml")
        pseudo = text.index("BO_ 3221225472")
        plain = text[:pseudo] + text[text.index("CM_ SG_"):].replace('VAL_ 3221225472 Unplaced 0 "Off" 1 "On" ;', "")
        cells = cantools.database.load_string(plain, database_format="dbc", strict=False).get_message_by_name("Cells")
        assert cfg.task.frames[0].data == cells.encode({"Spare": 3, "Cell_High": 3.3, "Cell_Low": 0})
        assert cfg.task.frames[0].data[0] == cfg.task.frames[0].data[3] == 3
        [p] = problems(tmp_path, CONFIG.replace(task, "task: {frames: [{message: Cells, signals: {Spare: 1}}]}"))
        assert "task.frames[0].signals.Spare: found 'Spare', which the DBC gets wrong" in p


class TestDecodes:
    """The sound signals of the file decode as cantools decodes them from a file without the others."""

    def test_check_then_replay(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """check counts the notes (-v lists them); replay's exported samples equal cantools' values."""
        vendor_dbc(tmp_path)
        config = tmp_path / "c.yaml"
        config.write_text(CONFIG, encoding="utf-8")
        code, out, err = cli(capsys, "check", "-c", config)
        assert code == 0, err
        head = "  6 DBC notes (parts skipped or signals taken out, none read by this config"
        assert f"{head}; check -v lists them)\n" in out
        code, verbose, _ = cli(capsys, "check", "-v", "-c", config)
        lines = verbose.splitlines()
        at = lines.index(f"{head}):")
        assert code == 0 and all(line.startswith(f"    {tmp_path / 'vendor.dbc'}:") for line in lines[at + 1:at + 7])
        assert lines[at + 7] == "buses:"

        db = sound_db()
        rnd = random.Random(45)
        lines, want = [], []
        for k in range(40):
            name = ("Pack", "Cells", "Drive", "Phases")[k % 4]
            msg = db.get_message_by_name(name)
            data = bytearray(rnd.randbytes(8))
            if name == "Phases":
                data[0] = k // 4 % 2
            lines.append(f"({k / 100:.6f}) vcan0 {msg.frame_id:03X}#{bytes(data).hex().upper()}")
            want.append((k / 100, msg.decode(bytes(data), decode_choices=False)))
        log = tmp_path / "vendor.log"
        log.write_text("\n".join(lines) + "\n", encoding="ascii")
        out_file = tmp_path / "samples.parquet"
        code, out, err = cli(capsys, "replay", log, "-c", config, "--json", "--export-signals", out_file)
        assert code == 0, err
        summary = json.loads(out)
        assert (summary["frames"]["decoded"], summary["frames"]["invalid"]) == (40, 0)
        got = {(r["t"], r["source"], r["signal"]): r["value"] for r in pq.read_table(out_file).to_pylist()}
        reads = {("pack", "current"): "Pack_Current", ("drive", "current"): "Iq", ("other", "id"): "Id",
                 ("other", "cell"): "Cell_High", ("other", "phase_b"): "Phase_B", ("other", "phase_c"): "Phase_C"}
        expected = {(t, src, role): float(values[sig]) for t, values in want
                    for (src, role), sig in reads.items() if sig in values}
        assert {k: v for k, v in got.items() if k[2] != "present"} == expected
