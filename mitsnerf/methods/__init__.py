"""The registry of methods: name -> :class:`Method` (its model type, config type and source).

Filled from three sources (:mod:`mitsnerf.plugins`), each method declared once, where it is written:

- the built-ins: each module of this package that declares ``METHOD = SomeModel``;
- the ``mitsnerf.methods`` entry points of installed distributions (the entry point's name is the
  method's name, its object the model class);
- ``MITSNERF_METHODS="name=module:Class,other=path/to/file.py:Class"``, for code that is not installed.

What a method must be is :mod:`mitsnerf.methods.base`'s contract; a plugin that breaks it is refused
with one line (:func:`methods` ``.problems``), and the other methods keep working. What only a built
model shows (its parameters) :func:`check_model` checks before training, with a
:class:`~mitsnerf.errors.MethodError`.

>>> sorted(methods())[:2]
['mitsuba-inverse', 'nerf']
>>> get_method("ngp").source.kind, get_method("ngp").config_type.__name__
('built-in', 'NGPMethodConfig')
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import drjit as dr

from mitsnerf.errors import MethodError
from mitsnerf.methods.base import MethodConfig, Model, RendersRays, TrainsOnPixels, TrainsOnViews
from mitsnerf.plugins import Entry, Kind, PluginError, Registry, Source, load

#: The environment variable that registers methods which are not installed.
VARIABLE = "MITSNERF_METHODS"
#: The entry-point group of installed plugin methods.
GROUP = "mitsnerf.methods"


@dataclass(frozen=True)
class Method:
    """A registered method."""

    name: str
    model_type: type[Model]
    source: Source
    """Where it came from: built-in, entry point or variable, with the plugin's version."""

    @property
    def config_type(self) -> type[MethodConfig]:
        return self.model_type.config_type

    @property
    def description(self) -> str:
        return self.model_type.description

    @property
    def tiny(self) -> Mapping[str, Any]:
        """Overrides making the method's smallest configuration."""
        return self.model_type.tiny


def _check_rung(what: str, obj: type[Model]) -> None:
    """``rung`` one of :data:`mitsnerf.oracle.rungs.RUNGS`, ``knows`` a tuple of words."""
    from mitsnerf.oracle.rungs import RUNGS

    if obj.rung not in RUNGS:
        raise PluginError(f"{what}.rung must be one of {', '.join(RUNGS)}, got {obj.rung!r}")
    if not isinstance(obj.knows, tuple) or not all(isinstance(k, str) and k.strip() for k in obj.knows):
        raise PluginError(f"{what}.knows must be a tuple of words (what it is given besides the images), "
                          f"got {obj.knows!r}")


def check_method(name: str, obj: Any) -> type[Model]:
    """``obj`` if it is a method's model class that keeps :mod:`mitsnerf.methods.base`'s contract, else a
    :class:`~mitsnerf.plugins.PluginError` saying which part it breaks."""
    what = f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', type(obj).__name__)}"
    if not (inspect.isclass(obj) and issubclass(obj, Model)):
        raise PluginError(f"{what} is not a mitsnerf.methods.base.Model subclass")
    if inspect.isabstract(obj):
        missing = ", ".join(sorted(obj.__abstractmethods__))
        raise PluginError(f"{what} leaves abstract methods unwritten: {missing}")
    if not any(issubclass(obj, kind) for kind in (RendersRays, TrainsOnPixels, TrainsOnViews)):
        raise PluginError(f"{what} neither renders rays (subclass RayModel), trains on pixels (subclass PixelModel) "
                          "nor trains on views (subclass ViewModel)")
    _check_config_type(what, getattr(obj, "config_type", None))
    if not isinstance(getattr(obj, "description", None), str) or not obj.description.strip():
        raise PluginError(f"{what}.description must be a one-line string")
    _check_rung(what, obj)
    try:
        inspect.signature(obj).bind(None, None, 0)
    except TypeError:
        raise PluginError(f"{what}'s constructor must take (config, scene, seed), "
                          f"not {inspect.signature(obj)}") from None
    return obj


def _check_config_type(what: str, config_type: Any) -> None:
    if not (inspect.isclass(config_type) and issubclass(config_type, MethodConfig)):
        raise PluginError(f"{what}.config_type must be a dataclass subclassing mitsnerf.methods.base.MethodConfig, "
                          f"got {config_type!r}")
    if not config_type.__dataclass_params__.frozen:  # type: ignore[attr-defined]
        raise PluginError(f"{what}.config_type must be a frozen dataclass")
    required = [f.name for f in dataclasses.fields(config_type)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if required:
        raise PluginError(f"{what}.config_type: every field needs a default; {', '.join(required)} has none")


KIND = Kind("method", "mitsnerf.methods", "METHOD", GROUP, VARIABLE, check_method)


def methods() -> Registry[Method]:
    """Every registered method, by name (built-ins first, then plugins by name); broken plugins in ``.problems``."""
    return _methods(os.environ.get(VARIABLE, ""), tuple(sys.path))


@functools.lru_cache(maxsize=8)
def _methods(variable: str, path: tuple[str, ...]) -> Registry[Method]:
    """The registry for ``variable``'s text and ``path`` (entry points are found on ``sys.path``)."""
    loaded = load(KIND, {VARIABLE: variable})
    entries = {name: Entry(name, Method(name, e.value, e.source), e.source) for name, e in loaded.entries.items()}
    return Registry(loaded.what, entries, loaded.problems)


def check_model(method: Method, model: Model) -> None:
    """Raise :class:`~mitsnerf.errors.MethodError` naming ``method`` and its source unless ``model.parameters()``
    is what the optimiser needs: a non-empty mapping (a ``drjit.nn`` module or a dict) of names to Dr.Jit
    floating-point arrays or tensors."""
    where = f"method {method.name!r} ({method.source.where})"
    params = model.parameters()
    if not isinstance(params, Mapping):
        raise MethodError(where, "parameters()", f"returned a {type(params).__name__}, not a mapping of names to "
                          "Dr.Jit arrays (a drjit.nn module or a dict)")
    if not params:
        raise MethodError(where, "parameters()", "returned nothing to train: a method optimises at least one Dr.Jit "
                          "array (return a drjit.nn module or a dict of name -> array, and render from those values)")
    for key, value in params.items():
        if not (isinstance(key, str) and dr.is_array_v(value) and dr.is_float_v(value)):
            raise MethodError(where, f"parameters()[{key!r}]", f"is a {type(value).__name__}, not a Dr.Jit "
                              "floating-point array or tensor (what the optimiser can step)")


def get_method(name: str) -> Method:
    """The method ``name``; a KeyError naming the known methods, or why a plugin of that name is broken."""
    return methods()[name]

