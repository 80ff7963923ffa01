"""Start-up: a config is parsed once, by libyaml when PyYAML has it, with the pure-Python loader's results.

Every config the project ships loads to the same document through both loaders; a YAML error
is the pure-Python loader's own message; the line numbers of problems are worked out only
when there is a problem.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

import canguard.config.yamlsrc as yamlsrc
from canguard.config.loader import load_config, load_config_text
from canguard.errors import ConfigError
from checkout import REPO

CONFIGS = sorted(p for p in (REPO / "config").rglob("*.yaml")) + sorted((REPO / "tests" / "data").glob("*.yaml"))


@pytest.mark.parametrize("path", CONFIGS, ids=[p.name for p in CONFIGS])
def test_both_loaders_read_the_same_document(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    assert yamlsrc.load_yaml(text) == yaml.load(text, Loader=yamlsrc._UniqueKeyLoader)


@pytest.mark.skipif(not getattr(yaml, "__with_libyaml__", False), reason="PyYAML without libyaml")
def test_libyaml_is_used_when_there() -> None:
    assert issubclass(yamlsrc._LOADERS[0], yaml.CSafeLoader)


@pytest.mark.parametrize("text", [
    "a: 1\na: 2\n",                      # duplicate key (the loader's own check)
    "a: [1, 2\nb: 3\n",                  # unclosed flow sequence
    "a: b: c\n",                         # mapping values not allowed here
    "a:\n  - 1\n - 2\n",                 # bad indentation
    "--- 1\n--- 2\n",                    # two documents
    "a: !!python/object:os.system x\n",  # not a safe tag
])
def test_a_yaml_error_is_the_pure_python_loaders(text: str) -> None:
    with pytest.raises(yaml.YAMLError) as pure:
        yaml.load(text, Loader=yamlsrc._UniqueKeyLoader)
    with pytest.raises(yaml.YAMLError) as used:
        yamlsrc.load_yaml(text)
    assert str(used.value) == str(pure.value)


def test_a_valid_config_is_not_parsed_again_for_line_numbers(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    real = yamlsrc.key_lines

    def counting(text: str) -> dict[str, int]:
        calls.append(text)
        return real(text)

    monkeypatch.setattr(yamlsrc, "key_lines", counting)
    load_config(REPO / "config" / "canguard.yaml")
    assert calls == []
    text = (REPO / "config" / "canguard.yaml").read_text(encoding="utf-8").replace("max_age: 0.5", "max_age: -1")
    with pytest.raises(ConfigError) as err:
        load_config_text(text, REPO / "config" / "canguard.yaml")
    assert len(calls) == 1
    line = 1 + next(i for i, ln in enumerate(text.splitlines()) if "max_age: -1" in ln)
    assert any(f"canguard.yaml:{line}: sources./battery_state.max_age" in p for p in err.value.located)
