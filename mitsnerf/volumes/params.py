"""Validators for family parameter dataclasses.

Each checks one value and returns it normalised (ints accepted as floats, lists as tuples, as TOML
gives them), or raises ``ValueError`` whose message starts with the field name, so the spec layer
can prefix the file::

    >>> check_int("octaves", 0, lo=1)
    Traceback (most recent call last):
    ...
    ValueError: octaves: must be an integer >= 1, got 0
    >>> check_float("radius", 1, lo=0.0, hi=0.45, lo_open=True)
    Traceback (most recent call last):
    ...
    ValueError: radius: must be a number in (0, 0.45], got 1
    >>> check_rgb("albedo", [0.5, 1, 0.25])
    (0.5, 1.0, 0.25)

Use them in a frozen dataclass's ``__post_init__`` through :func:`normalise`.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any


def _is_int(value: Any) -> bool:
    return isinstance(value, Integral) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool)


def range_text(lo, hi, lo_open: bool = False, hi_open: bool = False) -> str:
    """How an allowed range reads in an error message: `` in [0, 1)``, `` >= 1``, ``""``."""
    if lo is not None and hi is not None:
        return f" in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if lo is not None:
        return f" {'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f" {'<' if hi_open else '<='} {hi:g}"
    return ""


def check_int(name: str, value: Any, lo: int | None = None, hi: int | None = None) -> int:
    """An integer (not bool, not float) in ``[lo, hi]``."""
    text = f"{name}: must be an integer{range_text(lo, hi)}, got {value!r}"
    if not _is_int(value):
        raise ValueError(text)
    value = int(value)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ValueError(text)
    return value


def check_float(
    name: str,
    value: Any,
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> float:
    """A finite real number (int accepted) in the given interval, returned as float."""
    text = f"{name}: must be a number{range_text(lo, hi, lo_open, hi_open)}, got {value!r}"
    if not _is_number(value) or not math.isfinite(value):
        raise ValueError(text)
    value = float(value)
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise ValueError(text)
    if hi is not None and (value >= hi if hi_open else value > hi):
        raise ValueError(text)
    return value


def check_rgb(name: str, value: Any) -> tuple[float, float, float]:
    """Three numbers in [0, 1] (a list or tuple), returned as a tuple of floats."""
    text = f"{name}: must be 3 numbers in [0, 1], got {value!r}"
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 3:
        raise ValueError(text)
    if not all(_is_number(c) and 0.0 <= c <= 1.0 for c in value):
        raise ValueError(text)
    return tuple(float(c) for c in value)


def check_choice(name: str, value: Any, choices: tuple[str, ...]) -> str:
    """One of the given strings."""
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name}: must be one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def check_fbm(octaves: Any, base_frequency: Any, persistence: Any, lacunarity: Any) -> dict[str, Any]:
    """The four fBm fields shared by noise families (see :func:`mitsnerf.volumes.noise.fbm`).

    The finest octave's frequency ``base_frequency * lacunarity^(octaves - 1)`` must stay <= 256,
    the noise lattice's period (beyond it the pattern would repeat inside the box).

    >>> check_fbm(12, 4.0, 0.5, 2.0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: octaves: the finest octave's frequency 4 * 2^11 = 8192 exceeds 256; lower ...
    """
    out = {
        "octaves": check_int("octaves", octaves, lo=1),
        "base_frequency": check_float("base_frequency", base_frequency, 0.0, 64.0, lo_open=True),
        "persistence": check_float("persistence", persistence, 0.0, 1.0, lo_open=True),
        "lacunarity": check_float("lacunarity", lacunarity, 1.5, 4.0),
    }
    finest = out["base_frequency"] * out["lacunarity"] ** (out["octaves"] - 1)
    if finest > 256.0:
        raise ValueError(
            f"octaves: the finest octave's frequency {out['base_frequency']:g} * "
            f"{out['lacunarity']:g}^{out['octaves'] - 1} = {finest:g} exceeds 256; "
            "lower octaves, base_frequency or lacunarity"
        )
    return out


def normalise(obj: Any, **values: Any) -> None:
    """Store checked values back on a frozen dataclass (``object.__setattr__``)."""
    for name, value in values.items():
        object.__setattr__(obj, name, value)
