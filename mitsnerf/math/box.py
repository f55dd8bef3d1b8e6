"""The scene box: the axis-aligned region of world space a dataset's medium lives in.

Every field, grid, occupancy structure, exporter, renderer and density score maps this one
box; it is a property of the dataset (``mitsnerf.data.dataset.Dataset.box``), recorded by
every run. The conventions around it live here and nowhere else:

- world to unit coordinates: ``p = (x - lo) / (hi - lo)``, so the box is ``[0, 1]^3``;
- the slab test: ``t_n = max_a min(t0_a, t1_a)`` clamped to >= 0, ``t_f = min_a max(t0_a, t1_a)``
  with ``t0_a = (lo_a - o_a) / d_a``, ``t1_a = (hi_a - o_a) / d_a``; a ray misses when
  ``t_f <= t_n`` (or the test is not finite: a ray parallel to a slab it lies outside of gets
  ``t0_a = t1_a = +inf`` on the low side) and then gets the empty interval ``t_n = t_f = 0``,
  whose samples are finite points with ``delta = 0``;
- voxel centres of an ``R^3`` grid over the box: unit coordinate ``(i + 1/2) / R`` along each
  axis, grids indexed ``[z, y, x]`` (x fastest), as Mitsuba's ``gridvolume``;
- optical depth along rays ``tau = int_{t_n}^{t_f} sigma(o + t d) dt`` by the midpoint rule, and
  the transmittance from points inside the box to where they leave it (towards a light).

>>> box = Box((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5))
>>> box.size, box.to_unit(np.array([0.0, 1.5, -1.5])).tolist()
((3.0, 3.0, 3.0), [0.5, 1.0, 0.0])
>>> t_n, t_f, hit = box.intersect_numpy(np.array([[0.0, 0.0, -4.0]]), np.array([[0.0, 0.0, 1.0]]))
>>> t_n.tolist(), t_f.tolist(), hit.tolist()
([2.5], [5.5], [True])
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

Vec3 = tuple[float, float, float]


def _triple(values) -> Vec3:
    """Three numbers as a :data:`Vec3` (float)."""
    x, y, z = values
    return float(x), float(y), float(z)


def _vec3(name: str, value: Sequence[float]) -> Vec3:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: must be 3 finite numbers, got {value!r}")
    return (float(v[0]), float(v[1]), float(v[2]))


@dataclass(frozen=True)
class Box:
    """An axis-aligned box ``[lo, hi]`` (world units); ``lo < hi`` on every axis.

    >>> Box((0, 0, 0), (1, 2, 3)).centre
    (0.5, 1.0, 1.5)
    >>> Box((0, 0, 0), (1, 0, 1))
    Traceback (most recent call last):
    ...
    ValueError: box: min must be < max on every axis, got min (0.0, 0.0, 0.0) and max (1.0, 0.0, 1.0)
    """

    lo: Vec3 = (-0.5, -0.5, -0.5)
    hi: Vec3 = (0.5, 0.5, 0.5)

    def __post_init__(self) -> None:
        lo, hi = _vec3("box min", self.lo), _vec3("box max", self.hi)
        if not all(a < b for a, b in zip(lo, hi)):
            raise ValueError(f"box: min must be < max on every axis, got min {lo} and max {hi}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @classmethod
    def cube(cls, half: float, centre: Sequence[float] = (0.0, 0.0, 0.0)) -> Box:
        """The cube of half side ``half`` around ``centre``.

        >>> Box.cube(1.5).hi
        (1.5, 1.5, 1.5)
        """
        c = _vec3("box centre", centre)
        return cls(_triple(v - half for v in c), _triple(v + half for v in c))

    @classmethod
    def from_list(cls, value: Any) -> Box:
        """A box from ``[[x0, y0, z0], [x1, y1, z1]]`` (the form datasets and runs record).

        >>> Box.from_list([[-1, -1, -1], [1, 1, 1]]).size
        (2.0, 2.0, 2.0)
        """
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ValueError(f"box: must be [[min x, y, z], [max x, y, z]], got {value!r}")
        return cls(_vec3("box min", value[0]), _vec3("box max", value[1]))

    def to_list(self) -> list[list[float]]:
        return [list(self.lo), list(self.hi)]

    @property
    def size(self) -> Vec3:
        return _triple(b - a for a, b in zip(self.lo, self.hi))

    @property
    def centre(self) -> Vec3:
        return _triple(0.5 * (a + b) for a, b in zip(self.lo, self.hi))

    @property
    def diagonal(self) -> float:
        """Length of the box's diagonal (the longest chord)."""
        return math.sqrt(sum(s * s for s in self.size))

    def scaled(self, factor: float) -> Box:
        """The box scaled by ``factor`` about the world origin.

        >>> Box().scaled(3.0).lo
        (-1.5, -1.5, -1.5)
        """
        return Box(_triple(factor * v for v in self.lo), _triple(factor * v for v in self.hi))

    # -- coordinates (numpy arrays (..., 3) or Dr.Jit Array3f) -------------------------

    def to_unit(self, x):
        """``(x - lo) / (hi - lo)``: the box becomes ``[0, 1]^3``."""
        if isinstance(x, np.ndarray):
            return (x - np.asarray(self.lo)) / np.asarray(self.size)
        return (x - dr.scalar.Array3f(self.lo)) / dr.scalar.Array3f(self.size)

    def from_unit(self, p):
        """``lo + p (hi - lo)``: the inverse of :meth:`to_unit`."""
        if isinstance(p, np.ndarray):
            return np.asarray(self.lo) + p * np.asarray(self.size)
        return dr.scalar.Array3f(self.lo) + p * dr.scalar.Array3f(self.size)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Bool (M,): whether each point (M, 3) lies in the closed box."""
        p = np.asarray(points, dtype=np.float64)
        return np.all((p >= np.asarray(self.lo)) & (p <= np.asarray(self.hi)), axis=-1)

    # -- the slab test ------------------------------------------------------------------

    def intersect(self, o, d):
        """Distances ``(t_n, t_f, hit)`` where rays ``o + t d`` (Dr.Jit Array3f (R,)) enter and leave.

        ``t_n`` is clamped to >= 0 (a ray starting inside begins at its origin); rays that
        miss get ``t_n = t_f = 0``, so every sample on them is a finite point with ``delta = 0``
        (a ray parallel to a face, outside its slab on the low side, has ``t_n = +inf`` before that:
        its samples ``t_n + u (t_f - t_n)`` were NaN, and one such ray in a batch made the loss NaN).

        >>> from drjit.llvm import Array3f
        >>> Box().intersect(Array3f(0, 0, -2), Array3f(0, 0, 1))
        ([1.5], [2.5], [True])
        >>> Box().intersect(Array3f(0, 2, -0.6), Array3f(0, -1, 0))  # parallel to z = -0.5, below it
        ([0], [0], [False])
        """
        Float = type(o.x)
        inv = dr.rcp(d)
        t0 = (dr.scalar.Array3f(self.lo) - o) * inv
        t1 = (dr.scalar.Array3f(self.hi) - o) * inv
        t_n = dr.maximum(dr.max(dr.minimum(t0, t1)), 0.0)
        t_f = dr.min(dr.maximum(t0, t1))
        hit = t_f > t_n
        t_n = dr.select(hit, t_n, 0.0)
        return Float(t_n), Float(dr.select(hit, t_f, t_n)), hit

    def intersect_numpy(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The slab test of :meth:`intersect` on numpy rays (M, 3), in float64."""
        o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            a, b = (np.asarray(self.lo) - o) * inv, (np.asarray(self.hi) - o) * inv
        t_n = np.nanmax(np.minimum(a, b), axis=-1).clip(min=0.0)
        t_f = np.nanmin(np.maximum(a, b), axis=-1)
        hit = t_f > t_n
        t_n = np.where(hit, t_n, 0.0)
        return t_n, np.where(hit, t_f, t_n), hit

    # -- grids --------------------------------------------------------------------------

    def voxel_axes(self, resolution: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World coordinates of the voxel centres along x, y and z, each float64 (R,)."""
        u = (np.arange(resolution, dtype=np.float64) + 0.5) / resolution
        x, y, z = (lo + u * s for lo, s in zip(self.lo, self.size))
        return x, y, z

    def voxel_centres(self, resolution: int) -> np.ndarray:
        """World positions (R, R, R, 3) of the voxel centres, indexed ``[z, y, x]``, last axis (x, y, z).

        ``voxel_centres(R).reshape(-1, 3)`` lists them x fastest, so values computed there
        reshape to an ``(R, R, R)`` grid indexed ``[z, y, x]``.

        >>> Box().voxel_centres(2)[0, 0, 1].tolist()   # voxel z=0, y=0, x=1
        [0.25, -0.25, -0.25]
        """
        x, y, z = self.voxel_axes(resolution)
        zz, yy, xx = np.meshgrid(z, y, x, indexing="ij")
        return np.stack([xx, yy, zz], axis=-1)


UNIT_BOX = Box()
"""``[-0.5, 0.5]^3``: where mitsnerf's scene specs place their media."""


def optical_depth(density: Callable[[Any], Any], o, d, box: Box, n: int):
    """``tau = int_{t_n}^{t_f} sigma(o + t d) dt`` along rays by the midpoint rule, ``n`` samples each.

    ``density``: Array3f (M,) -> Float (M,); ``o``, ``d``: Array3f (R,) -> Float (R,) (a chromatic density,
    Array3f -> Array3f, gives one ``tau`` per colour channel).
    ``tau = h sum_k sigma(o + (t_n + (k + 1/2) h) d)``, ``h = (t_f - t_n) / n`` (rays that miss: 0).

    >>> from drjit.llvm import Array3f, Float
    >>> optical_depth(lambda x: 2.0 + 0.0 * x.x, Array3f(0, 0, -2), Array3f(0, 0, 1), UNIT_BOX, 4)
    [2]
    """
    Float = type(o.x)
    UInt32 = dr.uint32_array_t(Float)
    Array3f = type(o)
    t_n, t_f, _ = box.intersect(o, d)
    h = (t_f - t_n) / n
    idx = dr.arange(UInt32, dr.width(t_n) * n)
    ray = idx // n
    k = Float(idx - ray * n)
    t = dr.gather(Float, t_n, ray) + (k + 0.5) * dr.gather(Float, h, ray)
    x = dr.gather(Array3f, o, ray) + t * dr.gather(Array3f, d, ray)
    return dr.block_sum(density(x), n) * h


def march_optical_depth(density: Callable[[Any], Any], x, w, m: int, box: Box, s_max=None):
    """``tau = int_0^{s_f} sigma(x + s w) ds`` from points ``x`` inside the box along ``w``.

    ``s_f`` is where the ray leaves the box, or ``min(s_f, s_max)`` with ``s_max`` (Float (M,),
    e.g. the distance to a point light inside the box). Midpoint rule with ``m`` equal intervals
    (second order, unlike the render quadrature's last half interval): ``s_k = (k + 1/2) s_f / m``,
    ``tau = (s_f / m) sum_k sigma(x + s_k w)``. ``x`` Array3f (M,), ``w`` Array3f (M,) or (1,)
    unit; ``density`` maps Array3f -> Float (or Array3f per colour: ``tau`` per channel). Returns Float (M,).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> slab = lambda p: 2.0 + 0.0 * p.x                      # sigma_t = 2, path 0.5 to the face
    >>> march_optical_depth(slab, mi.Array3f(0, 0, 0), mi.Array3f(0, 0, 1), 4, UNIT_BOX)
    [1]
    """
    Array3f = type(x)
    Float = type(x.x)
    UInt32 = dr.uint32_array_t(Float)
    width = dr.width(x)
    w = w + dr.zeros(Array3f, width) if dr.width(w) != width else w
    _, s_f, _ = box.intersect(x, w)
    if s_max is not None:
        s_f = dr.minimum(s_f, s_max)
    idx = dr.arange(UInt32, width * m)
    ray = idx // m
    k = Float(idx - ray * m)
    s_f_k = dr.gather(Float, s_f, ray)
    p = dr.gather(Array3f, x, ray) + (k + 0.5) / m * s_f_k * dr.gather(Array3f, w, ray)
    return dr.block_sum(density(p), m) * (s_f / m)


def march_transmittance(density: Callable[[Any], Any], x, w, m: int, box: Box, s_max=None):
    """``T = exp(-tau)`` of :func:`march_optical_depth`: the transmittance from points ``x`` inside the box along
    ``w`` to where the ray leaves it (or to ``s_max``); Float (M,) (or per colour).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> slab = lambda p: 2.0 + 0.0 * p.x                      # sigma_t = 2, path 0.5 to the face
    >>> march_transmittance(slab, mi.Array3f(0, 0, 0), mi.Array3f(0, 0, 1), 4, UNIT_BOX)  # exp(-1)
    [0.367879]
    >>> march_transmittance(slab, mi.Array3f(0, 0, 0), mi.Array3f(0, 0, 1), 4, UNIT_BOX, mi.Float(0.25))
    [0.606531]
    """
    return dr.exp(-march_optical_depth(density, x, w, m, box, s_max))
