"""Settings by name: ``section.field=value`` for any setting of a StabilizeConfig (``deblur.alpha=4``,
``completion.neighbour_frames=2``, ``smoothing.radius_frames=90``, ``completion.mosaic.variance_threshold=50``), as the
debugger takes them (``ffviz debug --set``).

A value is read by its field's type (int, float, bool, str, a choice, ``none`` where the field may be None, a tuple
as items joined by ``+``); the config's own checks then judge it, so an out-of-range value fails as it would on the
command line. Every error is one line naming the valid choices.
"""

from __future__ import annotations

import dataclasses
import functools
import types
import typing
from typing import Any, Literal, Mapping

from pipeline.config import StabilizeConfig
from pipeline.errors import ConfigError

TRUE, FALSE = ("true", "on", "yes", "1"), ("false", "off", "no", "0")
TUPLE_SEPARATOR = "+"  # a tuple's items (a comma separates settings)
# What the path plan depends on besides pass 1's motion: these re-plan the path; motion.* and rolling_shutter
# change pass 1 itself.
PATH_SECTIONS = ("mode", "smoothing", "crop")
PASS_1_SECTIONS = ("motion", "rolling_shutter")


def parse_settings(text: str) -> dict[str, str]:
    """``"completion.neighbour_frames=2,deblur.alpha=4"`` -> {name: value text}."""
    settings: dict[str, str] = {}
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        name, equals, value = part.partition("=")
        if not equals or not name.strip():
            raise ConfigError(f"--set {text!r}: expected SECTION.FIELD=VALUE, comma-separated (e.g. deblur.alpha=4)")
        settings[name.strip()] = value.strip()
    if not settings:
        raise ConfigError(f"--set {text!r}: no setting given (e.g. deblur.alpha=4)")
    return settings


def setting_names(config: Any = None, prefix: str = "") -> list[str]:
    """Every settable name of ``config`` (a StabilizeConfig by default), sections flattened."""
    config = StabilizeConfig() if config is None else config
    names = []
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if dataclasses.is_dataclass(value):
            names += setting_names(value, f"{prefix}{field.name}.")
        else:
            names.append(f"{prefix}{field.name}")
    return names


def with_settings(config: StabilizeConfig, settings: Mapping[str, Any]) -> StabilizeConfig:
    """``config`` with each named setting changed (values as text or already typed); ConfigError on an unknown
    name, an unreadable value or one the config refuses."""
    for name, value in settings.items():
        config = _with_setting(config, name.split("."), value, name)
    return config


def _with_setting(config: Any, parts: list[str], value: Any, name: str) -> Any:
    fields = {f.name: f for f in dataclasses.fields(config)}
    head = parts[0]
    if head not in fields:
        raise ConfigError(f"unknown setting {name!r}; {_where(name, parts)}: " + ", ".join(sorted(fields)))
    current = getattr(config, head)
    if len(parts) > 1:
        if not dataclasses.is_dataclass(current):
            raise ConfigError(f"unknown setting {name!r}: {head} is a setting, not a section")
        new = _with_setting(current, parts[1:], value, name)
    elif dataclasses.is_dataclass(current):
        raise ConfigError(f"{name!r} is a section: its settings are "
                          + ", ".join(f"{name}.{n}" for n in setting_names(current)))
    else:
        new = _read(value, _hints(type(config))[head], name)
    try:
        return dataclasses.replace(config, **{head: new})
    except ConfigError as error:
        raise ConfigError(f"{name}={_text(value)}: {error}") from None
    except (TypeError, ValueError) as error:
        raise ConfigError(f"{name}={_text(value)}: {error}") from None


def _where(name: str, parts: list[str]) -> str:
    section = name[: len(name) - len(".".join(parts))].rstrip(".")
    return f"the settings of {section!r} are" if section else "the sections and settings are"


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _read(value: Any, hint: Any, name: str) -> Any:
    """``value`` (text, or already typed) as the type ``hint`` says."""
    if not isinstance(value, str):
        return value
    text = value.strip()
    options = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    if type(None) in options and text.lower() == "none":
        return None
    errors = []
    for option in (o for o in options if o is not type(None)):
        try:
            return _read_as(text, option)
        except ValueError as error:
            errors.append(str(error))
    raise ConfigError(f"{name}={text!r}: " + "; ".join(dict.fromkeys(errors)))


def _read_as(text: str, hint: Any) -> Any:
    origin = typing.get_origin(hint)
    if origin is Literal:
        choices = typing.get_args(hint)
        if text not in choices:
            raise ValueError(f"choose one of {', '.join(map(str, choices))}")
        return text
    if origin is tuple:
        item = typing.get_args(hint)[0]
        return tuple(_read_as(part.strip(), item) for part in text.split(TUPLE_SEPARATOR) if part.strip())
    if hint is bool:
        if text.lower() not in TRUE + FALSE:
            raise ValueError("expected true or false")
        return text.lower() in TRUE
    if hint in (int, float, str):
        try:
            return hint(text)
        except ValueError:
            raise ValueError(f"expected {'a number' if hint is float else 'a whole number' if hint is int else 'text'}")
    raise ValueError(f"cannot be set by name (a {getattr(hint, '__name__', hint)})")


def _text(value: Any) -> str:
    return value if isinstance(value, str) else repr(value)


def changes_pass_1(settings: Mapping[str, Any]) -> list[str]:
    """The named settings that change pass 1's motion (the video must be opened again with them)."""
    return [name for name in settings if name.split(".")[0] in PASS_1_SECTIONS]


def changes_path(settings: Mapping[str, Any]) -> bool:
    """Whether the named settings change the path plan."""
    return any(name.split(".")[0] in PATH_SECTIONS for name in settings)


def label(settings: Mapping[str, Any]) -> str:
    """A variant's name from its settings: 'default', or 'alpha=4,neighbour_frames=2' (the field names)."""
    if not settings:
        return "default"
    return ",".join(f"{name.rsplit('.', 1)[-1]}={_text(value)}" for name, value in settings.items())
