"""Fields and rules that several volume families' parameter dataclasses share.

Each family's ``Params`` is a frozen dataclass of :func:`mitsnerf.config.param` fields: the range
and the documentation of a field sit on the field, and :func:`mitsnerf.config.from_dict` checks
them (``mitsnerf.volumes.make_params``). Rules between fields stay in the class's
``__post_init__``, raising ``ValueError("field: problem")``, like :func:`check_fbm` here.

>>> from dataclasses import dataclass
>>> from mitsnerf.config import from_dict
>>> @dataclass(frozen=True)
... class Noise:
...     octaves: int = octaves(5)
...     base_frequency: float = base_frequency(3.0)
...     persistence: float = persistence(0.5)
...     lacunarity: float = lacunarity(2.0)
...     def __post_init__(self):
...         check_fbm(self)
>>> from_dict(Noise, {"octaves": 0})
Traceback (most recent call last):
...
mitsnerf.errors.SpecError: octaves: must be an integer >= 1, got 0
>>> from_dict(Noise, {"octaves": 12})  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
mitsnerf.errors.SpecError: octaves: the finest octave's frequency 3 * 2^11 = 6144 exceeds 256; lower ...
"""

from __future__ import annotations

from typing import Any

from mitsnerf.config import param

#: The noise lattice's period (:data:`mitsnerf.volumes.noise.PERIOD`): no octave may be finer.
FINEST_FREQUENCY = 256.0


def octaves(default: int, doc: str = "fBm octaves") -> Any:
    return param(default, lo=1, doc=doc)


def base_frequency(default: float, doc: str = "lowest octave, lattice cells per unit length") -> Any:
    return param(default, lo=0.0, hi=64.0, lo_open=True, doc=doc)


def persistence(default: float) -> Any:
    return param(default, lo=0.0, hi=1.0, lo_open=True, doc="amplitude ratio between octaves")


def lacunarity(default: float) -> Any:
    return param(default, lo=1.5, hi=4.0, doc="frequency ratio between octaves")


def albedo(default: tuple[float, float, float]) -> Any:
    return param(default, lo=0.0, hi=1.0, doc="constant single-scattering albedo, RGB")


def check_fbm(params: Any) -> None:
    """The fBm fields' rule (see :func:`mitsnerf.volumes.noise.fbm`): the finest octave's frequency
    ``base_frequency * lacunarity^(octaves - 1)`` must stay <= 256, the noise lattice's period
    (beyond it the pattern would repeat inside the box)."""
    finest = params.base_frequency * params.lacunarity ** (params.octaves - 1)
    if finest > FINEST_FREQUENCY:
        raise ValueError(
            f"octaves: the finest octave's frequency {params.base_frequency:g} * "
            f"{params.lacunarity:g}^{params.octaves - 1} = {finest:g} exceeds {FINEST_FREQUENCY:g}; "
            "lower octaves, base_frequency or lacunarity"
        )


def check_edge_softness(params: Any) -> None:
    """``edge_softness <= radius``: a spherical envelope's fall-off lies inside its radius."""
    if params.edge_softness > params.radius:
        raise ValueError(f"edge_softness: must be <= radius ({params.radius:g}), got {params.edge_softness:g}")
