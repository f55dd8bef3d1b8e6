"""A field of volumetric primitives: a sum of anisotropic Gaussian kernels, each with a density and an SH colour.

Kernel ``k`` (:mod:`mitsnerf.math.gaussian`: mean ``mu_k``, rotation ``q_k``, scales ``s_k``, truncated at the
Mahalanobis radius ``cutoff``) carries a peak density ``sigma_k`` (one, or one per colour channel for a chromatic
medium) and SH coefficients ``k_k`` (degree ``sh_degree``)::

    sigma(x)    = sum_k sigma_k g_k(x)                              sigma_k = exp(density_k)   (per channel)
    c_k(d)      = c_max sigmoid(sum_j k_kj Y_j(d))                   (per channel, as voxel's SH colour)
    c(x, d)     = sum_k sigma_k g_k(x) c_k(d) / sigma(x)             (the kernels' emission mixed by density)

so the medium is what an emission-absorption renderer sees when the kernels overlap: densities add, and the
colour at a point is the density-weighted mean of the kernels' colours there. The trainable values, one row
per kernel (:data:`PARAMETER_COLUMNS`): ``mean`` (N, 3), ``log_scale`` (N, 3), ``rotation`` (N, 4; the quaternion
``(x, y, z, w)``, normalised on use), ``density`` (N, C) raw, ``sh`` (N, 3 K), ``K = (sh_degree + 1)^2``, channel
``3 j + c`` the coefficient of ``Y_j`` for colour ``c``.

For rendering and queries the kernels become two row-major tables (:class:`Kernels`): *geometry*, 12 floats a
row (``mu``, then ``M = S^-1 R^T`` row by row), and *appearance*, ``3 + 3 K`` floats (``sigma`` per channel, a grey
density repeated, then the SH coefficients), built from the parameters with Dr.Jit's AD, so gradients reaching the
tables reach the parameters. :class:`CellLists` sorts the kernels into a uniform ``G^3`` grid of cells over the
scene box (a kernel is listed in every cell its shell's bounding box overlaps; kernels outside the box in none):
a point, or a ray segment inside one cell, needs only that cell's list.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.fields.sh import MAX_DEGREE, num_coefficients, sh_basis
from mitsnerf.math.activations import sigmoid
from mitsnerf.math.box import Box
from mitsnerf.math.gaussian import (
    ELLIPSOID_RADIUS,
    ellipsoid_value,
    full_integral,
    inverse_frame,
    kernel_value,
    ray_profile,
    segment_integral,
    segment_length,
)

#: The parameters of a kernel and their columns (0: set by the config, :meth:`PrimitiveFieldConfig.columns`).
PARAMETER_COLUMNS = {"mean": 3, "log_scale": 3, "rotation": 4, "density": 0, "sh": 0}
GEOMETRY = 12
"""Floats per row of the geometry table: the mean, then ``M`` row by row."""


@dataclass(frozen=True)
class PrimitiveFieldConfig:
    """What each kernel holds and how the kernels are found."""

    kernel: str = param("gaussian", choices=("gaussian", "ellipsoid"))
    """Each kernel's shape: ``gaussian`` (truncated at ``cutoff``) or ``ellipsoid``, EVER's constant density inside
    the ellipsoid of the same covariance (semi-axes ``sqrt(5) s``)."""
    sh_degree: int = param(1, lo=0, hi=MAX_DEGREE)
    """Highest SH band L of each kernel's colour (K = (L + 1)^2 coefficients per channel)."""
    density_channels: int = param(1, choices=(1, 3))
    """1: one density per kernel; 3: one per colour channel (chromatic media)."""
    c_max: float = param(1.0, lo=0.0, lo_open=True)
    """Largest colour (radiance)."""
    cutoff: float = param(3.0, lo=1.0, hi=6.0)
    """Mahalanobis radius where each Gaussian kernel is truncated (3: at 1.1% of its peak)."""
    cells: int = param(32, lo=1, hi=256)
    """Cells per axis of the grid that lists the kernels overlapping each cell."""

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def appearance(self) -> int:
        """Floats per row of the appearance table: ``3 + 3 K``.

        >>> PrimitiveFieldConfig(sh_degree=1).appearance
        15
        """
        return 3 + 3 * num_coefficients(self.sh_degree)

    @property
    def radius(self) -> float:
        """The Mahalanobis radius of a kernel's support: ``cutoff``, or ``sqrt 5`` for an ellipsoid."""
        return self.cutoff if self.kernel == "gaussian" else ELLIPSOID_RADIUS

    def columns(self, key: str) -> int:
        """Columns of parameter ``key`` (``density``: the density channels; ``sh``: 3 K)."""
        if key == "density":
            return self.density_channels
        if key == "sh":
            return 3 * num_coefficients(self.sh_degree)
        return PARAMETER_COLUMNS[key]


def _module(v):
    return sys.modules[type(v).__module__]


def column(tensor, j: int, columns: int):
    """Column ``j`` of a row-major ``(N, columns)`` tensor, a Float (N,) (differentiable)."""
    Float = dr.leaf_t(type(tensor)) if dr.is_tensor_v(tensor) else type(tensor)
    flat = tensor.array if dr.is_tensor_v(tensor) else tensor
    n = dr.width(flat) // columns
    return dr.gather(Float, flat, dr.arange(dr.uint32_array_t(Float), n) * columns + j)


def table(columns_list: list) -> Any:
    """The row-major flat table whose columns are ``columns_list`` (Floats of one width N), differentiable.

    >>> from drjit.llvm.ad import Float
    >>> table([Float(1, 2), Float(3, 4)])
    [1, 3, 2, 4]
    """
    Float = type(columns_list[0])
    n, c = dr.width(columns_list[0]), len(columns_list)
    out = dr.zeros(Float, n * c)
    index = dr.arange(dr.uint32_array_t(Float), n) * c
    for j, col in enumerate(columns_list):
        dr.scatter(out, col, index + j)
    return out


class Kernels:
    """The kernels of the parameters ``params`` (a mapping of :data:`PARAMETER_COLUMNS` to row-major tensors) as the
    geometry and appearance tables (module docstring), keeping their AD graph."""

    def __init__(self, config: PrimitiveFieldConfig, params: Mapping[str, Any]) -> None:
        self.config = config
        mean = params["mean"]
        self.count = int(mean.shape[0]) if dr.is_tensor_v(mean) else dr.width(mean) // 3
        m = _module(column(mean, 0, 3))
        cols = {key: [column(params[key], j, config.columns(key)) for j in range(config.columns(key))]
                for key in PARAMETER_COLUMNS}
        M = inverse_frame(m.Array4f(*cols["rotation"]), m.Array3f(*cols["log_scale"]))
        self.geometry = table(cols["mean"] + [M[i][j] for i in range(3) for j in range(3)])
        sigma = [dr.exp(v) for v in cols["density"]]
        sigma = sigma * 3 if len(sigma) == 1 else sigma
        self.appearance = table(sigma + cols["sh"])

    def detached(self) -> Kernels:
        """The same tables without their AD graph (for queries and views)."""
        out = object.__new__(Kernels)
        out.config, out.count = self.config, self.count
        out.geometry, out.appearance = dr.detach(self.geometry), dr.detach(self.appearance)
        return out

    def numpy_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean (N, 3), M (N, 3, 3))`` as float64 numpy arrays."""
        g = np.asarray(dr.detach(self.geometry).numpy(), dtype=np.float64).reshape(self.count, GEOMETRY)
        return g[:, :3], g[:, 3:].reshape(self.count, 3, 3)


def shell_extents(M: np.ndarray, cutoff: float) -> np.ndarray:
    """Half extents (N, 3) of the bounding boxes of the shells ``|M (x - mu)| <= cutoff``: ``cutoff`` times the
    norms of the rows of ``M^-1 = R S``.

    >>> shell_extents(np.diag([0.5, 1.0, 2.0])[None], 3.0).tolist()
    [[6.0, 3.0, 1.5]]
    """
    inv = np.linalg.inv(M)
    return cutoff * np.sqrt(np.sum(inv * inv, axis=2))


@dataclass(frozen=True)
class CellLists:
    """Which kernels overlap each cell of a ``G^3`` grid over the box, as compressed rows: the kernels of cell ``c``
    (``c = (z G + y) G + x``) are ``items[offsets[c]:offsets[c + 1]]``, in increasing order."""

    offsets: Any
    """UInt32 (G^3 + 1)."""
    items: Any
    """UInt32 (P,): kernel indices (P the number of (cell, kernel) pairs; a single 0 when there are none)."""
    resolution: int
    box: Box
    pairs: int

    @classmethod
    def build(cls, kernels: Kernels, box: Box, UInt32) -> CellLists:
        """The lists of ``kernels`` (their shells' bounding boxes, :func:`shell_extents`), on the host."""
        g = kernels.config.cells
        mean, M = kernels.numpy_geometry()
        ext = shell_extents(M, kernels.config.radius)
        lo, size = np.asarray(box.lo), np.asarray(box.size)
        first = np.floor((mean - ext - lo) / size * g).astype(np.int64)
        last = np.floor((mean + ext - lo) / size * g).astype(np.int64)
        inside = np.all((last >= 0) & (first < g), axis=1) & np.all(np.isfinite(mean), axis=1)
        first, last = np.clip(first, 0, g - 1), np.clip(last, 0, g - 1)
        span = np.where(inside[:, None], last - first + 1, 0)
        kernel, cell = _pairs(first, span, g)
        order = np.argsort(cell, kind="stable")
        counts = np.bincount(cell, minlength=g**3)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.uint32)
        items = kernel[order].astype(np.uint32) if len(kernel) else np.zeros(1, np.uint32)
        return cls(UInt32(offsets), UInt32(items), g, box, int(len(kernel)))

    def cell_of(self, x):
        """``(cell index UInt32, inside Bool)`` of world points ``x`` (Array3f)."""
        m = _module(x)
        p = self.box.to_unit(x) * self.resolution
        inside = dr.all((p >= 0) & (p < self.resolution))
        i = dr.clip(m.Int32(dr.floor(p.x)), 0, self.resolution - 1)
        j = dr.clip(m.Int32(dr.floor(p.y)), 0, self.resolution - 1)
        k = dr.clip(m.Int32(dr.floor(p.z)), 0, self.resolution - 1)
        return m.UInt32((k * self.resolution + j) * self.resolution + i), inside


def _pairs(first: np.ndarray, span: np.ndarray, g: int) -> tuple[np.ndarray, np.ndarray]:
    """Every (kernel, cell) pair of the per-kernel cell ranges ``first .. first + span - 1`` (x, y, z)."""
    per = np.prod(span, axis=1)
    kernel = np.repeat(np.arange(len(per)), per)
    local = np.arange(len(kernel)) - np.repeat(np.cumsum(per) - per, per)
    sx, sy = span[kernel, 0], span[kernel, 1]
    dx, dy, dz = local % sx, (local // sx) % sy, local // (sx * sy)
    f = first[kernel]
    cell = ((f[:, 2] + dz) * g + (f[:, 1] + dy)) * g + (f[:, 0] + dx)
    return kernel, cell


def kernel_rows(geometry, appearance, k, channels: int):
    """Kernel ``k``'s rows (UInt32 indices, any width): ``(mean Array3f, M Matrix3f, sigma Array3f, coeffs list)``;
    ``channels``: floats per appearance row."""
    m = _module(k)
    g = dr.gather(m.ArrayXf, geometry, k, shape=(GEOMETRY, dr.width(k)))
    a = dr.gather(m.ArrayXf, appearance, k, shape=(channels, dr.width(k)))
    return unpack(g, a)


def unpack(g, a):
    """``(mean, M, sigma, coeffs)`` of gathered geometry and appearance rows (ArrayXf packets)."""
    m = _module(g[0])
    mean = m.Array3f(g[0], g[1], g[2])
    M = m.Matrix3f(*(g[3 + i] for i in range(9)))
    sigma = m.Array3f(a[0], a[1], a[2])
    return mean, M, sigma, [a[3 + i] for i in range(len(a) - 3)]


def point_value(config: PrimitiveFieldConfig, x, mean, M):
    """A kernel's value at points ``x`` (peak 1): the truncated Gaussian or the ellipsoid's indicator."""
    return kernel_value(x, mean, M, config.cutoff) if config.kernel == "gaussian" else ellipsoid_value(x, mean, M)


def line_integral(config: PrimitiveFieldConfig, o, d, mean, M, t0, t1):
    """A kernel's integral (peak 1) over the segments ``[t0, t1]`` of rays ``o + t d``, in closed form
    (:mod:`mitsnerf.math.gaussian`)."""
    profile = ray_profile(o, d, mean, M, config.radius)
    return segment_integral(profile, t0, t1) if config.kernel == "gaussian" else segment_length(profile, t0, t1)


def kernel_colour(coeffs, Y, c_max: float):
    """``c_max sigmoid(sum_j k_j Y_j)`` per channel (``coeffs[3 j + c]``), Array3f."""
    m = _module(Y[0])
    raw = [sum(coeffs[3 * j + c] * Y[j] for j in range(len(Y))) for c in range(3)]
    return m.Array3f(*(c_max * sigmoid(v) for v in raw))


class PrimitiveField:
    """The field ``(x, d) -> (rgb, sigma)`` of kernels (module docstring), and ``density(x)``, found through their
    cell lists. ``kernels`` are used as given (detach them for queries without gradients).

    >>> import mitsuba as mi, numpy as np
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> config = PrimitiveFieldConfig(sh_degree=0, cells=4)
    >>> params = {"mean": mi.TensorXf(np.zeros((1, 3))), "log_scale": mi.TensorXf(np.full((1, 3), np.log(0.1))),
    ...           "rotation": mi.TensorXf(np.array([[0.0, 0, 0, 1]])),
    ...           "density": mi.TensorXf(np.full((1, 1), np.log(5.0))), "sh": mi.TensorXf(np.zeros((1, 3)))}
    >>> field = PrimitiveField(Kernels(config, params), UNIT_BOX)
    >>> rgb, sigma = field(mi.Array3f([0, 0.1, 0.4], 0, 0), mi.Array3f(0, 0, 1))
    >>> sigma, rgb[0]  # 5 at the centre, 5 exp(-1/2) one scale away, 0 beyond the shell  # doctest: +ELLIPSIS
    ([5, 3.0326..., 0], [0.5, 0.5, 0])
    """

    def __init__(self, kernels: Kernels, box: Box, lists: CellLists | None = None) -> None:
        import mitsuba as mi

        self.kernels, self.box, self.config = kernels, box, kernels.config
        self.lists = lists if lists is not None else CellLists.build(kernels, box, mi.UInt32)

    @property
    def sigma_channels(self) -> int:
        """1, or 3 for one density per colour channel (``sigma`` an Array3f)."""
        return self.config.density_channels

    def _sums(self, x, d):
        """``(sum_k sigma_k g_k(x), sum_k sigma_k g_k(x) c_k(d))`` (Array3f each; ``d`` None: no colour)."""
        m = _module(x)
        cell, inside = self.lists.cell_of(x)
        start = dr.gather(m.UInt32, self.lists.offsets, cell, inside)
        end = dr.gather(m.UInt32, self.lists.offsets, cell + 1, inside)
        Y = None if d is None else sh_basis(d, self.config.sh_degree)
        kern, cfg = self.kernels, self.config

        def body(j, density, emission):
            k = dr.gather(m.UInt32, self.lists.items, j)
            mean, M, sigma, coeffs = kernel_rows(kern.geometry, kern.appearance, k, cfg.appearance)
            w = sigma * point_value(cfg, x, mean, M)
            if Y is not None:
                emission = dr.fma(w, kernel_colour(coeffs, Y, cfg.c_max), emission)
            return j + 1, density + w, emission

        zero = dr.zeros(m.Array3f, dr.width(x))
        _, density, emission = dr.while_loop((m.UInt32(start), zero, zero), lambda j, *_: j < end, body,
                                             label="primitive_field")
        return density, emission

    def _sigma(self, density):
        return density if self.config.density_channels == 3 else density[0]

    def density(self, x):
        """``sigma(x)``, Float (M,) (an Array3f with ``density_channels = 3``); 0 outside the box."""
        return self._sigma(self._sums(x, None)[0])

    def __call__(self, x, d):
        density, emission = self._sums(x, d)
        rgb = dr.select(density > 0, emission / dr.maximum(density, 1e-30), 0.0)
        return rgb, self._sigma(density)


def kernel_volume(log_scale: np.ndarray, kernel: str = "gaussian") -> np.ndarray:
    """The integral over space of a kernel of peak 1 (N,): ``(2 pi)^(3/2) s_x s_y s_z`` for an untruncated
    Gaussian, ``4/3 pi 5^(3/2) s_x s_y s_z`` for the ellipsoid.

    >>> [round(float(kernel_volume(np.zeros((1, 3)), k)[0]), 4) for k in ("gaussian", "ellipsoid")]
    [15.7496, 46.8321]
    """
    unit = (2.0 * math.pi) ** 1.5 if kernel == "gaussian" else 4.0 / 3.0 * math.pi * ELLIPSOID_RADIUS**3
    return unit * np.exp(np.sum(log_scale, axis=1))


def largest_line_integral(log_scale_max: np.ndarray, config: PrimitiveFieldConfig) -> np.ndarray:
    """A kernel's largest integral (peak 1) along any ray, through its centre along its longest axis: ``sqrt(2 pi)
    s_max erf(cutoff / sqrt 2)`` for the Gaussian, ``2 sqrt(5) s_max`` for the ellipsoid.

    >>> largest_line_integral(np.zeros(1), PrimitiveFieldConfig(kernel="ellipsoid")).round(4).tolist()
    [4.4721]
    """
    unit = full_integral(0.0, config.cutoff) if config.kernel == "gaussian" else 2.0 * ELLIPSOID_RADIUS
    return unit * np.exp(log_scale_max)
