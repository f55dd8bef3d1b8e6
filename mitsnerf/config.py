"""Typed, frozen dataclass configs from plain mappings (TOML tables, CLI overrides).

>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class C:
...     steps: int = 10
...     lr: float = 0.1
>>> from_dict(C, {"lr": 1})
C(steps=10, lr=1.0)
>>> from_dict(C, {"stepz": 1})
Traceback (most recent call last):
...
ValueError: stepz: unknown key (known: steps, lr)
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Mapping


def _convert(tp, value, key: str):
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(arg, value, key)
            except ValueError as exc:
                errors.append(str(exc))
        raise ValueError(errors[0] if errors else f"{key}: invalid value {value!r}")
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise ValueError(f"{key}: expected a table, got {type(value).__name__}")
        return from_dict(tp, value, prefix=f"{key}.")
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{key}: expected a list, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{key}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise ValueError(f"{key}: expected {len(args)} values, got {len(value)}")
        return tuple(_convert(a, v, f"{key}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if tp is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{key}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{key}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{key}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ValueError(f"{key}: expected a string, got {value!r}")
        return value
    if typing.get_origin(tp) is typing.Literal:
        if value not in args:
            raise ValueError(f"{key}: must be one of {', '.join(map(repr, args))}, got {value!r}")
        return value
    return value


def from_dict(cls, values: Mapping[str, Any] | None, prefix: str = ""):
    """Build dataclass ``cls`` from ``values``; errors are ``ValueError("field: problem")``.

    Nested dataclass fields take nested mappings; missing keys keep their defaults;
    the dataclass's own ``__post_init__`` validation runs (its messages get the prefix).
    """
    values = dict(values or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [k for k in values if k not in fields]
    if unknown:
        raise ValueError(f"{prefix}{unknown[0]}: unknown key (known: {', '.join(fields)})")
    for key, value in values.items():
        # A table for a nested config overrides that field's own default, key by key.
        default = _field_default(fields[key])
        if dataclasses.is_dataclass(default) and isinstance(value, Mapping):
            values[key] = deep_merge(to_dict(default), value)
    kwargs = {k: _convert(hints[k], v, f"{prefix}{k}") for k, v in values.items()}
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise ValueError(f"{prefix}{exc}") from None
    except TypeError as exc:
        raise ValueError(f"{prefix.rstrip('.') or cls.__name__}: {exc}") from None


def _field_default(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return None


def deep_merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict:
    """``over`` merged into a copy of ``base``; nested tables merge key by key.

    >>> deep_merge({"a": 1, "n": {"x": 1, "y": 2}}, {"n": {"y": 3}, "b": 2})
    {'a': 1, 'n': {'x': 1, 'y': 3}, 'b': 2}
    """
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def to_dict(obj) -> dict:
    """A dataclass config as plain nested dicts/lists (JSON and TOML friendly)."""
    return dataclasses.asdict(obj)


def with_overrides(obj, overrides: Mapping[str, Any]):
    """A copy of config ``obj`` with dotted-key overrides, e.g. ``{"network.width": 32}``, validated."""
    base = to_dict(obj)
    for dotted, value in overrides.items():
        node = base
        parts = dotted.split(".")
        for part in parts[:-1]:
            if not isinstance(node.get(part), dict):
                raise ValueError(f"{dotted}: unknown key")
            node = node[part]
        if parts[-1] not in node:
            raise ValueError(f"{dotted}: unknown key")
        node[parts[-1]] = value
    return from_dict(type(obj), base)
