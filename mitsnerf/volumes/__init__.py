"""Volume families: seeded procedural density and albedo grids that each stress something different, and
``grid``, the user's own medium read from a file.

A family turns ``(params, resolution, seed)`` into a :class:`VolumeGrids` pair (density (R, R, R) in
[0, 1], albedo (R, R, R, 3) in [0, 1], float32, indexed ``[z, y, x]``), deterministically. Density is
the medium's shape, unscaled: the scene multiplies it by its extinction scale to get ``sigma_t``.
Every family keeps density below 0.01 outside ``[-0.45, 0.45]^3``, so the medium never touches the
faces of the scene box ``[-0.5, 0.5]^3``.

| family  | stresses                                                                         |
|---------|----------------------------------------------------------------------------------|
| cloud   | the default: smooth low-frequency fBm with density contrast, soft silhouette     |
| plume   | thin anisotropic filaments: high frequencies                                     |
| blobs   | disjoint lobes in exactly empty space: empty-space skipping                      |
| shell   | a thin dense hollow sphere or torus: sharp edges, high optical depth             |
| lattice | hard-edged cubes, density exactly 0 or 1: the worst case for smooth fields       |
| nebula  | spatially varying RGB albedo                                                     |
| grid    | your own medium: a .npy or .npz ([z, y, x]) or Mitsuba .vol file (see .grid)      |

Families are a registry (:mod:`mitsnerf.plugins`): each built-in declares ``FAMILY = Family(...)`` in its own
module; installed code joins through a ``mitsnerf.volumes`` entry point (its object a :class:`Family`, its
name the entry point's), code that is not installed through ``MITSNERF_VOLUMES="name=path/to/file.py:FAMILY"``.

>>> sorted(families())
['blobs', 'cloud', 'grid', 'lattice', 'nebula', 'plume', 'shell']
>>> g = generate_volume("cloud", 8, seed=0, params={"octaves": 2})
>>> g.density.shape, g.albedo.shape
((8, 8, 8), (8, 8, 8, 3))
>>> make_params("cloud", {"octaves": 0})
Traceback (most recent call last):
...
mitsnerf.errors.SpecError: octaves: must be an integer >= 1, got 0
"""

from __future__ import annotations

import dataclasses
import functools
import os
import sys
from collections.abc import Mapping
from typing import Any

from mitsnerf.config import from_dict
from mitsnerf.plugins import Entry, Kind, PluginError, Registry, load
from mitsnerf.volumes.base import Family, VolumeGrids

__all__ = ["Family", "VolumeGrids", "families", "generate_volume", "make_params"]

MIN_RESOLUTION, MAX_RESOLUTION = 8, 512
#: The environment variable that registers families which are not installed, and the entry-point group.
VARIABLE, GROUP = "MITSNERF_VOLUMES", "mitsnerf.volumes"


def check_family(name: str, obj: Any) -> Family:
    """``obj`` if it is a :class:`Family` (renamed to its registry name), else a PluginError saying what it is."""
    if not isinstance(obj, Family):
        raise PluginError(f"{obj!r} is not a mitsnerf.volumes.base.Family")
    if not (dataclasses.is_dataclass(obj.params_type) and callable(obj.generate)):
        raise PluginError(f"family {obj.name!r}: params_type must be a dataclass and generate callable")
    return obj if obj.name == name else dataclasses.replace(obj, name=name)


KIND = Kind("volume family", "mitsnerf.volumes", "FAMILY", GROUP, VARIABLE, check_family)


def families() -> Registry[Family]:
    """Every registered volume family by name (built-ins first); broken plugins in ``.problems``."""
    return _families(os.environ.get(VARIABLE, ""), tuple(sys.path))


@functools.lru_cache(maxsize=8)
def _families(variable: str, path: tuple[str, ...]) -> Registry[Family]:
    loaded = load(KIND, {VARIABLE: variable})
    return Registry(loaded.what, {n: Entry(n, e.value, e.source) for n, e in loaded.entries.items()}, loaded.problems)


def _family(name: Any) -> Family:
    registry = families()
    problem = registry.why_not(name)
    if problem:
        raise ValueError(problem)
    return registry[name]


def make_params(family: str, values: Mapping[str, Any]) -> Any:
    """Build ``family``'s parameter dataclass from a plain mapping (as parsed from TOML), with
    :func:`mitsnerf.config.from_dict`: missing keys take their defaults; lists are accepted for
    tuples and ints for floats; ranges are the fields' own.

    Raises:
        ValueError: an unknown family (the message names the known ones); a
            :class:`~mitsnerf.errors.SpecError` (a ValueError) for an unknown key, a wrong type or an
            out-of-range value, its message starting with the field name.

    >>> make_params("shell", {"shape": "torus", "thickness": 0.02}).shape
    'torus'
    >>> make_params("shell", {"thickness_mm": 2})
    Traceback (most recent call last):
    ...
    mitsnerf.errors.SpecError: thickness_mm: unknown parameter of volume family 'shell' (did you mean 'thickness'?)
    """
    return from_dict(_family(family).params_type, values)


def generate_volume(
    family: str, resolution: int, seed: int, params: Mapping[str, Any] | Any = None
) -> VolumeGrids:
    """Generate ``family``'s grids at ``resolution^3`` from ``seed``.

    Args:
        family: a key of :data:`FAMILIES`.
        resolution: voxels per axis, in [8, 512].
        seed: non-negative integer, fed to ``np.random.default_rng``.
        params: None (the defaults), a mapping (see :func:`make_params`), or an instance of the
            family's ``params_type``.

    Returns:
        VolumeGrids, identical for identical arguments.

    >>> generate_volume("lattice", 4, seed=0)
    Traceback (most recent call last):
    ...
    ValueError: resolution: must be an integer in [8, 512], got 4
    """
    fam = _family(family)
    if isinstance(resolution, bool) or not isinstance(resolution, int) or not (
        MIN_RESOLUTION <= resolution <= MAX_RESOLUTION
    ):
        raise ValueError(
            f"resolution: must be an integer in [{MIN_RESOLUTION}, {MAX_RESOLUTION}], got {resolution!r}"
        )
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed: must be an integer >= 0, got {seed!r}")
    if params is None:
        params = fam.params_type()
    elif isinstance(params, Mapping):
        params = make_params(family, params)
    elif not isinstance(params, fam.params_type):
        expected = f"{fam.params_type.__module__}.{fam.params_type.__qualname__}"
        raise ValueError(f"params: must be None, a mapping or {expected}, got {type(params).__name__}")
    return fam.generate(params, resolution, seed)
