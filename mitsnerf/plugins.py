"""Registries that code outside the package joins: built-ins, entry points, an environment variable.

The methods (:mod:`mitsnerf.methods`) and the volume families (:mod:`mitsnerf.volumes`) are each one
:class:`Registry`, filled from three sources, every entry declared once, where it is written:

1. **built-in**: every module of the package that declares the registry's module attribute
   (``METHOD = NeRFModel`` in ``mitsnerf/methods/nerf.py``, ``FAMILY = Family(...)`` in
   ``mitsnerf/volumes/cloud.py``);
2. **entry point**: the distribution's entry points in the registry's group (``mitsnerf.methods``,
   ``mitsnerf.volumes``); the entry point's name is the entry's name::

       [project.entry-points."mitsnerf.methods"]
       tensorf = "mitsnerf_tensorf:TensoRFModel"

3. **variable**: an environment variable (``MITSNERF_METHODS``, ``MITSNERF_VOLUMES``) of
   ``NAME=MODULE:ATTR`` entries separated by ``,`` or ``:``, for code that is not installed; ``MODULE``
   is a dotted module name on ``sys.path`` or the path of a ``.py`` file.

A broken plugin (an import error, an object of the wrong type, a name taken by an earlier source)
is one line in :attr:`Registry.problems`, naming the entry point or variable and the problem; every
other entry keeps working. Asking for a broken entry by name raises that line.

Each entry carries its :class:`Source`; a plugin's :attr:`Source.version` (its distribution's name and
version, and a sha256 of its package's Python source) is what a benchmark cell's or a dataset's key
covers beyond mitsnerf's own version, so editing a plugin reruns what it decides, and nothing else.

>>> parse_variable("MITSNERF_METHODS", "a=pkg.mod:A,b=./b.py:Model:c=mod:obj.attr")
[('a', 'pkg.mod', 'A'), ('b', './b.py', 'Model'), ('c', 'mod', 'obj.attr')]
>>> parse_variable("MITSNERF_METHODS", "a=pkg")
Traceback (most recent call last):
...
mitsnerf.plugins.PluginError: MITSNERF_METHODS: 'a=pkg': not NAME=MODULE:ATTR
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import importlib.util
import os
import pkgutil
import re
import sys
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType, ModuleType
from typing import Any, Generic, TypeVar

from mitsnerf.errors import unknown

T = TypeVar("T")

BUILT_IN, ENTRY_POINT, VARIABLE = "built-in", "entry point", "variable"

_NAME = r"[A-Za-z0-9][A-Za-z0-9_.-]*"
_ENTRY = re.compile(rf"(?P<name>{_NAME})=(?P<module>[^=,]+):(?P<attr>[A-Za-z_][\w.]*)")


class PluginError(ValueError):
    """A plugin that cannot join a registry; the message is the one line that says why."""


@dataclass(frozen=True)
class Source:
    """Where a registry entry came from.

    Attributes:
        kind: ``"built-in"``, ``"entry point"`` or ``"variable"``.
        where: the module (built-in), ``GROUP: NAME = VALUE (DIST VERSION)`` (entry point) or
            ``VARIABLE: NAME=VALUE`` (variable).
        version: None for built-ins (mitsnerf's own version covers them); a plugin's
            ``DIST==VERSION sha256:HEX`` (entry point) or ``sha256:HEX`` (variable), HEX over its
            package's Python files.
    """

    kind: str
    where: str
    version: str | None = None


@dataclass(frozen=True)
class Entry(Generic[T]):
    """One registered object with its name and source."""

    name: str
    value: T
    source: Source


@dataclass(frozen=True)
class Registry(Mapping[str, T]):
    """A read-only ``name -> value`` mapping of the loaded entries, with the problems of the broken ones.

    >>> r = Registry("colour", {"red": Entry("red", 1, Source(BUILT_IN, "here"))},
    ...              {"blue": "entry point colours: blue = x:y: ModuleNotFoundError: No module named 'x'"})
    >>> r["red"], list(r), r.entry("red").source.kind
    (1, ['red'], 'built-in')
    >>> r["blue"]
    Traceback (most recent call last):
    ...
    KeyError: "colour 'blue' is broken: entry point colours: blue = x:y: ModuleNotFoundError: No module named 'x'"
    """

    what: str
    """What an entry is, for messages (``"method"``)."""
    entries: Mapping[str, Entry[T]]
    problems: Mapping[str, str]
    """name (or the variable's text) -> the one line saying why that plugin is not loaded."""

    def __getitem__(self, name: str) -> T:
        return self.entry(name).value

    def __iter__(self) -> Iterator[str]:
        return iter(self.entries)

    def __len__(self) -> int:
        return len(self.entries)

    def entry(self, name: str) -> Entry[T]:
        """The entry ``name``; a KeyError saying it is unknown (naming the known ones) or broken (and why)."""
        if name in self.entries:
            return self.entries[name]
        raise KeyError(self.why_not(name))

    def why_not(self, name: Any) -> str | None:
        """None if ``name`` is registered, else the one line saying why not: unknown (naming the known
        entries) or broken (and why)."""
        if isinstance(name, str) and name in self.entries:
            return None
        if isinstance(name, str) and name in self.problems:
            return f"{self.what} {name!r} is broken: {self.problems[name]}"
        return unknown(self.what, name, sorted(self.entries))


@dataclass(frozen=True)
class Kind(Generic[T]):
    """How one registry is filled: see the module docstring.

    ``check(name, obj)`` returns the value to register, or raises :class:`PluginError` saying what is
    wrong with ``obj`` (a built-in that fails it is a bug, raised as is).
    """

    what: str
    package: str
    """The package whose modules hold the built-ins."""
    attribute: str
    """The module attribute a built-in declares itself in."""
    group: str
    variable: str
    check: Callable[[str, Any], T]


def load(kind: Kind[T], environ: Mapping[str, str] | None = None) -> Registry[T]:
    """The registry ``kind`` describes: built-ins, then entry points, then the variable in ``environ``
    (default ``os.environ``). An entry whose name an earlier source took is a problem, not an override."""
    environ = os.environ if environ is None else environ
    entries: dict[str, Entry[T]] = {}
    problems: dict[str, str] = {}
    for name, value, source in _built_ins(kind):
        entries[name] = Entry(name, kind.check(name, value), source)
    for name, loader, where in _plugins(kind, environ.get(kind.variable, ""), problems):
        if name in entries:
            problems[name] = f"{where}: the name {name!r} is taken by the {entries[name].source.kind} " \
                             f"{kind.what} ({entries[name].source.where}); rename it"
            continue
        try:
            value, source = loader()
            entries[name] = Entry(name, kind.check(name, value), source)
        except PluginError as exc:
            problems[name] = f"{where}: {exc}"
        except Exception as exc:  # a plugin's import may raise anything: it is the plugin's problem, not ours
            problems[name] = f"{where}: {type(exc).__name__}: {exc}"
    return Registry(kind.what, MappingProxyType(entries), MappingProxyType(problems))


def _built_ins(kind: Kind) -> Iterator[tuple[str, Any, Source]]:
    package = importlib.import_module(kind.package)
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{kind.package}.{info.name}")
        if hasattr(module, kind.attribute):
            value = getattr(module, kind.attribute)
            yield _builtin_name(value), value, Source(BUILT_IN, module.__name__)


def _builtin_name(value: Any) -> str:
    name = getattr(value, "name", None)
    if not isinstance(name, str) or not name:
        raise TypeError(f"built-in {value!r} declares no name")
    return name


def _plugins(kind: Kind, variable: str, problems: dict[str, str]):
    """``(name, loader, where)`` of every entry point and variable entry; ``loader()`` imports it."""
    for ep in sorted(importlib.metadata.entry_points(group=kind.group), key=lambda e: e.name):
        where = f"entry point {kind.group}: {ep.name} = {ep.value}"
        yield ep.name, (lambda ep=ep, where=where: _load_entry_point(ep, where)), where
    try:
        parsed = parse_variable(kind.variable, variable)
    except PluginError as exc:
        problems[kind.variable] = str(exc)
        return
    for name, module, attr in parsed:
        where = f"{kind.variable}: {name}={module}:{attr}"
        yield name, (lambda m=module, a=attr, where=where: _load_variable_entry(m, a, where)), where


def _load_entry_point(ep, where: str) -> tuple[Any, Source]:
    value = ep.load()
    dist = ep.dist
    label = f"{dist.metadata['Name']}=={dist.version}" if dist is not None else "unknown distribution"
    module = sys.modules[ep.module]
    return value, Source(ENTRY_POINT, f"{where} ({label})", f"{label} {source_digest(module)}")


def _load_variable_entry(module_text: str, attr: str, where: str) -> tuple[Any, Source]:
    module = _import_module(module_text)
    value: Any = module
    for part in attr.split("."):
        if not hasattr(value, part):
            raise PluginError(f"module {module.__name__!r} has no attribute {attr!r}")
        value = getattr(value, part)
    return value, Source(VARIABLE, where, source_digest(module))


def _import_module(text: str) -> ModuleType:
    """A dotted module name, or a ``.py`` file's path (imported under its stem's name)."""
    if not (text.endswith(".py") or "/" in text or os.sep in text):
        return importlib.import_module(text)
    path = Path(text).expanduser().resolve()
    if not path.is_file():
        raise PluginError(f"no such file {str(path)!r}")
    name = path.stem
    if name in sys.modules and getattr(sys.modules[name], "__file__", None) == str(path):
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise PluginError(f"{str(path)!r} is not a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look classes up by module name
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def parse_variable(variable: str, text: str) -> list[tuple[str, str, str]]:
    """``[(name, module, attr)]`` of a ``NAME=MODULE:ATTR`` list separated by ``,`` or ``:`` (see the
    module docstring); a :class:`PluginError` naming the variable and the first entry that is not one."""
    out = []
    for chunk in filter(None, (c.strip() for c in text.split(","))):
        for item in re.split(rf":(?={_NAME}=)", chunk):
            match = _ENTRY.fullmatch(item)
            if match is None:
                raise PluginError(f"{variable}: {item!r}: not NAME=MODULE:ATTR")
            out.append((match["name"], match["module"], match["attr"]))
    return out


def source_digest(module: ModuleType) -> str:
    """``sha256:HEX`` over the Python files of ``module``'s top-level package (the module's own file
    when it is not in a package), each named by its path inside the package, in sorted order."""
    top = sys.modules.get(module.__name__.partition(".")[0], module)
    paths = getattr(top, "__path__", None)
    if paths:
        roots = [Path(p) for p in paths]
        files = sorted((f.relative_to(r).as_posix(), f) for r in roots for f in r.rglob("*.py"))
    else:
        file = Path(getattr(module, "__file__", "") or "")
        files = [(file.name, file)] if file.is_file() else []
    digest = hashlib.sha256()
    for rel, f in files:
        digest.update(rel.encode() + b"\0" + f.read_bytes() + b"\0")
    return f"sha256:{digest.hexdigest()[:16]}"
