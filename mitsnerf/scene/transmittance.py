"""The exact transmittance of the true grid along camera rays, averaged over each pixel as the film does.

A camera ray that volpath traces through the medium reaches the environment behind it without a real
collision with probability ``T = exp(-tau)``, ``tau = int sigma_t(o + t d) dt`` over the ray's chord of
the box, where ``sigma_t`` is the grid looked up trilinearly with clamped borders (Mitsuba's
``gridvolume``; :class:`mitsnerf.fields.grid.GridField` is the same lookup). ``T`` is deterministic, so
the environment's part of a pixel, ``mean over the pixel of T(d) L_env(d)``, need not be estimated by
Monte Carlo: :func:`pixel_transmittance` computes it to float32 rounding along each ray and by a
``K x K`` stratified average over the pixel.

**Along a ray** (:func:`optical_depths`): between two consecutive planes through voxel centres (grid
coordinate ``g = unit * R - 1/2`` an integer on some axis) the lookup is the product of three linear
functions of ``t``, a cubic; the clamped half voxel at each border is a polynomial of lower degree. The
ray is walked cell by cell (a DDA over those planes: the next plane crossed on each axis computed from
its integer index, so no error accumulates) and each segment is integrated by the two-point
Gauss-Legendre rule, which is exact for cubics: ``tau`` is exact up to float32 rounding (about 1e-6
relative). A ray whose ``tau`` passes :data:`TAU_STOP` (``T < 1e-13``) stops there. A cell whose 8 corner voxels
are 0 adds exactly 0, so the walk does not look it up: from such a cell it goes in one step to the far side of the
empty cube around it (:func:`empty_distances`; most of a cloud's box is empty: 10 steps a ray instead of 44).

**Over the pixel** (:func:`pixel_transmittance`): Mitsuba's ``independent`` sampler puts a pixel's
samples uniformly on its square ``[col, col + 1) x [row, row + 1)`` and the box filter (radius 1/2)
gives each sample to that pixel alone with weight 1, so a pixel's expectation is the plain mean over
its square. It is taken at the ``K x K`` stratum centres (:func:`mitsnerf.math.rays.footprint_offsets`,
the midpoint rule in two dimensions, second order where ``T`` is smooth over the pixel), summed in float64; where
the mean is above 1/2 as ``1 - mean(1 - T)`` with ``1 - T`` to float32's relative precision (:func:`absorbed`), so a
pixel at the medium's faint edge keeps its small collision probability.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.math.box import Box
from mitsnerf.math.camera import Camera
from mitsnerf.math.composite import is_chromatic

#: Optical depth past which a ray is not followed further (T < 1e-13: below float32 resolution of 1).
TAU_STOP = 30.0
#: Sub-pixel rays per side (K x K per pixel) of the ground truth's background term.
FOOTPRINT = 8
_GAUSS = float(0.5 / np.sqrt(3.0))  # the two Gauss-Legendre nodes at mid -+ this fraction of the segment


def optical_depths(density: Callable[[Any], Any], resolution: int, box: Box, o, d, channels: int = 1,
                   distances=None):
    """``tau`` (Float (M,)) of rays ``o + t d`` (Array3f (M,), ``d`` unit) through a trilinear ``R^3`` grid
    over ``box``: exact per cell (module docstring). ``density``: Array3f -> Float, the grid's lookup, or
    Array3f -> Array3f with ``channels = 3`` (a chromatic grid: ``tau`` an Array3f, the ray followed until
    every channel's passes :data:`TAU_STOP`). ``distances``: the grid's :func:`empty_cells` (None: found here);
    the walk crosses the cube of cells it gives around an empty cell without looking the grid up."""
    Float = type(o.x)
    Tau = type(o) if channels == 3 else Float
    if distances is None:
        distances = empty_cells(density, resolution, box, type(o))
    t_n, t_f, _ = box.intersect(o, d)
    line = _GridLine.of(resolution, box, o, d)

    def segment(t, tau, *planes):  # a cell with medium in it: integrated, and the next plane crossed
        t_next, crossed = line.next_crossing(planes, t, t_f)
        mid, half = 0.5 * (t + t_next), t_next - t
        f = density(o + (mid - _GAUSS * half) * d) + density(o + (mid + _GAUSS * half) * d)
        return (t_next, tau + 0.5 * half * f, *line.moved(planes, crossed))

    def skip(empty, t, tau, *planes):  # an empty cube of 2 D - 1 cells a side: to its far side
        far = [planes[i] + line.step[i] * (empty - 1) for i in range(3)]
        t_next, crossed = line.next_crossing(far, t, t_f)
        return (t_next, tau, *line.furthest(line.moved(planes, crossed, far), line.planes_after(t_next)))

    def body(t, tau, *planes):
        empty = dr.gather(type(planes[0]), distances, line.cell(planes))
        return dr.if_stmt((empty, t, tau, *planes), empty == 0, lambda _, *s: segment(*s), skip, label="cell")

    state = (Float(t_n), dr.zeros(Tau, dr.width(o)), *line.planes_after(t_n))
    _, tau, *_ = dr.while_loop(state, lambda t, tau, *_: (t < t_f) & (_least(tau) < TAU_STOP), body,
                               label="optical_depths")
    return tau


@dataclass(frozen=True)
class _GridLine:
    """Rays in grid coordinates, ``g_k(t) = a_k + b_k t`` on axis ``k`` (voxel centres at integers), and the planes
    ``g_k`` integer that :func:`optical_depths` walks: ``step_k`` the way it crosses them (+-1), ``inv_k = 1 / b_k``
    (inf where the ray never crosses one).

    >>> from drjit.llvm import Array3f, Float
    >>> line = _GridLine.of(4, Box(), Array3f(-1.0, 0.1, 0.1), Array3f(1.0, 0.0, 0.0))  # g_x = -2.5 + 4 t
    >>> planes = line.planes_after(Float(0.5))  # where it enters the box, g_x = -1/2
    >>> [int(p[0]) for p in planes], int(line.cell(planes)[0])  # the clamped half voxel before plane 0: cell 0
    ([0, 2, 2], 12)
    >>> t, crossed = line.next_crossing(planes, Float(0.5), Float(1.5))
    >>> float(t[0]), [bool(c[0]) for c in crossed], [int(p[0]) for p in line.moved(planes, crossed)]
    (0.625, [True, False, False], [1, 2, 2])
    """

    a: list
    b: list
    step: list
    inv: list
    resolution: int

    @classmethod
    def of(cls, resolution: int, box: Box, o, d) -> _GridLine:
        """The rays ``o + t d`` (Array3f) in the grid coordinates of an ``R^3`` grid over ``box``."""
        lo, size = dr.scalar.Array3f(box.lo), dr.scalar.Array3f(box.size)
        b = [d[k] * (resolution / size[k]) for k in range(3)]
        a = [(o[k] - lo[k]) * (resolution / size[k]) - 0.5 for k in range(3)]
        return cls(a, b, [dr.select(bk >= 0, 1, -1) for bk in b],
                   [dr.select(dr.abs(bk) > 1e-12, dr.rcp(bk), dr.inf) for bk in b], resolution)

    def planes_after(self, t) -> list:
        """The first plane each axis crosses after ``t`` (Int32 each)."""
        Int32 = dr.int32_array_t(type(t))
        g = [self.a[k] + self.b[k] * t for k in range(3)]
        return [dr.select(self.b[k] >= 0, Int32(dr.floor(g[k])) + 1, Int32(dr.ceil(g[k])) - 1) for k in range(3)]

    def next_crossing(self, planes, t, t_f):
        """``(t_next, crossed)``: where the ray first reaches one of ``planes`` (not before ``t``, at most ``t_f``),
        and on which axes it does there (Bool each)."""
        t_axis = [dr.select(dr.isinf(self.inv[k]), dr.inf, (type(t)(planes[k]) - self.a[k]) * self.inv[k])
                  for k in range(3)]
        t_next = dr.maximum(dr.minimum(dr.minimum(dr.minimum(t_axis[0], t_axis[1]), t_axis[2]), t_f), t)
        return t_next, [t_axis[k] <= t_next for k in range(3)]

    def moved(self, planes, crossed, reached=None) -> list:
        """The next planes: past ``reached`` (default: ``planes``) on the axes ``crossed`` there, else ``planes``."""
        reached = planes if reached is None else reached
        return [dr.select(crossed[k], reached[k] + self.step[k], planes[k]) for k in range(3)]

    def furthest(self, planes, others) -> list:
        """Per axis the further of two planes along the ray."""
        return [dr.select(self.step[k] > 0, dr.maximum(planes[k], others[k]), dr.minimum(planes[k], others[k]))
                for k in range(3)]

    def cell(self, planes):
        """The flat index in :func:`empty_cells` of the cell before ``planes`` (UInt32/Int32)."""
        n = self.resolution + 1
        j = [dr.clip(planes[k] + dr.select(self.step[k] > 0, 0, 1), 0, self.resolution) for k in range(3)]
        return (j[0] * n + j[1]) * n + j[2]


def empty_cells(density: Callable[[Any], Any], resolution: int, box: Box, Array3f):
    """:func:`empty_distances` of the grid ``density`` looks up, flat (Int32 ``(R+1)^3``, cell ``(j_x, j_y, j_z)``
    at ``(j_x (R+1) + j_y) (R+1) + j_z``), from its voxels (:func:`voxel_values`)."""
    Int32 = dr.int32_array_t(dr.value_t(Array3f))
    return Int32(empty_distances(voxel_values(density, resolution, box, Array3f)).ravel())


def voxel_values(density: Callable[[Any], Any], resolution: int, box: Box, Array3f) -> np.ndarray:
    """``density`` at the ``R^3`` voxel centres ``lo + (i + 1/2) size / R`` of ``box``: ``(R, R, R)`` float64 indexed
    ``[x, y, z]`` (``(R, R, R, 3)`` chromatic). Where ``density`` is a grid's trilinear lookup, a voxel is 0 here
    only where it is 0 in the grid (the centres' float32 rounding mixes in at most a sliver of a neighbour).

    >>> from drjit.llvm import Array3f
    >>> voxel_values(lambda x: x.x + 10 * x.y, 2, Box(), Array3f)[:, :, 0].tolist()
    [[-2.75, 2.25], [-2.25, 2.75]]
    """
    from mitsnerf.math.rays import host

    Float = dr.value_t(Array3f)
    i = dr.arange(dr.uint32_array_t(Float), resolution ** 3)
    index = [i // (resolution * resolution), i // resolution % resolution, i % resolution]
    lo, size = dr.scalar.Array3f(box.lo), dr.scalar.Array3f(box.size)
    centre = Array3f(*(lo[k] + (Float(index[k]) + 0.5) * (size[k] / resolution) for k in range(3)))
    values = host(density(centre))
    return values.reshape(resolution, resolution, resolution, *values.shape[1:])


#: The largest distance :func:`empty_distances` records: a skip crosses at most ``2 SKIP_CAP - 1`` cells.
SKIP_CAP = 16


def empty_distances(values: np.ndarray, cap: int = SKIP_CAP) -> np.ndarray:
    """How far each cell of the walk lies from the medium: int32 ``(R+1, R+1, R+1)``, the cell ``j`` on an axis the
    one between voxel centres ``j - 1`` and ``j`` (``-1`` and ``R``: the clamped half voxels at the borders). Its
    entry ``D`` is the least Chebyshev distance, in cells, to a cell with a non-zero corner voxel (0: its own), at
    most ``cap``: a trilinear lookup in a cell mixes its 8 corners only, so the density is 0 on the whole cube of
    ``2 D - 1`` cells a side around it. ``values``: the voxels, ``(R, R, R)`` or ``(R, R, R, 3)`` (chromatic: a
    voxel is empty where every channel is 0), any axis order (the cells have the same).

    >>> v = np.zeros((4, 4, 4)); v[0, 0, 0] = 1.0
    >>> empty_distances(v)[:, 0, 0].tolist(), empty_distances(v, cap=2)[:, 3, 0].tolist()
    ([0, 0, 1, 2, 3], [2, 2, 2, 2, 2])
    """
    occupied = values != 0 if values.ndim == 3 else (values != 0).any(axis=-1)
    reached = np.pad(occupied, 1, mode="edge")  # the clamped borders: voxel -1 is voxel 0, R is R - 1
    for axis in range(3):
        reached = _without(reached, axis, 0) | _without(reached, axis, -1)  # a cell: either of its two corners
    distance = np.zeros(reached.shape, np.int32)
    for _ in range(cap):
        distance += ~reached
        for axis in range(3):
            reached = reached | _grown(reached, axis)
    return distance


def _without(x: np.ndarray, axis: int, end: int) -> np.ndarray:
    """``x`` without its first (``end`` 0) or its last (``end`` -1) slice along ``axis``."""
    return x[(slice(None),) * axis + (slice(1, None) if end == 0 else slice(None, -1),)]


def _grown(x: np.ndarray, axis: int) -> np.ndarray:
    """Where ``x`` (bool) or a neighbour of it along ``axis`` is true."""
    out = x.copy()
    out[(slice(None),) * axis + (slice(1, None),)] |= _without(x, axis, -1)
    out[(slice(None),) * axis + (slice(None, -1),)] |= _without(x, axis, 0)
    return out


def _least(tau):
    """The smallest channel of a chromatic ``tau`` (Array3f), or ``tau`` itself (Float)."""
    return dr.minimum(dr.minimum(tau[0], tau[1]), tau[2]) if is_chromatic(tau) else tau


@dataclass(frozen=True)
class PixelTransmittance:
    """What each pixel of a set of views sees through the medium, means over the pixel's square."""

    t: np.ndarray
    """``(V, H, W)`` float64: the mean transmittance ``mean T`` (a chromatic medium: also the mean over the
    three channels, what ``medium/``'s alpha estimates there: :mod:`mitsnerf.scene.render`)."""
    through: np.ndarray | None
    """``(V, H, W, 3)``: the mean of ``T(d) L(d)``, the environment seen through the medium (None: no background)."""
    env: np.ndarray | None
    """``(V, H, W, 3)``: the mean of ``L(d)``, the environment alone (None: no background)."""
    t_rgb: np.ndarray | None = None
    """``(V, H, W, 3)`` float64: a chromatic medium's mean ``T_k`` per colour channel ``k`` (None: a grey one)."""


def pixel_transmittance(density: Callable[[Any], Any], resolution: int, box: Box, cameras: Sequence[Camera], *,
                        pixel_center: float = 0.5, footprint: int = FOOTPRINT, background=None,
                        chunk: int = 1 << 21, channels: int = 1) -> PixelTransmittance:
    """Each pixel's mean transmittance over its square and, with ``background`` (``d -> Array3f``, the radiance
    a ray leaving in direction ``d`` sees), the means of ``T(d) L(d)`` and of ``L(d)``, at the K x K stratum
    centres of the pixel (``footprint`` K). ``density``: the grid's lookup (Array3f -> Float) over ``box``;
    with ``channels = 3`` a chromatic grid's (Array3f -> Array3f): ``T L`` is then per channel, and so is ``t_rgb``."""
    import mitsuba as mi

    from mitsnerf.math.composite import channel_mean
    from mitsnerf.math.rays import PixelRays, footprint_offsets

    rays = PixelRays(mi.Float, cameras, pixel_center)
    kk = footprint * footprint
    offsets = footprint_offsets(footprint)
    du_all, dv_all = (mi.Float(np.ascontiguousarray(offsets[:, i], np.float32)) for i in range(2))
    t_mean = np.empty(rays.size)
    t_rgb = np.empty((rays.size, 3)) if channels == 3 else None
    env = None if background is None else (np.empty((rays.size, 3)), np.empty((rays.size, 3)))
    per = max(1, chunk // kk)
    distances = empty_cells(density, resolution, box, rays.Array3f)
    for start in range(0, rays.size, per):
        n = min(per, rays.size - start)
        idx = dr.arange(mi.UInt32, n * kk)
        pixel, k = idx // kk + start, idx % kk
        o, d = rays.rays(pixel, dr.gather(mi.Float, du_all, k), dr.gather(mi.Float, dv_all, k))
        tau = optical_depths(density, resolution, box, o, d, channels=channels, distances=distances)
        t, p = dr.exp(-tau), absorbed(tau)
        dr.eval(t, p)  # the walk runs once: each later mean would trace it into its own kernel again
        t_mean[start:start + n] = _mean_t(channel_mean(t), channel_mean(p), kk)
        if t_rgb is not None:
            t_rgb[start:start + n] = np.stack([_mean_t(t[i], p[i], kk) for i in range(3)], axis=-1)
        if env is not None:
            radiance = dr.zeros(mi.Array3f, dr.width(d)) + mi.Array3f(background(d))  # a constant has width 1
            for out, value in zip(env, (radiance * t, radiance)):
                out[start:start + n] = np.stack([_pixel_means(value[i], kk) for i in range(3)], axis=-1)
    shape = (len(cameras), cameras[0].height, cameras[0].width)
    per_channel = None if t_rgb is None else t_rgb.reshape(*shape, 3)
    if env is None:
        return PixelTransmittance(t_mean.reshape(shape), None, None, per_channel)
    return PixelTransmittance(t_mean.reshape(shape), env[0].reshape(*shape, 3), env[1].reshape(*shape, 3), per_channel)


def _pixel_means(values, kk: int) -> np.ndarray:
    """The means of consecutive blocks of ``kk`` entries (one pixel's rays), summed in float64 (a float32 sum of
    ``kk`` values near 1 would round away deficits below its ulp, about ``kk`` 6e-8)."""
    return np.asarray(dr.block_sum(dr.float64_array_t(type(values))(values), kk), np.float64) / kk


def _mean_t(t, p, kk: int) -> np.ndarray:
    """Each pixel's mean ``T`` from its rays' ``T`` and ``1 - T`` (``p``, :func:`absorbed`): the mean of ``T`` where
    it is below 1/2, else 1 - the mean of ``p``, each to its own relative precision (float64 sums)."""
    direct = _pixel_means(t, kk)
    return np.where(direct < 0.5, direct, 1.0 - _pixel_means(p, kk))


#: Below this optical depth :func:`absorbed` takes its series.
SERIES_BELOW = 1e-3


def absorbed(tau):
    """``1 - exp(-tau)``, the probability that a ray of optical depth ``tau`` (Float or Array3f) collides, to
    float32's relative precision where it is tiny too: ``1 - exp(-tau)`` in float32 is 0 below ``tau`` about
    6e-8 and coarse above, so below :data:`SERIES_BELOW` it is the series ``tau (1 - tau / 2 (1 - tau / 3))``
    (first term left out ``tau^4 / 24``, 4e-14 there). The transmittance check reads ``p = 1 - mean T`` of a pixel
    at the medium's faint edge from it: a pixel whose ``p`` came out 0 would call any collision in it impossible.

    >>> from drjit.llvm import Float
    >>> [f"{x:.6g}" for x in absorbed(Float(1e-9, 1e-5, 2.0))]
    ['1e-09', '9.99995e-06', '0.864665']
    """
    small = tau < SERIES_BELOW
    return dr.select(small, tau * (1.0 - 0.5 * tau * (1.0 - tau * (1.0 / 3.0))), 1.0 - dr.exp(-tau))
