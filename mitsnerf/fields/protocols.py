"""What a field is, as typed protocols: the renderers, the scores and the export take any object that has
these methods, and test for a capability with ``isinstance`` (the protocols are runtime-checkable).

A :class:`Field` is ``field(x, d) -> (rgb, sigma)``: Array3f positions and directions of width M in,
Array3f colour and Float extinction of width M out. A :class:`DensityField` also answers ``density(x)``, the
extinction from the position alone, which is what the density scores and ``mitsnerf export`` read.

A field of a chromatic medium returns an Array3f ``sigma``, one extinction per colour channel, and says so
with an attribute ``sigma_channels = 3`` (absent: 1). ``render_rays`` and ``composite`` need nothing more;
``march_rays`` and ``eval_masked`` read the attribute to size their loop state, and the replayed march
(one extinction per ray) refuses such a field.

>>> def constant(x, d):
...     return x, 1.0
>>> isinstance(constant, Field), isinstance(constant, DensityField)
(True, False)
>>> class Fog:
...     def __call__(self, x, d):
...         return x, self.density(x)
...     def density(self, x):
...         return 0.5
>>> isinstance(Fog(), DensityField)
True
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class Field(Protocol):
    """``field(x, d) -> (rgb, sigma)`` (module docstring)."""

    def __call__(self, x: Any, d: Any, /) -> tuple[Any, Any]: ...


@runtime_checkable
class DensityField(Field, Protocol):
    """A field whose extinction can be queried from the position alone: ``density(x) -> sigma``."""

    def density(self, x: Any, /) -> Any: ...


@runtime_checkable
class TextureField(Field, Protocol):
    """A field made of trilinear texture lookups at one point followed by a pointwise head::

        field(x, d) == field.head([tex.eval(field.box.to_unit(x)) for tex in field.textures()], x, d)

    ``textures()``: ``dr.Texture3f`` s built with ``use_accel=False``, linear filtering and clamped borders,
    whose tensors (``tex.tensor()``, (Z, Y, X, C)) are the field's parameters; ``head(values, x, d) ->
    (rgb, sigma)`` takes each texture's channels (a list of Floats per texture). What this structure buys: a
    renderer can differentiate the head alone and scatter the lookups' adjoints into the grids itself
    (:mod:`mitsnerf.render.replay`), instead of going through the texture's own derivative.
    """

    box: Any

    def textures(self) -> Sequence[Any]: ...

    def head(self, values: Sequence[Sequence[Any]], x: Any, d: Any, /) -> tuple[Any, Any]: ...
