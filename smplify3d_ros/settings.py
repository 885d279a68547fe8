"""The settings machinery every section shares: YAML loading, profile merging, typed validation.

Layout of `params/`:
- `params/base/<section>.yaml`: one file per section, together holding every tunable value with a
  one-line comment. They are the single source of values: the section dataclasses declare types and
  ranges, not defaults.
- `params/<profile>.yaml` (e.g. `jackal_vlp16.yaml`, the default): overrides on top of the base, as a
  nested mapping of sections.

`load_sections` merges base, profile and programmatic overrides into plain mappings (every overriding
key must exist in the base, so typos fail); each owner turns its section into its dataclass with
`from_dict`: the core (`smplify3d_ros.config.load_config`: fitting, lidar, people), the drivers
(`smplify3d_ros.runtime.config`: node) and the simulator (`smplify3d_ros.sim.config`: sim). This module
imports no section, so that sections can import `require` from here without a cycle.

Unknown keys, missing keys, wrong types and out-of-range values raise `ConfigError` naming the key.
"""

from __future__ import annotations

import copy
import dataclasses
import os
import stat
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

PARAMS_DIR = Path(__file__).resolve().parent.parent / "params"
DEFAULT_PROFILE = "jackal_vlp16"


class ConfigError(ValueError):
    """A configuration value is unknown, missing, of the wrong type or out of range."""


def require(condition: bool, message: str) -> None:
    """Range check for section `__post_init__` methods; the loader prefixes the key path."""
    if not condition:
        raise ConfigError(message)


def params_dir() -> Path:
    """Where the YAML files live: next to the package in a source checkout, or in the installed share."""
    if PARAMS_DIR.is_dir():
        return PARAMS_DIR
    try:  # installed as an ament package: share/smplify3d_ros/params
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("smplify3d_ros")) / "params"
    except Exception as exc:  # noqa: BLE001 - any failure means "not installed that way"
        raise ConfigError(f"cannot find the params/ directory (looked in {PARAMS_DIR})") from exc


def resolve_profile(profile: str | Path | None) -> Path:
    """A profile name (`ouster64`) or a path to a YAML file."""
    if profile is None:
        profile = DEFAULT_PROFILE
    path = Path(profile)
    if path.suffix in (".yaml", ".yml") and path.exists():
        return path
    candidate = params_dir() / f"{profile}.yaml"
    if candidate.exists():
        return candidate
    known = sorted(p.stem for p in params_dir().glob("*.yaml"))
    raise ConfigError(f"unknown params profile {str(profile)!r}; known profiles: {known} or a .yaml path")


# libyaml's safe loader when PyYAML was built with it (ten times faster), else the pure-Python one
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_yaml(path: Path) -> dict[str, Any]:
    """A YAML mapping; unreadable files, YAML errors and tags (`!!python/...`) are one-line ConfigErrors.
    A file is parsed once while it is unchanged (same size and modification time); callers get a copy."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not stat.S_ISREG(info.st_mode):  # a pipe or a device: read every time
        return _parse_yaml(path)
    key = (os.path.abspath(path), info.st_mtime_ns, info.st_size)
    if key not in _PARSED:
        if len(_PARSED) >= 64:  # a tuning loop writing profiles: keep the cache bounded
            _PARSED.clear()
        _PARSED[key] = _parse_yaml(path)
    return copy.deepcopy(_PARSED[key])


_PARSED: dict[tuple[str, int, int], dict[str, Any]] = {}


def _parse_yaml(path: Path) -> dict[str, Any]:
    try:
        with open(path, encoding="utf-8") as handle:
            data = yaml.load(handle, Loader=_SAFE_LOADER) or {}
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{path}: invalid YAML{where}: {problem}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping")
    return data


def deep_merge(base: Mapping[str, Any], override: Mapping[str, Any], where: str = "") -> dict[str, Any]:
    """Merge `override` into `base`; every overriding key must exist in the base (no typos pass)."""
    merged = dict(base)
    for key, value in override.items():
        path = f"{where}.{key}" if where else key
        if key not in base:
            raise ConfigError(f"unknown key {path!r}")
        if isinstance(value, Mapping) and isinstance(base[key], Mapping):
            merged[key] = deep_merge(base[key], value, path)
        else:
            merged[key] = value
    return merged


def base_values() -> dict[str, Any]:
    """Every section of params/base/, by section name (the file's stem)."""
    values: dict[str, Any] = {}
    for path in sorted((params_dir() / "base").glob("*.yaml")):
        values[path.stem] = load_yaml(path)
    return values


def load_sections(profile: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """params/base/*.yaml, then the profile's overrides, then `overrides`: section name -> mapping."""
    values = deep_merge(base_values(), load_yaml(resolve_profile(profile)))
    if overrides:
        values = deep_merge(values, overrides)
    return values


def section(cls: type, name: str, profile: str | Path | None = None,
            overrides: Mapping[str, Any] | None = None) -> Any:
    """One section of a profile as its dataclass `cls` (e.g. the simulator's, the node's)."""
    values = load_sections(profile, overrides)
    if name not in values:
        raise ConfigError(f"missing section {name!r} (params/base/{name}.yaml)")
    return from_dict(cls, values[name], name)


def _coerce(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        return from_dict(hint, value, where)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(f"{where}: {value!r} matches none of {hint}")
    if origin is typing.Literal:
        if value not in typing.get_args(hint):
            raise ConfigError(f"{where}: {value!r} is not one of {typing.get_args(hint)}")
        return value
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        args = typing.get_args(hint)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(value):
                raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
            return tuple(_coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
        item = args[0] if args else Any
        items = [_coerce(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        key_t, val_t = typing.get_args(hint) or (Any, Any)
        return {k: _coerce(v, val_t, f"{where}.{k}") for k, v in value.items()}
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type, data: Mapping[str, Any], where: str = "") -> Any:
    """Build dataclass `cls` from a mapping: every field required, no unknown keys, types checked."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(f"unknown key {where + '.' if where else ''}{sorted(unknown)[0]!r}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        path = f"{where}.{f.name}" if where else f.name
        if f.name not in data:
            if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING:
                continue
            raise ConfigError(f"missing key {path!r}")
        kwargs[f.name] = _coerce(data[f.name], hints[f.name], path)
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}" if where else str(exc)) from None


def to_dict(obj: Any) -> Any:
    """The inverse of `from_dict` (for logging and for overriding one value programmatically)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_dict(v) for k, v in obj.items()}
    return obj
