"""Component configs: attrs classes with validators, loadable from YAML or TOML.

A config is an ``@define(kw_only=True)`` attrs class; assignments and
:func:`apply_config` run its converters and validators, so a bad value is
refused where it is written, not deep inside a running component. Each
component deep-copies its config, so two components built from one config
object never share (or mutate) each other's settings.

Example::

    >>> cfg = apply_config(BaseComponentConfig(), {"loop_rate_hz": "5"})
    >>> cfg.loop_rate_hz
    5.0
    >>> apply_config(cfg, {"loop_rate": 5})
    Traceback (most recent call last):
    embagents.config.ConfigError: BaseComponentConfig: unknown config key 'loop_rate'; valid keys: ...
"""

from __future__ import annotations

import copy
import os
import sys
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import attrs
from attrs import AttrsInstance, define, field

__all__ = [
    "LOG_LEVELS",
    "BaseComponentConfig",
    "ConfigError",
    "apply_config",
    "config_fields",
    "int_at_least",
    "load_configs",
    "one_of",
    "optional_positive_float",
    "positive_float",
    "positive_int",
    "to_bool",
]

LOG_LEVELS = ("debug", "info", "warning", "error")

C = TypeVar("C", bound=AttrsInstance)


class ConfigError(ValueError):
    """A config value, key or file is invalid; the message names it and the valid choices."""


def positive_float(value: object) -> float:
    """Converter: a number (or numeric string) > 0, as float.

    >>> positive_float("2.5")
    2.5
    """
    if isinstance(value, bool):
        raise ConfigError(f"expected a number > 0, got {value!r}")
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ConfigError(f"expected a number > 0, got {value!r}") from None
    if not out > 0:  # also refuses NaN
        raise ConfigError(f"expected a number > 0, got {value!r}")
    return out


def to_bool(value: object) -> bool:
    """Converter: a bool, or true/false, yes/no, on/off, 1/0.

    >>> to_bool("yes")
    True
    """
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.lower() in ("true", "yes", "on", "1", "false", "no", "off", "0"):
        return value.lower() in ("true", "yes", "on", "1")
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    raise ConfigError(f"expected true or false, got {value!r}")


def int_at_least(low: int) -> Callable[[object], int]:
    """Converter factory: an integer (or integral string) >= ``low``.

    >>> int_at_least(1)("3")
    3
    """
    def conv(value: object) -> int:
        out: int | None = None
        if isinstance(value, int) and not isinstance(value, bool):
            out = value
        elif isinstance(value, float) and value.is_integer():
            out = int(value)
        elif isinstance(value, str) and value.strip().lstrip("-").isdigit():
            out = int(value)
        if out is None or out < low:
            raise ConfigError(f"expected an integer >= {low}, got {value!r}")
        return out

    return conv


def positive_int(value: object) -> int:
    """Converter: an integer (or integral string) >= 1; a named function, so mypy types the field.

    >>> positive_int("3")
    3
    """
    return int_at_least(1)(value)


def one_of(name: str, *allowed: str, meanings: Mapping[str, str] | None = None) -> Callable[[object], str]:
    """Converter factory: one of the strings ``allowed``; the error names the field and each choice
    (with what it means, where ``meanings`` says).

    >>> one_of("mode", "vector", "llm")("llm")
    'llm'
    >>> one_of("durability", "normal", "full", meanings={"full": "also a power loss"})("fast")
    Traceback (most recent call last):
    ...
    embagents.config.ConfigError: durability must be 'normal' or 'full' (also a power loss), got 'fast'
    """
    shown = [repr(a) + (f" ({meanings[a]})" if meanings and a in meanings else "") for a in allowed]
    choices = f"{', '.join(shown[:-1])} or {shown[-1]}" if len(shown) > 1 else shown[0]

    def conv(value: object) -> str:
        if value not in allowed:
            raise ConfigError(f"{name} must be {choices}, got {value!r}")
        return str(value)

    return conv


def optional_positive_float(value: object) -> float | None:
    """Converter: ``None`` or a number > 0.

    >>> optional_positive_float(None) is None
    True
    """
    return None if value is None else positive_float(value)


def _log_level(value: object) -> str:
    level = str(value).lower()
    if level not in LOG_LEVELS:
        raise ConfigError(f"log_level must be one of {', '.join(LOG_LEVELS)}; got {value!r}")
    return level


@define(kw_only=True)
class BaseComponentConfig:
    """Settings every component has.

    - ``loop_rate_hz``: rate in Hz of a timed component (``trigger=10.0`` sets it to 10 Hz).
    - ``step_timeout_s``: under ``embagents supervise``, a step that keeps the
      component busy longer than this is a hang: its heartbeat deadline, so the
      supervisor kills the process and restarts it (time spent waiting on a
      model actor does not count: that wait beats); ``None``: the default
      deadline, 30 s.
    - ``input_max_age_s``: an input message older than this is treated as not
      received (a frozen camera must not feed a stale frame); ``None``: no limit.
    - ``log_level``: one of debug, info, warning, error: the level of the
      component's logger (``embagents.component.<name>``).
    - ``wait_for_subscribers``: under ``embagents supervise``, the component is
      activated (its steps start) only once the subscribers the System declares
      for its outputs are connected and active, so nothing it publishes at
      startup is lost, whatever the list order; ``False``: at once, in list
      order (a camera that must not wait; what it publishes before its
      subscribers are up is lost).
    - ``wait_for_inputs``: a step (rate, topic or event triggered) waits until
      every required input has a message, and says once which one it waits
      for; ``False``: it runs with what is there (``None`` for the missing ones).

    >>> BaseComponentConfig(loop_rate_hz=2).loop_rate_hz
    2.0
    """

    loop_rate_hz: float = field(default=10.0, converter=positive_float)
    step_timeout_s: float | None = field(default=None, converter=optional_positive_float)
    input_max_age_s: float | None = field(default=None, converter=optional_positive_float)
    log_level: str = field(default="info", converter=_log_level)
    wait_for_subscribers: bool = field(default=True, converter=to_bool)
    wait_for_inputs: bool = field(default=True, converter=to_bool)


def config_fields(config_or_class: object) -> list[str]:
    """The settable keys of a config (object or class), in declaration order.

    >>> config_fields(BaseComponentConfig)[:2]
    ['loop_rate_hz', 'step_timeout_s']
    """
    cls = config_or_class if isinstance(config_or_class, type) else type(config_or_class)
    if not attrs.has(cls):
        raise TypeError(f"{cls.__qualname__} is not an attrs config class")
    return [f.name for f in attrs.fields(cls) if f.init]


def _evolve(config: C, changes: dict[str, Any]) -> C:
    # mypy's attrs plugin takes a TypeVar for an attrs class only when bound to one class, not to AttrsInstance.
    return attrs.evolve(copy.deepcopy(config), **copy.deepcopy(changes))  # type: ignore[misc]


def apply_config(config: C, overrides: Mapping[str, Any]) -> C:
    """A validated copy of ``config`` with ``overrides`` applied; ``config`` is untouched.

    A nested attrs config field takes a dict of its own overrides. Unknown keys
    and invalid values raise :class:`ConfigError` naming the key.

    >>> base = BaseComponentConfig()
    >>> apply_config(base, {"log_level": "DEBUG"}).log_level, base.log_level
    ('debug', 'info')
    """
    cls = type(config)
    valid = config_fields(cls)
    if not isinstance(overrides, Mapping):
        raise ConfigError(f"{cls.__name__}: overrides must be a mapping of key -> value, got {overrides!r}")
    for key in overrides:
        if key not in valid:
            raise ConfigError(
                f"{cls.__name__}: unknown config key {key!r}; valid keys: {', '.join(valid)}"
            )
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        current = getattr(config, key)
        if attrs.has(type(current)) and isinstance(value, Mapping):
            value = apply_config(current, value)
        changes[key] = value
    try:
        return _evolve(config, changes)
    except (TypeError, ValueError) as exc:
        error = exc
    # Find the key at fault so the message can name it (cross-field checks may
    # only fail together, then all keys are named).
    for key, value in changes.items():
        try:
            _evolve(config, {key: value})
        except (TypeError, ValueError) as one:
            raise ConfigError(f"{cls.__name__}: invalid value {value!r} for {key!r}: {one}") from one
    raise ConfigError(
        f"{cls.__name__}: invalid combination of {', '.join(map(repr, changes))}: {error}"
    ) from error


def _read(path: str) -> Any:
    ext = os.path.splitext(path)[1].lower()
    if ext in (".yaml", ".yml"):
        import yaml

        with open(path, encoding="utf-8") as f:
            try:
                return yaml.safe_load(f)
            except yaml.YAMLError as exc:
                raise ConfigError(f"{path}: invalid YAML: {exc}") from exc
    if ext == ".toml":
        if sys.version_info >= (3, 11):
            import tomllib
        else:  # pragma: no cover - Python 3.10
            import tomli as tomllib
        with open(path, "rb") as f:
            try:
                return tomllib.load(f)
            except tomllib.TOMLDecodeError as exc:
                raise ConfigError(f"{path}: invalid TOML: {exc}") from exc
    raise ConfigError(f"{path}: unsupported config file type {ext or '(none)'!r}; use .yaml, .yml or .toml")


def load_configs(path: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """Read per-component overrides: a mapping of component name -> mapping of settings.

    The format follows the extension (``.yaml``/``.yml`` or ``.toml``)::

        # configs.yaml                 # configs.toml
        llm:                           [llm]
          temperature: 0.2             temperature = 0.2
          chat_history: true           chat_history = true

    Feed each entry to :func:`apply_config` (or ``component.reconfigure``).
    """
    path = os.fspath(path)
    try:
        data = _read(path)
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc.strerror or exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ConfigError(
            f"{path}: expected a mapping of component name -> settings at top level, "
            f"got {type(data).__name__}"
        )
    out: dict[str, dict[str, Any]] = {}
    for name, settings in data.items():
        if settings is None:
            settings = {}
        if not isinstance(settings, Mapping):
            raise ConfigError(
                f"{path}: settings of {name!r} must be a mapping of key -> value, "
                f"got {type(settings).__name__} {settings!r}"
            )
        out[str(name)] = dict(settings)
    return out
