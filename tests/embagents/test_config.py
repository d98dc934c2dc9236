"""Configs: converters and validators, apply_config, YAML/TOML loading, deep copies."""

from __future__ import annotations

import pytest
from attrs import define, field

from embagents.config import (
    BaseComponentConfig,
    ConfigError,
    apply_config,
    config_fields,
    load_configs,
    one_of,
)


@define(kw_only=True)
class Inner:
    gain: float = field(default=1.0, converter=float)


@define(kw_only=True)
class Outer(BaseComponentConfig):
    inner: Inner = field(factory=Inner)
    words: list[str] = field(factory=list)


def test_defaults_and_converters():
    cfg = BaseComponentConfig(loop_rate_hz="2.5", log_level="WARNING", step_timeout_s=1)
    assert (cfg.loop_rate_hz, cfg.log_level, cfg.step_timeout_s, cfg.input_max_age_s) == (2.5, "warning", 1.0, None)


@pytest.mark.parametrize("bad", [{"loop_rate_hz": 0}, {"loop_rate_hz": "fast"}, {"loop_rate_hz": True},
                                 {"step_timeout_s": -1}, {"log_level": "loud"}, {"loop_rate_hz": float("nan")}])
def test_invalid_values_are_refused(bad):
    with pytest.raises(ConfigError):
        BaseComponentConfig(**bad)


def test_assignment_is_validated_too():
    cfg = BaseComponentConfig()
    with pytest.raises(ConfigError):
        cfg.loop_rate_hz = -3
    cfg.loop_rate_hz = "4"
    assert cfg.loop_rate_hz == 4.0


def test_apply_config_returns_a_validated_copy():
    base = Outer(words=["a"])
    new = apply_config(base, {"loop_rate_hz": 3, "inner": {"gain": "2"}})
    assert (new.loop_rate_hz, new.inner.gain) == (3.0, 2.0)
    assert (base.loop_rate_hz, base.inner.gain) == (10.0, 1.0)
    new.words.append("b")
    assert base.words == ["a"]  # no shared mutable state


def test_unknown_key_names_the_key_and_the_valid_ones():
    with pytest.raises(ConfigError) as err:
        apply_config(Outer(), {"loop_rate": 3})
    msg = str(err.value)
    assert "'loop_rate'" in msg and "loop_rate_hz" in msg and "words" in msg and msg.startswith("Outer")
    with pytest.raises(ConfigError, match="unknown config key 'gian'.*valid keys: gain"):
        apply_config(Outer(), {"inner": {"gian": 1}})


def test_invalid_value_names_the_key():
    with pytest.raises(ConfigError, match="invalid value -1 for 'loop_rate_hz'"):
        apply_config(Outer(), {"log_level": "debug", "loop_rate_hz": -1})
    with pytest.raises(ConfigError, match="mapping"):
        apply_config(Outer(), ["loop_rate_hz"])


def test_config_fields():
    assert config_fields(Outer())[-2:] == ["inner", "words"]
    with pytest.raises(TypeError):
        config_fields(dict)


def test_load_yaml_and_toml_give_the_same(tmp_path):
    y = tmp_path / "c.yaml"
    y.write_text("llm:\n  temperature: 0.2\n  chat_history: true\ncamera:\n")
    t = tmp_path / "c.toml"
    t.write_text("[llm]\ntemperature = 0.2\nchat_history = true\n[camera]\n")
    expected = {"llm": {"temperature": 0.2, "chat_history": True}, "camera": {}}
    assert load_configs(y) == expected
    assert load_configs(str(t)) == expected
    (tmp_path / "empty.yml").write_text("")
    assert load_configs(tmp_path / "empty.yml") == {}


def test_loaded_overrides_apply(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("node:\n  loop_rate_hz: 2\n  inner: {gain: 3}\n")
    cfg = apply_config(Outer(), load_configs(path)["node"])
    assert (cfg.loop_rate_hz, cfg.inner.gain) == (2.0, 3.0)


@pytest.mark.parametrize(
    ("name", "text", "match"),
    [("c.json", "{}", "unsupported config file type '.json'"),
     ("c.yaml", "- a\n- b\n", "expected a mapping of component name"),
     ("c.yaml", "llm: 3\n", "settings of 'llm' must be a mapping"),
     ("c.yaml", "llm: [\n", "invalid YAML"),
     ("c.toml", "[llm\n", "invalid TOML")],
)
def test_bad_files_name_the_file(tmp_path, name, text, match):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(ConfigError, match=match) as err:
        load_configs(path)
    assert str(path) in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_configs(tmp_path / "nope.yaml")


@define(kw_only=True)
class Moded(BaseComponentConfig):
    mode: str = field(default="fast", converter=one_of("mode", "fast", "safe", meanings={"safe": "checks each step"}))


def test_a_choice_names_its_field_and_each_choice_with_its_meaning():
    assert apply_config(Moded(), {"mode": "safe"}).mode == "safe"
    with pytest.raises(ConfigError, match=r"mode must be 'fast' or 'safe' \(checks each step\), got 'quick'"):
        Moded(mode="quick")
    with pytest.raises(ConfigError, match=r"invalid value \['fast'\] for 'mode': mode must be"):
        apply_config(Moded(), {"mode": ["fast"]})  # not a string: refused, not compared by accident
