"""What a field is, as typed protocols: the renderers, the scores and the export take any object that has
these methods, and test for a capability with ``isinstance`` (the protocols are runtime-checkable).

A :class:`Field` is ``field(x, d) -> (rgb, sigma)``: Array3f positions and directions of width M in,
Array3f colour and Float extinction of width M out. A :class:`DensityField` also answers ``density(x)``, the
extinction from the position alone, which is what the density scores and ``mitsnerf export`` read.

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

from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class Field(Protocol):
    """``field(x, d) -> (rgb, sigma)`` (module docstring)."""

    def __call__(self, x: Any, d: Any, /) -> tuple[Any, Any]: ...


@runtime_checkable
class DensityField(Field, Protocol):
    """A field whose extinction can be queried from the position alone: ``density(x) -> sigma``."""

    def density(self, x: Any, /) -> Any: ...
