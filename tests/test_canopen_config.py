"""``canopen:`` drives: the EDS translated at load time, and the drive's health on a manual clock.

The EDS is tests/data/canopen/cia402_drive.eds (a CiA 402 servo drive written for these
tests): TPDO1 0x180+node (statusword, mode display), TPDO2 0x280+node (statusword,
torque and current actual values), TPDO3 disabled by default (position actual value),
RPDO1 0x200+node (controlword, modes of operation = 4), heartbeat 100 ms.
"""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from canguard.cli.check import describe
from canguard.config.loader import load_config
from canguard.engine.core import Engine
from canguard.engine.gate import LogSink, TaskGate
from canguard.errors import ConfigError
from canguard.io.block import one_block
from canguard.io.clock import ManualClock
from canguard.io.frame import Frame
from checkout import REPO

EDS = Path(__file__).resolve().parent / "data" / "canopen" / "cia402_drive.eds"
T0 = 1_700_000_000.0
NODE = 2
TREE = """<root BTCPP_format="4" main_tree_to_execute="Drive">
  <BehaviorTree ID="Drive">
    <ReactiveSequence>
      <IsCurrentSafe topic_name="left_torque" overcurrent_threshold="35.0" recovery_threshold="25.0"/>
      <ExecuteTask/>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""


def config(tmp: Path, drive: dict[str, Any] | None = None, source: dict[str, Any] | None = None, **top: Any) -> Path:
    """A config with drive ``left`` (node 2) and source ``left_torque`` (0x6077, scale 0.1), no DBC."""
    (tmp / "tree.xml").write_text(TREE, encoding="utf-8")
    doc: dict[str, Any] = {
        "buses": {"main": {"interface": "virtual", "channel": "can0"}},
        "canopen": {"left": {"eds": str(EDS), "node": NODE, "bus": "main", **(drive or {})}},
        "sources": {
            "left_torque": {"kind": "current", "canopen": "left", "object": "0x6077", "scale": 0.1, **(source or {})}
        },
        "tree": {"file": "tree.xml", "tick_hz": 100},
        "task": {"period": 0.02, "frames": [{"canopen": "left", "command": "enable_operation"}]},
        "stop": {"repeat": 0.05, "frames": [{"canopen": "left", "command": "quick_stop"}]},
        "events": str(tmp / "events.jsonl"),
    }
    doc.update(top)
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


class TestTranslation:
    """The EDS's PDO mapping, heartbeat and EMCY become messages; commands become frames."""

    def test_object_is_read_from_the_tpdo_that_maps_it(self, tmp_path: Path) -> None:
        """0x6077 sits in TPDO2 (COB-ID 0x282) at bits 16..31; the statusword's Fault bit comes from the same frame."""
        cfg = load_config(config(tmp_path))
        src = cfg.sources["left_torque"]
        current, fault = src.signal("current"), src.signal("fault")
        assert current is not None and fault is not None
        assert (current.frame_id, fault.frame_id) == (0x282, 0x282)
        msg = cfg.database.get_message_by_frame_id(0x282)
        assert msg.decode(struct.pack("<Hhh", 0x27, -123, 0))[current.signal] == pytest.approx(-12.3)
        assert src.value_roles == ("current",)
        assert src.max_age_s == pytest.approx(0.15)  # 1.5 x the EDS's 100 ms producer heartbeat

    @pytest.mark.parametrize("obj", ["Torque actual value", "0x6077:0", "6077", 0x6077])
    def test_object_by_name_or_hex(self, tmp_path: Path, obj: Any) -> None:
        """``object`` is a ParameterName, ``INDEX:SUB``, bare hex or a YAML number."""
        cfg = load_config(config(tmp_path, source={"object": obj}))
        ref = cfg.sources["left_torque"].signal("current")
        assert ref is not None and ref.frame_id == 0x282

    def test_unmapped_object_names_the_tpdos_and_what_they_map(self, tmp_path: Path) -> None:
        """0x6064 is mapped only by TPDO3, which the EDS leaves invalid: the error lists what is mapped."""
        with pytest.raises(ConfigError) as err:
            load_config(config(tmp_path, source={"object": "0x6064"}))
        text = str(err.value)
        assert "sources.left_torque.object" in text
        assert "TPDO1: 0x6041, 0x6061" in text and "TPDO2: 0x6041, 0x6077, 0x6078" in text

    def test_pdo_override_replaces_a_tpdo_mapping(self, tmp_path: Path) -> None:
        """``pdo: {TPDO1: [...]}`` maps the listed objects in order, sized by their EDS data types."""
        cfg = load_config(config(tmp_path, drive={"pdo": {"TPDO1": ["0x6078", "Torque actual value"]}}))
        ref = cfg.sources["left_torque"].signal("current")
        assert ref is not None and ref.frame_id == 0x182
        msg = cfg.database.get_message_by_frame_id(0x182)
        assert msg.decode(struct.pack("<hh", 7, 250))[ref.signal] == pytest.approx(25.0)

    def test_an_object_mapped_but_not_described_is_an_error_only_when_read(self, tmp_path: Path) -> None:
        """An EDS whose TPDO2 maps 0x6078 without describing it still serves 0x6077; reading 0x6078 is an error."""
        text = EDS.read_text(encoding="utf-8")
        start = text.index("[6078]")
        partial = tmp_path / "partial.eds"
        end = text.find("\n[", start)
        partial.write_text(text[:start] + (text[end + 1 :] if end >= 0 else ""), encoding="utf-8")
        cfg = load_config(config(tmp_path, drive={"eds": str(partial)}))
        assert cfg.sources["left_torque"].signal("current") is not None
        with pytest.raises(ConfigError, match=r"0x6078, which TPDO2 maps but partial\.eds does not describe"):
            load_config(config(tmp_path, drive={"eds": str(partial)}, source={"object": "0x6078"}))

    def test_a_dummy_mapping_entry_takes_its_bits(self, tmp_path: Path) -> None:
        """A dummy entry (a data type index, here UNSIGNED8) in a TPDO mapping shifts the objects after it."""
        text = EDS.read_text(encoding="utf-8")
        at = text.index("DefaultValue=0x60410010", text.index("[1A01sub1]"))
        dummy = tmp_path / "dummy.eds"
        dummy.write_text(text[:at] + "DefaultValue=0x00050008" + text[at + len("DefaultValue=0x60410010") :],
                         encoding="utf-8")
        cfg = load_config(config(tmp_path, drive={"eds": str(dummy)}))
        ref = cfg.sources["left_torque"].signal("current")
        assert ref is not None and ref.frame_id == 0x282
        payload = bytes([0xAA]) + struct.pack("<hh", 250, 0)
        assert cfg.database.get_message_by_frame_id(0x282).decode(payload)[ref.signal] == pytest.approx(25.0)

    def test_a_dcf_parameter_value_overrides_the_eds_default(self, tmp_path: Path) -> None:
        """A DCF whose ParameterValue makes TPDO3 valid: the position actual value (0x6064) is then readable."""
        text = EDS.read_text(encoding="utf-8")
        head = text.index("[1802sub1]")
        line = text.index("DefaultValue=$NODEID+0x80000380", head)
        dcf = tmp_path / "drive.dcf"
        dcf.write_text(text[:line] + "ParameterValue=$NODEID+0x380\n" + text[line:], encoding="utf-8")
        cfg = load_config(config(tmp_path, drive={"eds": str(dcf)}, source={"object": "0x6064"}))
        ref = cfg.sources["left_torque"].signal("current")
        assert ref is not None and ref.frame_id == 0x382

    def test_command_and_nmt_frames(self, tmp_path: Path) -> None:
        """quick_stop / enable_operation: the controlword in RPDO1, modes of operation at its EDS value; NMT stop."""
        path = config(
            tmp_path,
            stop={"frames": [{"canopen": "left", "command": "quick_stop"}, {"canopen": "left", "nmt": "stop"}]},
        )
        cfg = load_config(path)
        quick, nmt = cfg.stop.frames
        [enable] = cfg.task.frames
        assert (quick.arbitration_id, quick.data) == (0x202, bytes([0x02, 0x00, 0x04]))
        assert (enable.arbitration_id, enable.data) == (0x202, bytes([0x0F, 0x00, 0x04]))
        assert (nmt.arbitration_id, nmt.data) == (0x000, bytes([0x02, NODE]))

    def test_check_shows_each_drive(self, tmp_path: Path) -> None:
        """``canguard check`` lists the drive's COB-IDs, mapped objects, heartbeat and EMCY ids."""
        text = describe(load_config(config(tmp_path)))
        assert "left: node 2 on main" in text
        assert "heartbeat 0x702 every 0.1 s (timeout 0.15 s), EMCY 0x082" in text
        assert "TPDO2 0x282: 0x6041 Statusword [bits 0..15], 0x6077 Torque actual value [bits 16..31]" in text
        assert "RPDO1 0x202: 0x6040 Controlword" in text

    @pytest.mark.parametrize(
        ("drive", "source", "key"),
        [
            ({"node": 0}, {}, "canopen.left.node"),
            ({"eds": "missing.eds"}, {}, "canopen.left.eds"),
            ({"pdo": {"TPDO9": ["0x6077"]}}, {}, "canopen.left.pdo.TPDO9"),
            ({}, {"canopen": "right"}, "sources.left_torque.canopen"),
            ({}, {"max_age": -1}, "sources.left_torque.max_age"),
            ({}, {"scale": float("nan")}, "sources.left_torque.scale"),
        ],
    )
    def test_bad_input_names_the_key(
        self, tmp_path: Path, drive: dict[str, Any], source: dict[str, Any], key: str
    ) -> None:
        """Each mistake is reported with the key at fault."""
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            load_config(config(tmp_path, drive=drive, source=source))

    def test_a_drive_without_eds_and_a_list_for_a_drive_name_are_errors(self, tmp_path: Path) -> None:
        """A drive entry with no ``eds:`` and a source whose ``canopen:`` is a list: errors naming each key."""
        path = config(tmp_path, source={"canopen": ["left"]})
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        doc["canopen"]["right"] = {"node": 3}
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        with pytest.raises(ConfigError) as err:
            load_config(path)
        text = str(err.value)
        assert "canopen.right.eds: found nothing, expected a value (required key)" in text
        assert "sources.left_torque.canopen: found a list, expected a drive of canopen:" in text

    def test_dbc_messages_and_a_drive_mix_on_one_bus(self, tmp_path: Path) -> None:
        """With a DBC too, its sources and the drive's load side by side in one database."""
        dbc = REPO / "dbc" / "robot.dbc"
        path = config(tmp_path, dbc=[str(dbc)])
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        doc["sources"]["axis3"] = {"kind": "current", "message": "Axis3_Get_Iq", "signal": "Iq_Measured"}
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        cfg = load_config(path)
        names = {m.name for m in cfg.database.messages}
        assert {"Axis3_Get_Iq", "left_TPDO2", "left_heartbeat", "left_emcy"} <= names
        assert cfg.sources["axis3"].bus == cfg.sources["left_torque"].bus == "main"

    def test_two_drives_on_one_node_id_clash(self, tmp_path: Path) -> None:
        """Two drives with the same node id on one bus send on the same COB-IDs: an error naming them."""
        path = config(tmp_path)
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        doc["canopen"]["right"] = dict(doc["canopen"]["left"])
        doc["sources"]["right_torque"] = {**doc["sources"]["left_torque"], "canopen": "right"}
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        with pytest.raises(ConfigError, match=r"COB-ID 0x282 of right_TPDO2 also message 'left_TPDO2'"):
            load_config(path)

    def test_canopen_is_not_imported_without_a_drive(self, tmp_path: Path) -> None:
        """Loading a config with no ``canopen:`` section never imports the canopen library."""
        repo = REPO
        code = (
            "import sys\nfrom canguard.config.loader import load_config\n"
            f"load_config({str(repo / 'config' / 'canguard.yaml')!r})\n"
            "print('canopen' in sys.modules)\n"
        )
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=tmp_path)
        assert out.stdout.strip() == "False"


class Drive:
    """An engine on a manual clock fed the frames a drive would send."""

    def __init__(self, tmp: Path) -> None:
        self.cfg = load_config(config(tmp, drive={"heartbeat": 0.1}))
        self.clock = ManualClock(T0)
        self.sink = LogSink(self.clock.now, self.cfg.buses)
        self.events: list[dict[str, Any]] = []
        self.engine = Engine(self.cfg, self.clock, self.sink, events=self)
        self.engine.start(T0)
        self.t = T0
        self.status, self.torque, self.nmt = 0x27, 100, 5
        self.health = self.engine.ctx.health["left_torque"]

    def write(self, event: Any) -> None:
        """Keep a journal event."""
        self.events.append(dict(event))

    def flush(self) -> None:
        """Nothing to make durable."""

    def frame(self, cob: int, data: bytes) -> None:
        self.engine.take("main", one_block(Frame(self.t, "can0", cob, data)))

    def run(self, seconds: float, heartbeat: bool = True) -> None:
        """Send TPDO2 every 10 ms and the heartbeat every 100 ms for ``seconds``."""
        end = self.t + seconds
        k = 0
        while self.t < end - 1e-9:
            self.t += 0.01
            k += 1
            self.frame(0x282, struct.pack("<Hhh", self.status, self.torque, 0))
            if heartbeat and k % 10 == 0:
                self.frame(0x702, bytes([self.nmt]))
            self.engine.advance(self.t)
            self.clock.advance_to(self.t)

    def emcy(self, code: int, register: int, data: bytes) -> None:
        self.frame(0x082, struct.pack("<HB", code, register) + data)

    def named(self, name: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e.get("event") == name]

    def up(self) -> None:
        self.frame(0x702, bytes([self.nmt]))
        self.run(0.2)
        assert self.engine.gate.state == TaskGate.RUNNING


class TestDriveHealth:
    """Heartbeat, NMT state, EMCY and the statusword Fault bit gate the drive's sources."""

    def test_missing_heartbeat_makes_the_source_stale_and_stops(self, tmp_path: Path) -> None:
        """No heartbeat within 1.5 x heartbeat: ``no_heartbeat``, the task stops; the heartbeat back clears it."""
        d = Drive(tmp_path)
        d.up()
        last = d.t
        d.run(0.5, heartbeat=False)
        [stale] = [e for e in d.named("stale") if e["reason"] == "no_heartbeat"]
        assert last - 0.1 + 0.15 < stale["t"] <= last + 0.15 + 0.02
        assert d.engine.gate.state == TaskGate.STOPPED
        d.run(0.3)
        assert d.health.reason(d.t) == ""
        assert d.named("fresh")[-1]["reason"] == "no_heartbeat cleared"

    def test_nmt_state_other_than_operational_is_not_present(self, tmp_path: Path) -> None:
        """Heartbeat state pre-operational (0x7F) or stopped (0x04): ``not_present``; each change an ``nmt`` event."""
        d = Drive(tmp_path)
        d.up()
        for state in (0x7F, 0x04):
            d.nmt = state
            d.run(0.2)
            assert d.health.reason(d.t) == "not_present"
            assert d.engine.gate.state == TaskGate.STOPPED
        d.nmt = 5
        d.run(0.2)
        assert d.health.reason(d.t) == ""
        changes = [(e["previous"], e["state"]) for e in d.named("nmt")]
        assert changes == [(None, "operational"), ("operational", "pre_operational"),
                           ("pre_operational", "stopped"), ("stopped", "operational")]

    def test_emcy_fails_the_guard_until_the_error_reset(self, tmp_path: Path) -> None:
        """An EMCY with a non-zero error register: ``emcy`` event and reason; code 0 register 0 clears it."""
        d = Drive(tmp_path)
        d.up()
        d.emcy(0x2310, 0x03, bytes([1, 2, 3, 4, 5]))
        d.run(0.1)
        [event] = d.named("emcy")
        assert (event["code"], event["error_register"], event["manufacturer"]) == ("0x2310", 3, "0102030405")
        assert d.health.reason(d.t) == "emcy"
        assert d.engine.gate.state == TaskGate.STOPPED
        d.run(1.0)
        assert d.health.reason(d.t) == "emcy"  # an EMCY does not wear off with time
        d.emcy(0x0000, 0x00, bytes(5))
        d.run(0.1)
        assert d.health.reason(d.t) == ""
        assert d.named("emcy")[-1]["reset"] is True

    def test_statusword_fault_bit_is_drive_fault(self, tmp_path: Path) -> None:
        """Bit 3 of the statusword (mapped with the torque) makes the source ``drive_fault``."""
        d = Drive(tmp_path)
        d.up()
        d.status = 0x27 | 0x08
        d.run(0.05)
        assert d.health.reason(d.t) == "drive_fault"
        assert d.engine.gate.state == TaskGate.STOPPED
        d.status = 0x27
        d.run(0.05)
        assert d.health.reason(d.t) == ""

    def test_torque_trips_and_sends_the_quick_stop(self, tmp_path: Path) -> None:
        """40 % torque (> 35) trips the guard; the quick stop controlword goes to RPDO1."""
        d = Drive(tmp_path)
        d.up()
        d.torque = 400
        d.run(0.05)
        assert d.named("trip")
        assert [f for f in d.sink.frames if f.arbitration_id == 0x202 and f.data == bytes([2, 0, 4])]


class TestInit:
    """``canguard init DIR --canopen EDS --node N`` writes a config and tree that check cleanly."""

    def test_init_writes_a_drive_config_that_checks(self, tmp_path: Path) -> None:
        """The written config guards the mapped torque and current, with the quick stop as its stop frame."""
        from canguard.cli.main import main

        target = tmp_path / "drive"
        assert main(["init", str(target), "--canopen", str(EDS), "--node", "5", "--simulation"]) == 0
        cfg = load_config(target / "canguard.yaml")
        assert sorted(cfg.sources) == ["drive_current", "drive_torque"]
        assert cfg.canopen["drive"].node == 5
        [quick] = cfg.stop.frames
        assert (quick.arbitration_id, quick.data) == (0x205, bytes([2, 0, 4]))
        assert main(["check", "-c", str(target / "canguard.yaml")]) == 0

    def test_init_without_node_says_so(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """``--canopen`` without ``--node`` is an error naming --node, and writes nothing."""
        from canguard.cli.main import main

        assert main(["init", str(tmp_path / "d"), "--canopen", str(EDS)]) == 2
        assert "--node" in capsys.readouterr().err
        assert not (tmp_path / "d").exists()
