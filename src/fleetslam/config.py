"""Typed configuration: the base model every section derives from, and loading with overrides.

Each subsystem declares its section once as a :class:`ConfigModel` subclass in its own package
(``fleetslam.slam.config.SlamConfig``, ...): typed fields with defaults and a docstring per field (the
docstring is the documentation; ``fleetslam config dump`` prints it). YAML files and ``FLEETSLAM_*``
environment variables only override those defaults. Errors name the file, the key and the value.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from fleetslam.errors import ConfigError

ModelT = TypeVar("ModelT", bound="ConfigModel")


class ConfigModel(BaseModel):
    """Base of every configuration section: unknown keys are errors, field docstrings are descriptions."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True, validate_assignment=True)


def _format_validation_error(err: ValidationError, source: str) -> str:
    problems = []
    for e in err.errors():
        key = ".".join(str(p) for p in e["loc"]) or "<root>"
        value = e.get("input")
        shown = repr(value)
        if len(shown) > 80:
            shown = shown[:77] + "..."
        problems.append(f"{source}: key '{key}' = {shown}: {e['msg']}")
    return "\n".join(problems)


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping; raises ConfigError naming the file (and line) when it is not one."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{path}: cannot read configuration file: {err.strerror}") from err
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: not UTF-8 text (byte 0x{err.object[err.start]:02x} at offset {err.start})") from err
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""
        raise ConfigError(f"{path}{where}: invalid YAML: {err}") from err
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return data


def deep_update(base: dict[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """Recursively merge ``update`` into a copy of ``base`` (mappings merge, everything else replaces)."""
    merged = dict(base)
    for key, value in update.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = deep_update(dict(merged[key]), value)
        else:
            merged[key] = value
    return merged


def parse_override(text: str) -> tuple[list[str], Any]:
    """Parse ``a.b.c=value`` (value is YAML) into ``(["a", "b", "c"], value)``."""
    if "=" not in text:
        raise ConfigError(f"override {text!r}: expected KEY=VALUE, e.g. odometry.max_features=1000")
    key, raw = text.split("=", 1)
    if not key.strip():
        raise ConfigError(f"override {text!r}: empty key")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as err:
        raise ConfigError(f"override {text!r}: value {raw!r} is not valid YAML") from err
    return key.strip().split("."), value


def _nest(path: list[str], value: Any) -> dict[str, Any]:
    out: dict[str, Any] = {path[-1]: value}
    for part in reversed(path[:-1]):
        out = {part: out}
    return out


def env_overrides(prefix: str, environ: Mapping[str, str] | None = None) -> list[str]:
    """``FLEETSLAM_<PREFIX>__A__B=value`` environment variables as ``a.b=value`` overrides."""
    environ = os.environ if environ is None else environ
    head = f"FLEETSLAM_{prefix.upper()}__"
    out = []
    for name, value in sorted(environ.items()):
        if name.startswith(head):
            key = ".".join(part.lower() for part in name[len(head) :].split("__"))
            out.append(f"{key}={value}")
    return out


def load_config(
    model: type[ModelT],
    path: str | Path | None = None,
    *,
    overrides: list[str] | None = None,
    section: str | None = None,
    env_prefix: str | None = None,
    environ: Mapping[str, str] | None = None,
) -> ModelT:
    """Build a config model from its defaults, a YAML file, environment variables and ``KEY=VALUE`` overrides.

    Args:
        model: the section's model class.
        path: optional YAML file; if ``section`` is given, only that top-level key of the file is used.
        overrides: ``a.b=value`` strings applied last.
        section: top-level key of the file holding this model.
        env_prefix: read ``FLEETSLAM_<ENV_PREFIX>__KEY__SUB=value`` variables.
        environ: environment to read (default ``os.environ``).

    Raises:
        ConfigError: naming the file or override, the key and the value at fault.
    """
    data: dict[str, Any] = {}
    source = "defaults"
    if path is not None:
        source = str(path)
        data = read_yaml(path)
        if section is not None:
            sub = data.get(section, {})
            if not isinstance(sub, dict):
                raise ConfigError(f"{path}: key '{section}' must be a mapping, got {type(sub).__name__}")
            data = sub
    all_overrides = list(env_overrides(env_prefix, environ) if env_prefix else []) + list(overrides or [])
    for text in all_overrides:
        keys, value = parse_override(text)
        data = deep_update(data, _nest(keys, value))
    if all_overrides:
        source = f"{source} + overrides {all_overrides}"
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_format_validation_error(err, source)) from err


#: section name -> "module:ClassName" of its ConfigModel, imported lazily: the sections of `fleetslam config dump`.
CONFIG_SECTIONS: dict[str, str] = {
    "robot": "fleetslam.robot.config:RobotConfig",
    "sim": "fleetslam.sim.config:SimConfig",
    "slam": "fleetslam.slam.config:SlamConfig",
    "mapping": "fleetslam.mapping.config:MappingConfig",
}


def section_model(section: str) -> type[BaseModel]:
    """The model class of a section of :data:`CONFIG_SECTIONS`."""
    module_name, _, class_name = CONFIG_SECTIONS[section].partition(":")
    model: type[BaseModel] = getattr(importlib.import_module(module_name), class_name)
    return model


def dump_sections(sections: Sequence[str] | None = None) -> str:
    """The defaults of ``sections`` (default: all) as YAML, each under its name, each key with its documentation."""
    chunks = []
    for section in sections or list(CONFIG_SECTIONS):
        body = dump_config(section_model(section)())
        indented = "".join(f"  {line}\n" if line else "\n" for line in body.splitlines())
        chunks.append(f"{section}:\n{indented}")
    return "\n".join(chunks)


def dump_config(config: BaseModel) -> str:
    """YAML text of a config model, each field preceded by its description as a comment."""
    lines: list[str] = []
    _dump_model(config, lines, indent=0)
    return "\n".join(lines) + "\n"


def _dump_model(config: BaseModel, lines: list[str], indent: int) -> None:
    pad = "  " * indent
    for name, field in type(config).model_fields.items():
        value = getattr(config, name)
        if field.description:
            for text in field.description.strip().splitlines():
                lines.append(f"{pad}# {text.strip()}")
        if isinstance(value, BaseModel):
            lines.append(f"{pad}{name}:")
            _dump_model(value, lines, indent + 1)
        else:
            dumped = yaml.safe_dump({name: _plain(value)}, default_flow_style=True, sort_keys=False).strip()
            if dumped.startswith("{") and dumped.endswith("}"):
                dumped = dumped[1:-1]
            lines.append(f"{pad}{dumped}")


def _plain(value: Any) -> Any:
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if hasattr(value, "value") and not isinstance(value, int | float | str | bool):
        return value.value
    return value
