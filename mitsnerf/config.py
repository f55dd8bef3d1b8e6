"""Typed, frozen dataclass configs from plain data (TOML tables, JSON, CLI overrides): the one mechanism.

A config is a frozen dataclass. A field declared with :func:`param` carries its range, its choices
and its documentation (one place per field); :func:`from_dict` converts plain data into the class,
checking types, ranges, choices and unknown keys, then runs the class's own ``__post_init__`` for
rules between fields. Every problem is one :class:`~mitsnerf.errors.SpecError` (a ``ValueError``)
naming the file, the dotted field (list items by index: ``lights.1.radiance``) and the problem:

>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Grid:
...     resolution: int = param(64, lo=8, hi=512, doc="voxels per axis")
...     scale: float = param(1.0, lo=0.0, lo_open=True)
...     albedo: tuple[float, float, float] = param((0.8, 0.8, 0.8), lo=0.0, hi=1.0)
>>> from_dict(Grid, {"scale": 2, "albedo": [1, 0.5, 0]})
Grid(resolution=64, scale=2.0, albedo=(1.0, 0.5, 0.0))
>>> from_dict(Grid, {"resolution": 4}, source="grid.toml")
Traceback (most recent call last):
...
mitsnerf.errors.SpecError: grid.toml: resolution: must be an integer in [8, 512], got 4
>>> from_dict(Grid, {"resolutoin": 4}, source="grid.toml")
Traceback (most recent call last):
...
mitsnerf.errors.SpecError: grid.toml: resolutoin: unknown field (did you mean 'resolution'?)

Fields typed ``int``, ``float`` (finite; ints accepted), ``bool``, ``str``, ``Literal``, tuples
(fixed ``tuple[float, float, float]`` and variadic ``tuple[int, ...]``; lists accepted),
nested dataclasses (a table; over the field's own default key by key), ``X | None``,
``Mapping`` and unions of dataclasses tagged by a ``type`` class attribute (dispatched on the
table's ``type`` key) are understood. :func:`to_dict` turns a config back into plain data,
:func:`apply_overrides` applies dotted overrides (``{"lights.0.radiance": [1, 1, 1]}``) to plain
data, :func:`parse_value` reads a command-line value, :func:`read_toml` reads a file, and
:func:`search_dirs` / :func:`named_files` find files by name (the user's directories, then the package's).

A config saved with what it made (a run's ``method_config``, ``train`` and ``eval``: :func:`to_dict`, every
setting) is read back by :func:`from_saved`: a key it lacks is a setting added after it was saved, read as the
value that reproduces what it was made with, which the field declares beside its default when that default is
not it (``param(True, since=("0.1.0+7e1ef78", False))``: saved before that version, read as false), or as
refused in one line (``since=Since(VERSION, refuse="why no value reproduces it")``); without a declaration, as the
default. :func:`saved_readings` lists what each key reads as (the suite keeps a copy of the built-in methods',
so a changed default without a declaration fails it).

Every config of the package declares its fields with :func:`param`; a dataclass whose fields are
plain (``x: int = 1``) is read too, with the wording ``expected an integer`` and ``unknown key``.
"""

from __future__ import annotations

import ast
import collections.abc
import dataclasses
import difflib
import inspect
import json
import math
import os
import re
import sys
import textwrap
import types
import typing
from collections.abc import Mapping
from numbers import Integral, Real
from pathlib import Path
from typing import Any

from mitsnerf.errors import SpecError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

_BOUNDS = "mitsnerf.config.bounds"
#: Metadata key of fields that are not configuration data (not read by from_dict, not in to_dict).
INTERNAL = "mitsnerf.config.internal"
_SOURCE = "mitsnerf.config.source"
#: The key that selects the member of a tagged union of dataclasses (their ``type`` class attribute).
TAG = "type"
_FIELD_PATH = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z0-9_]+)*")


# --------------------------------------------------------------------------- declaring fields


@dataclasses.dataclass(frozen=True)
class Bounds:
    """What a :func:`param` field admits besides its type: a range (for every number in it) or choices."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple | None = None
    doc: str = ""
    hi_why: str = ""
    """Why the upper bound is what it is, added to the message of a value above it."""

    def text(self) -> str:
        return range_text(self.lo, self.hi, self.lo_open, self.hi_open)

    def admits(self, x: Any) -> bool:
        if self.choices is not None:
            return x in self.choices
        if self.lo is not None and (x <= self.lo if self.lo_open else x < self.lo):
            return False
        return self.hi is None or (x < self.hi if self.hi_open else x <= self.hi)


_SINCE = "mitsnerf.config.since"


@dataclasses.dataclass(frozen=True)
class Since:
    """A setting that configs saved before ``version`` lack (it did not exist then), and how :func:`from_saved`
    reads one that lacks it: as ``before``, the value that reproduces what it was made with, or, where ``refuse``
    says why no value does, refused."""

    version: str
    """The version that added the setting: ``<mitsnerf version>+<commit>``, as a run's code version reads."""
    before: Any = None
    refuse: str = ""
    """Why no value reproduces the configs saved before ``version`` (then they are refused, with this reason)."""

    def reading(self) -> Any:
        """What a saved config lacking the key reads as (:func:`saved_readings`)."""
        return f"refused: {self.refuse}" if self.refuse else plain(self.before)


def param(
    default: Any = dataclasses.MISSING,
    *,
    default_factory: Any = dataclasses.MISSING,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    hi_open: bool = False,
    choices: tuple | None = None,
    doc: str = "",
    hi_why: str = "",
    since: Since | tuple[str, Any] | None = None,
    **kwargs: Any,
) -> Any:
    """A dataclass field with its range (``[lo, hi]``, ends open on request; it applies to every
    number of a tuple), its ``choices``, its documentation and why its upper bound is what it is
    (``hi_why``, said when a value exceeds it); no default: the field is required. ``since``: the version
    that added it and the value that configs saved before then were made with (``(version, value)``, or a
    :class:`Since`), where that is not the default: how :func:`from_saved` reads a config that lacks it."""
    bounds = Bounds(lo, hi, lo_open, hi_open, tuple(choices) if choices is not None else None, doc, hi_why)
    metadata: dict[str, Any] = {_BOUNDS: bounds}
    if since is not None:
        metadata[_SINCE] = since if isinstance(since, Since) else Since(*since)
    return dataclasses.field(default=default, default_factory=default_factory, metadata=metadata, **kwargs)


def source_field() -> Any:
    """A field that records the file a config was read from: filled by :func:`from_dict`'s ``source``,
    not configuration data itself (not read from the data, not in :func:`to_dict`, not compared)."""
    return dataclasses.field(default=None, compare=False, metadata={INTERNAL: True, _SOURCE: True})


def range_text(lo, hi, lo_open: bool = False, hi_open: bool = False) -> str:
    """How an allowed range reads in a message: `` in [8, 512]``, `` > 0``, ``""``.

    >>> range_text(1, 2**20), range_text(0.0, 0.45, lo_open=True), range_text(0, None)
    (' in [1, 1048576]', ' in (0, 0.45]', ' >= 0')
    """
    if lo is not None and hi is not None:
        return f" in {'(' if lo_open else '['}{_number(lo)}, {_number(hi)}{')' if hi_open else ']'}"
    if lo is not None:
        return f" {'>' if lo_open else '>='} {_number(lo)}"
    if hi is not None:
        return f" {'<' if hi_open else '<='} {_number(hi)}"
    return ""


def _number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def is_int(value: Any) -> bool:
    """An integer, not a bool."""
    return isinstance(value, Integral) and not isinstance(value, bool)


def is_number(value: Any) -> bool:
    """A finite real number (int or float), not a bool."""
    return isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value)


def _bounds(f: dataclasses.Field) -> Bounds | None:
    return f.metadata.get(_BOUNDS)


def _is_internal(f: dataclasses.Field) -> bool:
    return bool(f.metadata.get(INTERNAL)) or not f.init


def _noun(cls) -> str:
    """What the keys of ``cls`` are called: its ``config_noun``, "field" for :func:`param` configs."""
    declared = any(_bounds(f) for f in dataclasses.fields(cls))
    return getattr(cls, "config_noun", "field" if declared else "key")


# --------------------------------------------------------------------------- describing


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, (list, tuple)):
        return "a list"
    return {str: "a string", int: "an integer", float: "a number"}.get(type(value), type(value).__name__)


def _tag(cls) -> str | None:
    """The ``type`` class attribute of a tagged-union member, else None."""
    tag = getattr(cls, TAG, None) if dataclasses.is_dataclass(cls) else None
    return tag if isinstance(tag, str) and TAG not in {f.name for f in dataclasses.fields(cls)} else None


def _vector_length(tp) -> int | None:
    """n for ``tuple[float, ..., float]`` (n numbers), else None."""
    args = typing.get_args(tp)
    if typing.get_origin(tp) is tuple and args and Ellipsis not in args and all(a in (int, float) for a in args):
        return len(args)
    return None


def describe(tp, bounds: Bounds | None = None) -> str:
    """What a field of type ``tp`` must be, in words: ``an integer in [8, 512]``, ``3 numbers >= 0``."""
    rng = bounds.text() if bounds else ""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if bounds and bounds.choices is not None:
        return f"one of {', '.join(map(repr, bounds.choices))}"
    if origin in (typing.Union, types.UnionType):
        members = [a for a in args if a is not type(None)]
        if all(_tag(a) for a in members):
            return "a table"
        return " or ".join(describe(a, bounds) for a in members)
    if origin is typing.Literal:
        return f"one of {', '.join(map(repr, args))}"
    if _vector_length(tp):
        return f"{_vector_length(tp)} numbers{rng}"
    if origin is tuple:
        return "a list" if Ellipsis in args else f"{len(args)} values"
    if dataclasses.is_dataclass(tp) or origin in (dict, collections.abc.Mapping) or tp is dict:
        return "a table"
    named = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}
    return named[tp] + rng if tp in named else "a value"


@dataclasses.dataclass(frozen=True)
class OptionSpec:
    """How a command-line option reads one config field: the scalar type argparse converts to, the choices
    (None: any value of the type), what the value must be in words, the default and the documentation."""

    kind: type
    choices: tuple | None
    what: str
    default: Any
    doc: str


def option_spec(cls, name: str) -> OptionSpec:
    """The :class:`OptionSpec` of field ``name`` of config ``cls``, from its declaration (:func:`param`), so
    that a flag's type, choices and help come from the one place the field is declared.

    >>> from mitsnerf.train.config import TrainConfig
    >>> o = option_spec(TrainConfig, "batch_rays")
    >>> o.kind.__name__, o.what, o.default
    ('int', 'an integer in [1, 4194304]', 2048)
    """
    f = {f.name: f for f in dataclasses.fields(cls)}[name]
    tp = typing.get_type_hints(cls)[name]
    bounds = _bounds(f)
    kind: Any
    choices: tuple | None
    if typing.get_origin(tp) is typing.Literal:
        kind, choices = type(typing.get_args(tp)[0]), typing.get_args(tp)
    else:
        kind, choices = tp, bounds.choices if bounds is not None else None
    if kind not in (int, float, str, bool):
        raise TypeError(f"{cls.__name__}.{name}: a {tp} field has no command-line option")
    return OptionSpec(kind, choices, describe(tp, bounds), _default(f), field_docs(cls).get(name, ""))


def field_docs(cls) -> dict[str, str]:
    """The documentation of each field of ``cls``: its :func:`param` ``doc``, else its attribute docstring."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if dataclasses.is_dataclass(klass):
            docs.update(_attribute_docstrings(klass))
    out = {}
    for f in dataclasses.fields(cls):
        if not _is_internal(f):
            bounds = _bounds(f)
            out[f.name] = (bounds.doc if bounds is not None else "") or docs.get(f.name, "")
    return out


def _attribute_docstrings(klass) -> dict[str, str]:
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
    except (OSError, TypeError, SyntaxError):
        return {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    out = {}
    for node, nxt in zip(body, body[1:]):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(nxt, ast.Expr)
                and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str)):
            out[node.target.id] = " ".join(inspect.cleandoc(nxt.value.value).split())
    return out


def doc_table(cls, nested: bool = False) -> str:
    """The fields of config ``cls`` as a markdown table: name, what it must be, default, meaning.

    With ``nested``, a field holding a config of its own is listed field by field under dotted
    names (``network.width``, the keys ``--set`` takes), with that field's own defaults.

    >>> @dataclasses.dataclass(frozen=True)
    ... class Rig:
    ...     fov: float = param(lo=0.0, hi=180.0, lo_open=True, hi_open=True, doc="field of view, degrees")
    ...     seed: int = param(0, lo=0, doc="rig randomisation")
    >>> print(doc_table(Rig))
    | field | must be | default | meaning |
    |---|---|---|---|
    | fov | a number in (0, 180) | required | field of view, degrees |
    | seed | an integer >= 0 | 0 | rig randomisation |
    """
    rows = ["| field | must be | default | meaning |", "|---|---|---|---|"]
    return "\n".join(rows + _doc_rows(cls, None, "", nested))


def _since_text(since: Since | None) -> str:
    """What a :func:`doc_table` row says of a setting added since: how a run saved before it is read."""
    if since is None:
        return ""
    if since.refuse:
        return f" (added in {since.version}: a run saved before is refused, {since.refuse})"
    return f" (added in {since.version}: a run saved before reads {json.dumps(plain(since.before))})"


def _doc_rows(cls, defaults: Any, prefix: str, nested: bool) -> list[str]:
    """Table rows of ``cls``'s fields named ``prefix + name``; defaults from the instance ``defaults`` if given."""
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    rows = []
    for f in dataclasses.fields(cls):
        if f.name not in docs:
            continue
        default = _default(f) if defaults is None else getattr(defaults, f.name)
        if nested and dataclasses.is_dataclass(hints[f.name]) and dataclasses.is_dataclass(default):
            rows += _doc_rows(hints[f.name], default, f"{prefix}{f.name}.", nested)
            continue
        shown = "required" if default is dataclasses.MISSING else json.dumps(plain(default))
        rows.append(f"| {prefix}{f.name} | {describe(hints[f.name], _bounds(f))} | {shown} | {docs[f.name] or '...'}"
                    f"{_since_text(f.metadata.get(_SINCE))} |")
    return rows


# --------------------------------------------------------------------------- from_dict


def _join(prefix: str, key: Any) -> str:
    prefix = prefix.rstrip(".")
    return f"{prefix}.{key}" if prefix else str(key)


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def from_dict(cls, data: Mapping[str, Any] | None, *, source: Any = None, prefix: str = ""):
    """Build config ``cls`` from plain ``data``; every problem is a ``SpecError(source, field, problem)``.

    Missing keys keep their defaults (a required one is "missing field"); unknown keys are
    errors with a "did you mean" hint; then the class's ``__post_init__`` runs, and a
    ``ValueError("field: problem")`` it raises is reported at ``prefix.field``. A nested field may be
    given whole (``{"network": {"width": 32}}``) or by its dotted name (``{"network.width": 32}``, as
    ``--set`` writes it), in every surface alike (:func:`_undotted`).
    """
    source = None if source is None else str(source)
    data = {} if data is None else data
    if not isinstance(data, Mapping):
        raise SpecError(source, prefix.rstrip(".") or None, f"must be a table, got {_kind(data)}")
    data = _undotted(data, source, prefix)
    fields = [f for f in dataclasses.fields(cls) if not _is_internal(f)]
    _check_unknown(cls, data, [f.name for f in fields], source, prefix)
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in fields:
        path = _join(prefix, f.name)
        if f.name in data:
            value, default = data[f.name], _default(f)
            if dataclasses.is_dataclass(default) and isinstance(value, Mapping):
                value = deep_merge(to_dict(default), value)  # a table over the field's own default
            kwargs[f.name] = _convert(hints[f.name], value, path, _bounds(f), source)
        elif _default(f) is dataclasses.MISSING:
            raise SpecError(source, path, f"missing field ({describe(hints[f.name], _bounds(f))})")
    kwargs.update({f.name: source for f in dataclasses.fields(cls) if f.metadata.get(_SOURCE)})
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise as_spec_error(exc, source, prefix) from None


def _undotted(data: Mapping, source: str | None, prefix: str) -> Mapping:
    """``data`` with its dotted keys put into their tables (:func:`apply_overrides`, over the tables given whole;
    integer parts index lists), so that ``{"field.shadow_samples": 8}`` means ``{"field": {"shadow_samples": 8}}``.

    >>> _undotted({"a": {"x": 1, "y": 2}, "a.y": 3, "b": 4}, None, "")
    {'a': {'x': 1, 'y': 3}, 'b': 4}
    """
    dotted = {k: v for k, v in data.items() if isinstance(k, str) and "." in k}
    if not dotted:
        return data
    try:
        return apply_overrides({k: v for k, v in data.items() if k not in dotted}, dotted, source)
    except SpecError as exc:
        raise as_spec_error(exc, source, prefix) from None


def check_fields(obj) -> None:
    """Check every :func:`param` field of a config instance against its type and bounds, as
    :func:`from_dict` does (for configs built directly in code); call it from ``__post_init__``.

    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Budget:
    ...     steps: int = param(10, lo=1)
    ...     def __post_init__(self):
    ...         check_fields(self)
    >>> Budget(steps=0)
    Traceback (most recent call last):
    ...
    mitsnerf.errors.SpecError: steps: must be an integer >= 1, got 0
    """
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        bounds = _bounds(f)
        if bounds is not None and not _is_internal(f):
            _convert(hints[f.name], getattr(obj, f.name), f.name, bounds, None)


def as_spec_error(exc: ValueError, source: Any, prefix: str = "") -> SpecError:
    """``exc`` (a ``ValueError("field: problem")`` or a SpecError) as a SpecError at ``prefix.field`` in ``source``."""
    if isinstance(exc, SpecError):
        where = exc.where if exc.where is not None else source
        return SpecError(where, _join(prefix, exc.field) if exc.field else (prefix.rstrip(".") or None), exc.message)
    field_name, sep, message = str(exc).partition(": ")
    if sep and _FIELD_PATH.fullmatch(field_name):
        return SpecError(source, _join(prefix, field_name), message)
    return SpecError(source, prefix.rstrip(".") or None, str(exc))


def _check_unknown(cls, data: Mapping, known: list[str], source, prefix: str) -> None:
    for key in data:
        if key not in known:
            close = _did_you_mean(cls, str(key), known)
            hint = (f" (did you mean {close}?)" if close else f" (known: {', '.join(known)})" if known
                    else " (it takes none)")
            raise SpecError(source, _join(prefix, key), f"unknown {_noun(cls)}{hint}")


def _did_you_mean(cls, key: str, known: list[str]) -> str | None:
    """What an unknown ``key`` of ``cls`` may have meant: the fields of its nested configs of that very name
    (``shadow_samples``: ``'field.shadow_samples'``), else the closest of ``known``, else the closest field of a
    nested config; None when nothing is close (the quoted names, ``"'field.shadow_samples'"``)."""
    nested = _nested_names(cls)
    same = [name for name in nested if name.rsplit(".", 1)[-1] == key]
    if same:
        return " or ".join(repr(name) for name in same[:3])
    close = difflib.get_close_matches(key, known, n=1)
    if close:
        return repr(close[0])
    leaves: dict[str, str] = {}
    for name in nested:
        leaves.setdefault(name.rsplit(".", 1)[-1], name)
    close = difflib.get_close_matches(key, list(leaves), n=1)
    return repr(leaves[close[0]]) if close else None


def _nested_names(cls, prefix: str = "") -> list[str]:
    """The dotted names of the fields of ``cls``'s nested configs, at any depth (``field.shadow_samples``)."""
    hints = typing.get_type_hints(cls)
    names: list[str] = []
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        if not _is_internal(f) and isinstance(tp, type) and dataclasses.is_dataclass(tp):
            inner = [g.name for g in dataclasses.fields(tp) if not _is_internal(g)]
            names += [f"{prefix}{f.name}.{n}" for n in inner] + _nested_names(tp, f"{prefix}{f.name}.")
    return names


def _convert(tp, value: Any, path: str, bounds: Bounds | None, source) -> Any:
    """``value`` as type ``tp`` (checked against ``bounds``), or a SpecError at ``path``."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return _convert_union(tp, value, path, bounds, source)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise SpecError(source, path, f"{_verb(bounds)} a table, got {_kind(value)}")
        return from_dict(tp, value, source=source, prefix=path)
    if origin is tuple:
        return _convert_tuple(tp, value, path, bounds, source)
    if origin in (dict, collections.abc.Mapping) or tp is dict:
        if not isinstance(value, Mapping):
            raise SpecError(source, path, f"{_verb(bounds)} a table, got {_kind(value)}")
        return value
    if tp in (int, float, bool, str) or origin is typing.Literal:
        return _convert_scalar(tp, value, path, bounds, source)
    return value


def _verb(bounds: Bounds | None) -> str:
    return "must be" if bounds is not None else "expected"


def _convert_scalar(tp, value: Any, path: str, bounds: Bounds | None, source) -> Any:
    if typing.get_origin(tp) is typing.Literal:
        ok = value in typing.get_args(tp) and isinstance(value, (str, int, bool))
    elif tp is bool:
        ok = isinstance(value, bool)
    elif tp is int:
        ok = is_int(value)
    elif tp is float:
        ok = is_number(value)
    else:
        ok = isinstance(value, str)
    if ok and bounds is not None and tp in (int, float, str):
        ok = bounds.admits(value)
    if not ok:
        above = bounds is not None and bounds.hi is not None and is_number(value) and value > bounds.hi
        why = f": {bounds.hi_why}" if above and bounds is not None and bounds.hi_why else ""
        raise SpecError(source, path, f"{_verb(bounds)} {describe(tp, bounds)}, got {value!r}{why}")
    return float(value) if tp is float else int(value) if tp is int else value


def _convert_tuple(tp, value: Any, path: str, bounds: Bounds | None, source) -> tuple:
    args = typing.get_args(tp)
    n = _vector_length(tp)
    if not isinstance(value, (list, tuple)):
        raise SpecError(source, path, f"{_verb(bounds)} {describe(tp, bounds)}, got {_kind(value)} {value!r}")
    if n is not None:  # a vector of numbers is reported whole
        what = f"{_verb(bounds)} {describe(tp, bounds)}"
        if len(value) != n:
            raise SpecError(source, path, f"{what}, got {len(value)} values")
        try:
            return tuple(_convert_scalar(a, v, path, bounds, source) for a, v in zip(args, value))
        except SpecError:
            raise SpecError(source, path, f"{what}, got {value!r}") from None
    if Ellipsis in args:
        return tuple(_convert(args[0], v, _join(path, i), bounds, source) for i, v in enumerate(value))
    if len(args) != len(value):
        raise SpecError(source, path, f"{_verb(bounds)} {len(args)} values, got {len(value)}")
    return tuple(_convert(a, v, _join(path, i), bounds, source) for i, (a, v) in enumerate(zip(args, value)))


def _convert_union(tp, value: Any, path: str, bounds: Bounds | None, source) -> Any:
    members = [a for a in typing.get_args(tp) if a is not type(None)]
    if value is None and len(members) < len(typing.get_args(tp)):
        return None
    if all(_tag(m) for m in members):
        return _convert_tagged(members, value, path, source)
    errors = []
    for member in members:
        try:
            return _convert(member, value, path, bounds, source)
        except SpecError as exc:
            errors.append((exc, _same_kind(member, value)))
    raise next((exc for exc, same in errors if same), errors[0][0])


def _same_kind(tp, value: Any) -> bool:
    """Whether ``value`` is of ``tp``'s kind (a list for a tuple type, a table for a dataclass), so that
    its error, not another member's, is the one to report."""
    if isinstance(value, (list, tuple)):
        return typing.get_origin(tp) is tuple
    table = dataclasses.is_dataclass(tp) or typing.get_origin(tp) in (dict, collections.abc.Mapping)
    if isinstance(value, Mapping):
        return table
    return not (table or typing.get_origin(tp) is tuple)


def _convert_tagged(members: list, value: Any, path: str, source) -> Any:
    """A table whose ``type`` key picks the dataclass among ``members`` (their ``type`` class attribute)."""
    if isinstance(value, tuple(members)):
        return value
    if not isinstance(value, Mapping):
        raise SpecError(source, path, f"must be a table, got {_kind(value)}")
    tags = {str(_tag(m)): m for m in members}
    kind = getattr(members[0], "config_kind", "")
    if TAG not in value:
        raise SpecError(source, _join(path, TAG), f"missing field (one of {', '.join(tags)})")
    if value[TAG] not in tags:
        what = f"unknown {kind} type" if kind else "unknown type"
        raise SpecError(source, _join(path, TAG), f"{what} {value[TAG]!r} (known: {', '.join(tags)})")
    rest = {k: v for k, v in value.items() if k != TAG}
    return from_dict(tags[value[TAG]], rest, source=source, prefix=path)


# --------------------------------------------------------------------------- saved configs


def from_saved(cls, data: Mapping[str, Any] | None, *, source: Any = None, prefix: str = ""):
    """Config ``cls`` from ``data`` that something made with it saved (a run's settings, :func:`to_dict` of all of
    them), as :func:`from_dict` reads it, but each key it lacks (added since it was saved) read as the field's
    :class:`Since` says, the default where it declares none: what the saved thing was made with, not today's
    default. A key declared unreproducible is a SpecError naming ``source``, the field and the reason.

    >>> @dataclasses.dataclass(frozen=True)
    ... class Fit:
    ...     steps: int = param(100, lo=1)
    ...     carve: bool = param(True, since=("0.1.0+7e1ef78", False))
    ...     mode: str = param("b", since=Since("0.1.0+28686ef", refuse="mode a is gone"))
    >>> from_saved(Fit, {"steps": 5, "mode": "b"}), from_dict(Fit, {"steps": 5, "mode": "b"})
    (Fit(steps=5, carve=False, mode='b'), Fit(steps=5, carve=True, mode='b'))
    >>> from_saved(Fit, {"carve": True}, source="run/config.json", prefix="method_config.")
    Traceback (most recent call last):
    ...
    mitsnerf.errors.SpecError: run/config.json: method_config.mode: not recorded: saved before 0.1.0+28686ef \
added this setting, and no value reproduces it (mode a is gone)
    """
    return from_dict(cls, _complete_saved(cls, data, str(source) if source is not None else None, prefix),
                     source=source, prefix=prefix)


def _complete_saved(cls, data: Any, source: str | None, prefix: str) -> Any:
    """``data`` with each declared key it lacks set as its :class:`Since` says, in nested tables too."""
    if not isinstance(data, Mapping):
        return data  # from_dict names the problem
    hints = typing.get_type_hints(cls)
    out = dict(data)
    for f in dataclasses.fields(cls):
        if _is_internal(f):
            continue
        path, since = _join(prefix, f.name), f.metadata.get(_SINCE)
        if f.name not in out and since is not None:
            if since.refuse:
                raise SpecError(source, path, f"not recorded: saved before {since.version} added this setting, and "
                                              f"no value reproduces it ({since.refuse})")
            out[f.name] = plain(since.before)
            continue
        value = out[f.name] if f.name in out else {} if dataclasses.is_dataclass(_default(f)) else None
        nested = _table_class(hints[f.name], value)
        if nested is not None:
            table = _complete_saved(nested, value, source, path)
            if table or f.name in out:  # a table the config lacks: over the field's own default (from_dict)
                out[f.name] = table
    return out


def _table_class(tp, value: Any):
    """The dataclass a table ``value`` of a field typed ``tp`` is read as (a tagged union's by its ``type``),
    else None."""
    if not isinstance(value, Mapping):
        return None
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return tp
    if typing.get_origin(tp) not in (typing.Union, types.UnionType):
        return None
    members = [a for a in typing.get_args(tp) if dataclasses.is_dataclass(a)]
    if members and all(_tag(m) for m in members):
        return next((m for m in members if _tag(m) == value.get(TAG)), None)
    return members[0] if len(members) == 1 else None


def saved_readings(cls, prefix: str = "") -> dict[str, Any]:
    """What :func:`from_saved` reads each key of ``cls`` as when a saved config lacks it, by dotted key (nested
    configs' keys too): its :class:`Since`'s value (``"refused: REASON"`` where none reproduces it), else its
    default.

    >>> @dataclasses.dataclass(frozen=True)
    ... class Fit:
    ...     steps: int = param(100, lo=1)
    ...     carve: bool = param(True, since=("0.1.0+7e1ef78", False))
    >>> saved_readings(Fit)
    {'steps': 100, 'carve': False}
    """
    return _readings(cls, None, prefix)


def _readings(cls, defaults: Any, prefix: str) -> dict[str, Any]:
    """:func:`saved_readings`, the defaults taken from the instance ``defaults`` where given (a nested field's own)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if _is_internal(f):
            continue
        since = f.metadata.get(_SINCE)
        default = _default(f) if defaults is None else getattr(defaults, f.name)
        if since is not None:
            out[prefix + f.name] = since.reading()
        elif dataclasses.is_dataclass(default) and not isinstance(default, type):
            out.update(_readings(type(default), default, f"{prefix}{f.name}."))
        else:
            out[prefix + f.name] = "required" if default is dataclasses.MISSING else plain(default)
    return out


# --------------------------------------------------------------------------- plain data


def to_dict(obj) -> dict:
    """A config as plain nested dicts and lists (JSON and TOML friendly) that :func:`from_dict` reads back.

    A tagged-union member starts with its ``type``; a None field whose default is None is left out.
    """
    out: dict[str, Any] = {TAG: _tag(type(obj))} if _tag(type(obj)) else {}
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if _is_internal(f) or (value is None and f.default is None):
            continue
        out[f.name] = plain(value)
    return out


def plain(value: Any) -> Any:
    """``value`` as plain data: configs as :func:`to_dict`, mappings as dicts, tuples as lists."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return to_dict(value)
    if isinstance(value, Mapping):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


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


def apply_overrides(data: Mapping[str, Any], overrides: Mapping[str, Any], source: Any = None) -> dict:
    """A plain copy of ``data`` with dotted keys replaced; integer parts index lists.

    Missing tables on the way are created (so an unknown key reaches :func:`from_dict`, which
    names it); a problem on the way is a SpecError naming ``source`` and the dotted key.

    >>> apply_overrides({"lights": [{"radiance": [0, 0, 0]}], "n": 1}, {"lights.0.radiance": [1, 1, 1], "a.b": 2})
    {'lights': [{'radiance': [1, 1, 1]}], 'n': 1, 'a': {'b': 2}}
    >>> apply_overrides({"lights": []}, {"lights.3.radiance": 1}, "x.toml")
    Traceback (most recent call last):
    ...
    mitsnerf.errors.SpecError: x.toml: lights.3.radiance: no item '3' (there are 0)
    """
    out = plain(data)
    for key, value in overrides.items():
        parts = str(key).split(".")
        node: Any = out
        for i, part in enumerate(parts):
            index: str | int = part
            if isinstance(node, list):
                if not part.isdigit() or int(part) >= len(node):
                    raise SpecError(source, str(key), f"no item {part!r} (there are {len(node)})")
                index = int(part)
            elif not isinstance(node, dict):
                raise SpecError(source, str(key), f"cannot override inside {'.'.join(parts[:i])!r}: not a table")
            if i == len(parts) - 1:
                node[index] = plain(value)
            else:
                if isinstance(node, dict) and index not in node:
                    node[index] = {}
                node = node[index]
    return out


def with_overrides(obj, overrides: Mapping[str, Any], source: Any = None):
    """A copy of config ``obj`` with dotted-key overrides (``{"network.width": 32}``), validated again."""
    return from_dict(type(obj), apply_overrides(to_dict(obj), overrides, source), source=source)


def parse_value(text: str) -> Any:
    """A command-line value: JSON where it parses (numbers, lists, true/false), else the string itself.

    >>> parse_value("16"), parse_value("[1, 1, 1]"), parse_value("true"), parse_value("sphere")
    (16, [1, 1, 1], True, 'sphere')
    """
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def search_dirs(env_var: str, shipped: Path) -> list[Path]:
    """Where named files are looked up, first match first: the user's directories listed in
    ``$env_var`` (``os.pathsep``-separated), then the ``shipped`` one (package data).

    >>> import os
    >>> import tempfile
    >>> mine, ours = tempfile.mkdtemp(suffix="mine"), tempfile.mkdtemp(suffix="ours")
    >>> os.environ["MITSNERF_DOCTEST_DIRS"] = os.pathsep.join([mine, ours])
    >>> [p.name[-4:] for p in search_dirs("MITSNERF_DOCTEST_DIRS", Path("lib"))]
    ['mine', 'ours', 'lib']
    >>> del os.environ["MITSNERF_DOCTEST_DIRS"]

    A directory listed there that does not exist is refused, naming the variable (a typo would otherwise
    leave the user's specs silently unused).
    """
    mine = [Path(p) for p in os.environ.get(env_var, "").split(os.pathsep) if p]
    for d in mine:
        if not d.is_dir():
            raise SpecError(f"${env_var}", None, f"{d}: no such directory")
    return mine + [Path(shipped)]


def named_files(dirs: list[Path], suffix: str = ".toml") -> dict[str, Path]:
    """Each name (a file's stem) found in ``dirs`` -> its file in the first directory that has one, by name."""
    out: dict[str, Path] = {}
    for d in dirs:
        for path in sorted(d.glob(f"*{suffix}")) if d.is_dir() else ():
            out.setdefault(path.stem, path)
    return dict(sorted(out.items()))


def read_toml(path: str | Path, what: str = "a TOML file") -> dict:
    """A TOML file's data; a SpecError naming the file when it cannot be read or parsed (``what``
    the file should be, for a directory's message)."""
    path = Path(path)
    if path.is_dir():
        raise SpecError(path, None, f"is a directory, not {what}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SpecError(path, None, f"cannot read: {exc.strerror or exc}") from None
    try:
        return tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise SpecError(path, None, f"not a text file (invalid UTF-8 at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(path, None, f"TOML syntax error: {exc}") from None
