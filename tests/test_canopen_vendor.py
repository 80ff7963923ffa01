"""CANopen EDS files as vendors publish them: read as published, refused with file:line, ``init`` on each.

The files in tests/data/canopen/ were written for these tests, each with what published
vendor files do:

- vendor_defaults.eds: a CiA 402 drive at its factory defaults: TPDO1 sends position
  only, TPDO2-4 are disabled (COB-ID bit 31; TPDO4 without a COB-ID of its own), TPDO2
  and TPDO4 map nothing, 0x1017 heartbeat 0, a record (0x2100), a PDOMapping=0 object
  (0x6502), a string (0x1008), a ``[Comments]`` section written ``Lines1=`` and a key
  CiA 306 does not define (``VendorRemark`` in [6077]);
- commissioned.dcf: a DCF whose ParameterValues (over the DefaultValues) make TPDO1 valid
  with an INT32 0x6077 and give the heartbeat, with COB-IDs written for node 32;
- io_module.eds: a CiA 401 digital I/O module.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from canguard.cli.check import describe
from canguard.cli.main import main
from canguard.config.loader import load_config
from canguard.errors import ConfigError
from canguard.protect.staleness import SourceHealth
from test_canopen_config import TREE

DATA = Path(__file__).resolve().parent / "data" / "canopen"
VENDOR = DATA / "vendor_defaults.eds"
DCF = DATA / "commissioned.dcf"
IO_MODULE = DATA / "io_module.eds"


def config(tmp: Path, eds: Path = VENDOR, drive: dict[str, Any] | None = None,
           source: dict[str, Any] | None = None) -> Path:
    """Drive ``left`` (node 5) of ``eds`` with TPDO2 mapping the statusword and 0x6077, source ``left_torque``."""
    (tmp / "tree.xml").write_text(TREE, encoding="utf-8")
    entry = {"eds": str(eds), "node": 5, "heartbeat": 0.1, "pdo": {"TPDO2": ["0x6041", "0x6077"]}, **(drive or {})}
    doc = {
        "buses": {"main": {"interface": "virtual", "channel": "can0"}},
        "canopen": {"left": {k: v for k, v in entry.items() if v is not None}},
        "sources": {"left_torque": {"kind": "current", "canopen": "left", "object": "0x6077", **(source or {})}},
        "tree": {"file": "tree.xml", "tick_hz": 100},
        "stop": {"repeat": 0.05, "frames": [{"canopen": "left", "command": "quick_stop"}]},
    }
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def edited(tmp: Path, replace: dict[str, str], name: str = "edited.eds", src: Path = VENDOR) -> Path:
    """A copy of ``src`` with each text of ``replace`` replaced (each must occur)."""
    text = src.read_text(encoding="utf-8")
    for old, new in replace.items():
        assert old in text, old
        text = text.replace(old, new)
    out = tmp / name
    out.write_text(text, encoding="utf-8")
    return out


def line_of(path: Path, section: str) -> int:
    """The line of ``[section]`` in ``path``."""
    return path.read_text(encoding="utf-8").splitlines().index(f"[{section}]") + 1


class TestReading:
    """A vendor file loads as published; what is not part of the dictionary is tolerated and named."""

    def test_deviations_outside_the_dictionary_are_tolerated_and_named_in_check_v(self, tmp_path: Path) -> None:
        """``Lines1=`` comments, an undefined key, a key written twice load; ``check -v`` names each with its line."""
        cfg = load_config(config(tmp_path))
        verbose = describe(cfg, verbose=True)
        comments = line_of(VENDOR, "Comments")
        assert f"vendor_defaults.eds:{comments} [Comments]: found Lines=, Lines1=, Lines2=" in verbose
        remark = VENDOR.read_text(encoding="utf-8").splitlines().index("VendorRemark=per mille of the rated torque")
        assert f"vendor_defaults.eds:{remark + 1} [6077]: keys CiA 306 does not define: VendorRemark" in verbose
        assert "[Comments]" not in describe(cfg)
        twice = edited(tmp_path, {"ProductName=Bench servo (factory defaults)\n":
                                  "ProductName=Bench servo (factory defaults)\nProductName=Bench servo, again\n"})
        again = load_config(config(tmp_path, twice))
        assert again.canopen["left"].device.endswith("(factory defaults)")
        assert f"edited.eds:{line_of(twice, 'DeviceInfo') + 4} [DeviceInfo]: a key written a second time" in \
            describe(again, verbose=True)

    def test_a_broken_object_entry_is_an_error_naming_its_section_and_line(self, tmp_path: Path) -> None:
        """An object section without its DataType is still an error, at the section's line."""
        broken = edited(tmp_path, {"ParameterName=Torque actual value\nObjectType=0x7\nDataType=0x0003\n":
                                   "ParameterName=Torque actual value\nObjectType=0x7\n"})
        with pytest.raises(ConfigError, match=rf"edited\.eds:{line_of(broken, '6077')} \[6077\]: does not load"):
            load_config(config(tmp_path, broken))

    @pytest.mark.parametrize(("obj", "why"), [
        ("0x2100", r"\[2100\] Current actual values is a record: name one of its sub-indices "
                   r"\(0x2100:01 Current actual value averaged, 0x2100:02"),
        ("0x6502", r"\[6502\] Supported drive modes has PDOMapping=0"),
        ("0x1008", r"\[1008\] Manufacturer device name is a string or domain"),
    ])
    def test_what_cannot_be_a_pdo_value_is_refused_with_file_and_line(self, tmp_path: Path, obj: str,
                                                                       why: str) -> None:
        """A record without a sub-index, a PDOMapping=0 object and a string are refused in ``pdo:``."""
        line = line_of(VENDOR, obj[2:])
        with pytest.raises(ConfigError, match=rf"canopen\.left\.pdo\.TPDO2: found vendor_defaults\.eds:{line} {why}"):
            load_config(config(tmp_path, drive={"pdo": {"TPDO2": ["0x6041", obj]}}))

    def test_a_record_sub_index_is_a_pdo_value_and_a_whole_record_is_no_source(self, tmp_path: Path) -> None:
        """``0x2100:01`` maps (INT32 at bits 16..47); a source reading ``0x2100`` is told to name a sub-index."""
        cfg = load_config(config(tmp_path, drive={"pdo": {"TPDO2": ["0x6041", "0x2100:01"]}},
                                 source={"object": "0x2100:01"}))
        ref = cfg.sources["left_torque"].signal("current")
        assert ref is not None and ref.frame_id == 0x285
        with pytest.raises(ConfigError, match=r"sources\.left_torque\.object: found '0x2100', expected a variable, "
                                              r"not a whole object: .*is a record"):
            load_config(config(tmp_path, drive={"pdo": {"TPDO2": ["0x6041", "0x2100:01"]}},
                               source={"object": "0x2100"}))

    def test_a_disabled_tpdo_is_named_by_pdo_and_the_unmapped_error_says_so(self, tmp_path: Path) -> None:
        """TPDO4 (bit 31 and no COB-ID) gets the predefined 0x480 + node; without pdo: the error names TPDO2-4."""
        cfg = load_config(config(tmp_path, drive={"pdo": {"TPDO4": ["0x6077"]}}))
        ref = cfg.sources["left_torque"].signal("current")
        assert ref is not None and ref.frame_id == 0x485
        with pytest.raises(ConfigError) as err:
            load_config(config(tmp_path, drive={"pdo": None}))
        assert "TPDO1: 0x6041, 0x6064; TPDO2, TPDO3, TPDO4 disabled in the EDS: map it there with " \
               "canopen.left.pdo" in str(err.value)

    def test_a_dcf_parameter_value_wins_and_another_nodes_cob_id_is_named(self, tmp_path: Path) -> None:
        """TPDO1 is valid at 0x1A0 with an INT32 0x6077, heartbeat 50 ms; node 32's COB-IDs are noted for node 5."""
        cfg = load_config(config(tmp_path, DCF, drive={"pdo": None, "heartbeat": None}))
        ref = cfg.sources["left_torque"].signal("current")
        assert ref is not None and ref.frame_id == 0x1A0
        msg = cfg.database.get_message_by_frame_id(0x1A0)
        assert msg.decode(bytes([0x27, 0, 0x18, 0xFC, 0xFF, 0xFF]))[ref.signal] == -1000
        assert cfg.canopen["left"].heartbeat_s == pytest.approx(0.05)
        text = describe(cfg, verbose=True)
        assert f"commissioned.dcf:{line_of(DCF, '1800sub1')} [1800sub1] ParameterValue=0x000001A0: COB-ID 0x1A0 is " \
               "node 32's (0x180 + 32), not node 5's (0x180 + 5 = 0x185)" in text


class TestOneErrorPerCause:
    """A drive entry with a problem is reported once, not again by every source and frame that uses it."""

    @pytest.mark.parametrize(("drive", "cause"), [
        ({"heartbeat": None}, r"canopen\.left\.heartbeat: found nothing \(the EDS's 0x1017 producer heartbeat time "
                              r"is 0: the drive sends no heartbeat by default\)"),
        ({"eds": "missing.eds"}, r"canopen\.left\.eds"),
        ({"tpdo_period": 0.02}, r"canopen\.left\.tpdo_period: found 0\.02 without configure: true"),
    ])
    def test_a_broken_drive_is_one_error(self, tmp_path: Path, drive: dict[str, Any], cause: str) -> None:
        """The drive's own key is the only problem; its source and stop frame add none."""
        with pytest.raises(ConfigError, match=cause) as err:
            load_config(config(tmp_path, drive=drive))
        assert len(err.value.problems) == 1, err.value.problems

    def test_max_age_is_the_values_own_and_the_heartbeat_keeps_its_timeout(self, tmp_path: Path) -> None:
        """max_age 0.5 beside a 0.1 s heartbeat: a TPDO every 0.25 s is fresh; 0.2 s without heartbeat is not."""
        cfg = load_config(config(tmp_path, source={"max_age": 0.5}))
        health = SourceHealth(cfg.sources["left_torque"])
        for k in range(4):
            health.advance(("nmt",), (0.1 * k,), ((5.0,),))
        for t in (0.0, 0.25):
            health.advance(("current",), (t,), ((10.0,),))
            health.advance(("fault",), (t,), ((0.0,),))
        assert health.reason(0.3) == ""
        assert health.reason(0.46) == "no_heartbeat"  # 0.16 s after the last heartbeat: past 1.5 x 0.1 s
        assert health.reason(0.46, "current") == "no_heartbeat"


class TestInit:
    """``canguard init --canopen`` on each kind of vendor file: written, checked, told."""

    def init(self, tmp: Path, eds: Path, capsys: pytest.CaptureFixture[str], *more: str) -> tuple[Path, str]:
        target = tmp / "drive"
        assert main(["init", str(target), "--canopen", str(eds), "--simulation", *more]) == 0
        return target / "canguard.yaml", capsys.readouterr().err

    def test_disabled_tpdos_get_a_pdo_override_and_the_drive_is_told_what_it_needs(
        self, tmp_path: Path, capsys: pytest.CaptureFixture[str]
    ) -> None:
        """No TPDO maps 0x6077/0x6078: TPDO2 (disabled) carries them; its mapping, COB-ID and 0x1017 are told."""
        path, err = self.init(tmp_path, VENDOR, capsys, "--node", "5")
        cfg = load_config(path)
        assert [o.ref for o in cfg.canopen["drive"].tpdos[1].objects] == ["0x6041", "0x6077", "0x6078"]
        assert {cfg.sources[s].signal("current").frame_id for s in cfg.sources} == {0x285}  # type: ignore[union-attr]
        told = ["0x1017:00 = 0x0064 (producer heartbeat every 100 ms)",
                "0x1A01:02 = 0x60770010 (TPDO2 entry 2: 0x6077 Torque actual value)",
                "0x1801:01 = 0x40000285 (TPDO2 COB-ID 0x285, valid (bit 31 cleared))"]
        text = path.read_text(encoding="utf-8")
        for line in told:
            assert f"#   {line}" in text and f"  {line}" in err
        assert "TPDO2 0x285 carries 0x6041 Statusword, 0x6077 Torque actual value, 0x6078 Current actual value" in err
        assert main(["check", "-c", str(path)]) == 0
        assert "-> drive_TPDO2 id 0x285" in capsys.readouterr().out

    def test_an_int32_torque_fills_the_frame_and_configure_is_written(
        self, tmp_path: Path, capsys: pytest.CaptureFixture[str]
    ) -> None:
        """An INT32 0x6077 beside the statusword and 0x6078 takes all 64 bits; --configure writes configure: true."""
        eds = edited(tmp_path, {"ParameterName=Torque actual value\nObjectType=0x7\nDataType=0x0003":
                                "ParameterName=Torque actual value\nObjectType=0x7\nDataType=0x0004"})
        path, err = self.init(tmp_path, eds, capsys, "--node", "5", "--configure")
        drive = load_config(path).canopen["drive"]
        assert [(o.ref, o.start_bit, o.bits) for o in drive.tpdos[1].objects] == [
            ("0x6041", 0, 16), ("0x6077", 16, 32), ("0x6078", 48, 16)]
        assert drive.configure and "configure: true: canguard tells the drive over SDO" in err

    def test_a_tpdo_whose_mapping_is_fixed_is_passed_over(self, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
        """TPDO2's mapping count read-only in the EDS: the next disabled TPDO, TPDO3 (0x385), carries the values."""
        eds = edited(tmp_path, {"[1A01sub0]\nParameterName=Number of mapped objects\nObjectType=0x7\n"
                                "DataType=0x0005\nAccessType=rw": "[1A01sub0]\nParameterName=Number of mapped "
                                "objects\nObjectType=0x7\nDataType=0x0005\nAccessType=ro"})
        path, err = self.init(tmp_path, eds, capsys, "--node", "5")
        assert "TPDO3 0x385 carries 0x6041 Statusword, 0x6077" in err
        assert {s.signal("current").frame_id for s in load_config(path).sources.values()} == {0x385}  # type: ignore[union-attr]

    def test_a_dcf_with_another_nodes_cob_ids_is_warned_of(self, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
        """TPDO1 maps 0x6077 already: no override; COB-IDs of node 32 are warned of for node 5, not for node 32."""
        path, err = self.init(tmp_path, DCF, capsys, "--node", "5")
        assert "pdo:" not in path.read_text(encoding="utf-8")
        assert "warning: commissioned.dcf:" in err and "COB-ID 0x1A0 is node 32's" in err
        shutil.rmtree(tmp_path / "drive")
        _, err = self.init(tmp_path, DCF, capsys, "--node", "32")
        assert "warning" not in err

    @pytest.mark.parametrize(("eds", "edit", "message"), [
        (IO_MODULE, {}, r"io_module\.eds:\d+ \[1000\] device type 0x000F0191: this is a CiA 401 \(generic I/O "
                        r"module\) device, not a drive"),
        (VENDOR, {"[6077]": "[5077]", "[6078]": "[5078]"},
         r"found neither 0x6077 \(torque actual value\) nor 0x6078 \(current actual value\)"),
        (VENDOR, {"ParameterName=Torque actual value\nObjectType=0x7\nDataType=0x0003\nAccessType=ro\n"
                  "DefaultValue=0\nPDOMapping=1": "ParameterName=Torque actual value\nObjectType=0x7\n"
                  "DataType=0x0003\nAccessType=ro\nDefaultValue=0\nPDOMapping=0",
                  "ParameterName=Current actual value\nObjectType=0x7\nDataType=0x0003\nAccessType=ro\n"
                  "DefaultValue=0\nPDOMapping=1": "ParameterName=Current actual value\nObjectType=0x7\n"
                  "DataType=0x0003\nAccessType=ro\nDefaultValue=0\nPDOMapping=0"},
         r"\[6077\] Torque actual value has PDOMapping=0.*\[6078\] Current actual value has PDOMapping=0"),
    ])
    def test_what_is_no_drive_is_refused_and_nothing_is_written(
        self, tmp_path: Path, capsys: pytest.CaptureFixture[str], eds: Path, edit: dict[str, str], message: str
    ) -> None:
        """A CiA 401 module, a dictionary without 0x6077/0x6078, or neither mappable: exit 2, no directory."""
        source = edited(tmp_path, edit, src=eds) if edit else eds
        assert main(["init", str(tmp_path / "d"), "--canopen", str(source), "--node", "5"]) == 2
        assert capsys.readouterr().err and not (tmp_path / "d").exists()
        with pytest.raises(ConfigError, match=message):
            from canguard.cli.init import drive_files

            drive_files(source, 5, bus="can0", state_dir=tmp_path, simulation=True)

    def test_a_written_config_that_does_not_load_leaves_nothing_behind(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
    ) -> None:
        """Should what init wrote not load, the error is shown and the files and the directory it made are gone."""
        import canguard.config.loader

        def refuse(path: Path) -> None:
            raise ConfigError(f"{path}: refused")

        monkeypatch.setattr(canguard.config.loader, "load_config", refuse)
        assert main(["init", str(tmp_path / "d"), "--canopen", str(VENDOR), "--node", "5"]) == 2
        assert "canguard.yaml: refused" in capsys.readouterr().err
        assert not (tmp_path / "d").exists()

    @pytest.mark.slow
    def test_any_file_name_round_trips_through_the_installed_cli(self, tmp_path: Path) -> None:
        """``canguard init`` (the console script) quotes an EDS named with brackets, a comma and spaces."""
        eds = tmp_path / "iPOS [rev B], v2 #1.eds"
        shutil.copyfile(VENDOR, eds)
        target = tmp_path / "out dir"
        done = subprocess.run([sys.executable, "-m", "canguard", "init", str(target), "--canopen", str(eds),
                               "--node", "7", "--simulation"], capture_output=True, text=True, cwd=tmp_path)
        assert done.returncode == 0, done.stderr
        cfg = load_config(target / "canguard.yaml")
        assert cfg.canopen["drive"].eds == target / eds.name
        assert cfg.events == target / "events.jsonl"
