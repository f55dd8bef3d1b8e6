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

A broken plugin (an import error, a module that calls ``sys.exit`` while imported, an object of the
wrong type, a malformed variable entry, a ``.py`` file whose name would replace another module) is one
line in :attr:`Registry.problems`, naming the entry point or variable entry and the problem; every other
entry keeps working. Asking for a broken entry by name raises that line.

A name means one entry. A plugin cannot replace a built-in, nor a later source an earlier one: a name
claimed twice keeps its first claimant in the mapping (so listings show it), the later claim is a problem
line, and :meth:`Registry.why_not` refuses the name, naming both, until one is renamed; so neither is used
silently where a user asked for the name.

Each entry carries its :class:`Source`; a plugin's :attr:`Source.version` (its distribution's name and
version, and a sha256 of its package's Python source) is what a benchmark cell's or a dataset's key
covers beyond mitsnerf's own version, so editing a plugin reruns what it decides, and nothing else.

>>> parse_variable("MITSNERF_METHODS", "a=pkg.mod:A,b=./b.py:Model:c=mod:obj.attr")
([('a', 'pkg.mod', 'A'), ('b', './b.py', 'Model'), ('c', 'mod', 'obj.attr')], {})
>>> entries, problems = parse_variable("MITSNERF_METHODS", "a=pkg,b=m:B")
>>> entries
[('b', 'm', 'B')]
>>> print(problems["a"])
MITSNERF_METHODS: 'a=pkg': not NAME=MODULE:ATTR (no ':ATTR' after the module: which object to register?)
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
        """None if ``name`` may be used, else the one line saying why not: unknown (naming the known
        entries), broken (and why), or claimed twice (naming both claims: the module docstring). Every
        place a user names an entry asks this first.

        >>> r = Registry("colour", {"red": Entry("red", 1, Source(BUILT_IN, "here"))},
        ...              {"red": "MY_COLOURS: red=x:y: the name 'red' is taken by the built-in colour (here)"})
        >>> r.why_not("red")
        "colour 'red' is claimed twice: MY_COLOURS: red=x:y: the name 'red' is taken by the built-in colour (here)"
        """
        if isinstance(name, str) and name in self.problems:
            state = "claimed twice" if name in self.entries else "broken"
            return f"{self.what} {name!r} is {state}: {self.problems[name]}"
        if isinstance(name, str) and name in self.entries:
            return None
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
    (default ``os.environ``). A name an earlier source claimed is a problem, never an override (the module
    docstring)."""
    environ = os.environ if environ is None else environ
    entries: dict[str, Entry[T]] = {}
    claims: dict[str, str] = {}
    for name, value, source in _built_ins(kind):
        entries[name] = Entry(name, kind.check(name, value), source)
        claims[name] = f"the built-in {kind.what} ({source.where}), which a plugin cannot replace: rename the plugin"
    problems: dict[str, str] = {}
    for name, loader, where in _plugins(kind, environ.get(kind.variable, ""), problems):
        if name in claims:
            line = f"{where}: the name {name!r} is taken by {claims[name]} (until then {name!r} is refused)"
            problems[name] = f"{problems[name]}; {line}" if name in problems else line
            continue
        claims[name] = f"{where}: rename one of them"
        try:
            value, source = loader()
            entries[name] = Entry(name, kind.check(name, value), source)
        except Exception as exc:  # noqa: BLE001 (a plugin's import may raise anything: the plugin's problem, not ours)
            problems[name] = f"{where}: {_why(exc)}"
        except SystemExit as exc:  # sys.exit in a plugin must not end every command, the built-ins' included
            problems[name] = f"{where}: the module called sys.exit({exc.code!r}) while it was imported; " \
                             "a plugin module may only define things"
    return Registry(kind.what, MappingProxyType(entries), MappingProxyType(problems))


def _why(exc: Exception) -> str:
    """What a plugin that failed to load did: a :class:`PluginError`'s own sentence, else the exception."""
    return str(exc) if isinstance(exc, PluginError) else f"{type(exc).__name__}: {exc}"


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
    parsed, malformed = parse_variable(kind.variable, variable)
    problems.update(malformed)
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
    """A dotted module name, or a ``.py`` file's path (imported under its stem's name, :func:`file_module_name`)."""
    if not (text.endswith(".py") or "/" in text or os.sep in text):
        return importlib.import_module(text)
    path = Path(text).expanduser().resolve()
    if not path.is_file():
        raise PluginError(f"no such file {str(path)!r}")
    name = file_module_name(path)
    if name in sys.modules:
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


def file_module_name(path: Path) -> str:
    """The module name a plugin's ``.py`` file is imported under: its stem, registered in ``sys.modules``
    (dataclasses and pickling look classes up there). A :class:`PluginError` if that name is another
    module's, already imported, of the standard library or on ``sys.path``: importing the file under it
    would replace that module for every other user of it (a ``json.py`` breaks the built-ins).

    >>> file_module_name(Path("/tmp/json.py"))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    mitsnerf.plugins.PluginError: '/tmp/json.py' would be imported as module 'json', which would replace Python's ...
    """
    name = path.stem
    if "." in name or not name:
        raise PluginError(f"{str(path)!r}: {name!r} is not a module name (no '.'); rename the file")
    loaded = sys.modules.get(name)
    file = getattr(loaded, "__file__", None)
    if file and Path(file).resolve() == path:
        return name  # imported before (by an earlier registry, or the other registry)
    if name in sys.stdlib_module_names:
        return _shadow(path, name, f"Python's standard-library module {name}")
    if loaded is not None:
        return _shadow(path, name, f"the module {name} already imported ({file or 'built into Python'})")
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        spec = None
    origin = None if spec is None else spec.origin  # None: a namespace package (a bare directory), hidden harmlessly
    if origin and Path(origin).resolve() != path:
        return _shadow(path, name, f"the module {name} ({origin})")
    return name


def _shadow(path: Path, name: str, what: str) -> str:
    raise PluginError(f"{str(path)!r} would be imported as module {name!r}, which would replace {what}; "
                      "rename the file")


def parse_variable(variable: str, text: str) -> tuple[list[tuple[str, str, str]], dict[str, str]]:
    """``([(name, module, attr)], {key: problem})`` of a ``NAME=MODULE:ATTR`` list separated by ``,`` or ``:``
    (see the module docstring). An item that is not one is a problem line naming the variable and the item,
    keyed by its NAME (so asking for that name says why), or by its text where it has none; the items beside
    it are parsed as usual."""
    out, problems = [], {}
    for chunk in filter(None, (c.strip() for c in text.split(","))):
        for item in re.split(rf":(?={_NAME}=)", chunk):
            match = _ENTRY.fullmatch(item)
            if match is not None:
                out.append((match["name"], match["module"], match["attr"]))
                continue
            name, eq, rest = item.partition("=")
            key = name if eq and re.fullmatch(_NAME, name) else item
            problems[key] = f"{variable}: {item!r}: not NAME=MODULE:ATTR ({_malformed(name, eq, rest)})"
    return out, problems


def _malformed(name: str, eq: str, rest: str) -> str:
    """Which part of ``NAME=MODULE:ATTR`` an item lacks (``name``, ``eq``, ``rest``: the item split at its
    first ``=``)."""
    if not eq:
        return "no '=': which name to register it under?"
    if not re.fullmatch(_NAME, name):
        return f"{name!r} is not a NAME: letters, digits, '_', '.', '-', not starting with one of the last three"
    module, colon, attr = rest.rpartition(":")
    if not colon or not module:
        return "no ':ATTR' after the module: which object to register?"
    return f"{attr!r} is not an attribute path (Python names separated by '.')"


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
