"""Dataclass configs ⇄ plain YAML data, with strict keys and ``a.b=value`` overrides.

Each stage has one dataclass config (data, render, loss, densify, optim, mesh, …); a run's config
composes them. Presets in ``configs/*.yaml`` are those dataclasses serialised: plain data read with
``yaml.safe_load`` (never ``eval``). Unknown keys are errors, so a typo cannot be silently ignored.
"""

from __future__ import annotations

import dataclasses
import re
import typing
from pathlib import Path

import yaml

from .errors import GofError

_FLOAT_TEXT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")  # exponent notation without YAML's dot


class ConfigError(GofError):
    """A config file or override that does not match the config dataclasses."""


def to_dict(cfg) -> dict:
    """Dataclass → nested dict of plain data (tuples become lists).

    A field whose metadata has ``set_by`` (the dotted key that sets it, e.g. ``experimental.tile_cull``) is left
    out: it is a copy of a setting that lives elsewhere in the composed config."""

    def plain(v):
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v) if not f.metadata.get("set_by")}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(cfg)


def _coerce(value, annotation, where):
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        return from_dict(annotation, value, where)
    if origin is typing.Union or (origin is not None and str(origin) == "<class 'types.UnionType'>"):
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, where)
            except ConfigError:
                continue
        raise ConfigError(f"{where}: {value!r} does not match {annotation}")
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        inner = args[0] if args else typing.Any
        items = [_coerce(v, inner, where) for v in value]
        return tuple(items) if origin is tuple else items
    if annotation is float:
        if isinstance(value, str) and _FLOAT_TEXT.fullmatch(value.strip()):
            value = float(value)  # YAML 1.1 reads 1e-6 (no dot) as text; users mean the number
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not (isinstance(value, int) or (isinstance(value, float) and value.is_integer())):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return int(value)
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def from_dict(cls, data: dict, where: str = "config"):
    """Build dataclass ``cls`` from a (partial) dict; missing keys keep their defaults."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    if hasattr(cls, "upgrade_keys"):
        data = cls.upgrade_keys(data, where)
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; valid keys: {sorted(names)}")
    kwargs = {k: _coerce(v, hints[k], f"{where}.{k}") for k, v in data.items()}
    base = cls()
    return dataclasses.replace(base, **kwargs)


def merge(cfg, data: dict, where: str = "config"):
    """Return ``cfg`` with the values in (nested, partial) ``data`` replaced.

    A key that is not a field raises :class:`ConfigError` naming its dotted path (``densify.max_gausians``)
    and the valid keys at that level; values are type-checked as :func:`from_dict` does."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: overrides must be a mapping, got {type(data).__name__}")
    if hasattr(type(cfg), "upgrade_keys"):
        data = type(cfg).upgrade_keys(data, where)
    merged = to_dict(cfg)

    def deep(dst, src, prefix):
        for k, v in src.items():
            dotted = f"{prefix}{k}"
            if isinstance(v, dict) and isinstance(dst.get(k), dict):
                deep(dst[k], v, f"{dotted}.")
            else:
                if k not in dst:
                    level = f" of {prefix[:-1]!r}" if prefix else ""
                    raise ConfigError(f"{where}: unknown key {dotted!r}; valid keys{level}: {sorted(dst)}")
                dst[k] = v

    deep(merged, data, "")
    return from_dict(type(cfg), merged, where)


def parse_override(text: str) -> dict:
    """``"loss.lambda_normal=0.1"`` → ``{"loss": {"lambda_normal": 0.1}}`` (value parsed as YAML data)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r} must look like section.key=value")
    key, raw = text.split("=", 1)
    parts = [p for p in key.strip().split(".") if p]
    if not parts:
        raise ConfigError(f"override {text!r} has an empty key")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as e:
        raise ConfigError(f"override {text!r}: cannot parse value: {e}") from None
    out: dict = value
    for p in reversed(parts):
        out = {p: out}
    return out


def combine_overrides(overrides: list[str]) -> dict:
    """``section.key=value`` texts as one nested mapping (a later text wins for the same key), for one :func:`merge`.

    Merged together, settings that are checked against each other change together: ``densify.near_camera_fraction=0
    densify.late_prune_interval=0`` works in either order, where merging one at a time would stop at the first."""
    combined: dict = {}

    def deep(dst, src):
        for k, v in src.items():
            if isinstance(v, dict) and isinstance(dst.get(k), dict):
                deep(dst[k], v)
            else:
                dst[k] = v

    for o in overrides:
        deep(combined, parse_override(o))
    return combined


def load_yaml(path) -> dict:
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"config file {path} not found") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"config file {path} is not UTF-8 text (byte {e.start}: {e.reason}); save it as UTF-8") from None
    except RecursionError:
        raise ConfigError(f"config file {path} is nested too deeply to be a config (corrupt or not a config?)") from None
    except (OSError, yaml.YAMLError) as e:
        raise ConfigError(f"config file {path} cannot be read: {e}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path}: top level must be a mapping")
    return data


def dump_yaml(cfg) -> str:
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)
