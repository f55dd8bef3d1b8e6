"""A dense voxel field: density and spherical-harmonic colour per voxel (Plenoxels / DVGO style).

Two grids over the scene box, indexed ``[z, y, x]`` with voxel centres as in
docs/conventions.md, are looked up trilinearly (``dr.Texture3f``, ``use_accel=False``,
clamped borders: the lookup of :class:`mitsnerf.fields.grid.GridField`) and then
activated::

    sigma(x)   = sigma_scale * softplus(s(x))                   s: raw density grid (R, R, R, 1) (or 3)
    c(x, d)    = c_max * sigmoid(sum_k k_k(x) Y_k(d))           k: SH grid (R, R, R, 3 K), K = (L+1)^2

(interpolate, then activate, as Plenoxels does for density). With ``density_channels = 3`` the
density grid holds one extinction per colour channel, for chromatic media: ``sigma`` is then an
Array3f and each colour is composited with its own (:func:`mitsnerf.math.composite.composite`).
Gradients reach both grids
through the texture lookups. The total variation prior ::

    TV(g) = 1/C sum_c sum_{a in x,y,z} mean_v (g_c(v + e_a) - g_c(v))^2

is what :func:`total_variation` computes (a mean over voxel pairs and channels, so its
scale does not depend on the resolution's voxel count). :func:`upsample` doubles a grid by
evaluating it trilinearly at the new voxel centres, so the field barely changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.fields.grid import extinction
from mitsnerf.fields.sh import MAX_DEGREE, colour_start, num_coefficients, sh_basis
from mitsnerf.math.activations import sigmoid, softplus
from mitsnerf.math.box import Box


@dataclass(frozen=True)
class VoxelFieldConfig:
    """Activations and initial values of the voxel field."""

    sh_degree: int = param(1, lo=0, hi=MAX_DEGREE)
    """Highest SH band L of the colour (K = (L + 1)^2 coefficients per channel)."""
    sigma_scale: float = param(10.0, lo=0.0, lo_open=True)
    """``sigma = sigma_scale * softplus(s)``."""
    sigma_init: float = param(0.1, lo=0.0, lo_open=True)
    """Initial density everywhere (world units^-1)."""
    c_max: float = param(1.0, lo=0.0, lo_open=True)
    """Largest colour (radiance)."""
    density_channels: int = param(1, choices=(1, 3))
    """1: one density for every colour; 3: one per colour channel (chromatic media, a 3-channel sigma_t)."""

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def raw_sigma_init(self) -> float:
        """``s`` with ``sigma_scale * softplus(s) = sigma_init``.

        >>> round(VoxelFieldConfig(sigma_init=10.0 * np.log(2.0)).raw_sigma_init, 6)
        0.0
        """
        y = self.sigma_init / self.sigma_scale
        return float(y + np.log(-np.expm1(-y)))


def _texture(Texture3f, tensor):
    return Texture3f(tensor, use_accel=False, filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)


class VoxelField:
    """The field callable ``(x, d) -> (rgb, sigma)`` over two grid tensors; also ``density(x)``.

    ``sigma_raw`` (R, R, R, 1) (3 channels with ``density_channels = 3``) and ``sh`` (R, R, R, 3 K) are Dr.Jit
    tensors (their AD graph is kept: gradients of a render reach them). Channel ``3 k + c`` of ``sh`` is the
    coefficient of ``Y_k`` for colour channel ``c``.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> f = VoxelField.create(VoxelFieldConfig(sigma_init=2.0), 4, mi.TensorXf, UNIT_BOX)
    >>> rgb, sigma = f(mi.Array3f(0.1, 0.2, 0.3), mi.Array3f(0, 0, 1))
    >>> round(sigma[0], 4), rgb  # sigma_init, and sigmoid(0) = 1/2
    (2.0, [[0.5, 0.5, 0.5]])
    """

    def __init__(self, config: VoxelFieldConfig, sigma_raw, sh, box: Box) -> None:
        import mitsuba as mi

        self.config = config
        self.box = box
        self.n_coeffs = num_coefficients(config.sh_degree)
        if sh.shape[-1] != 3 * self.n_coeffs:
            raise ValueError(
                f"sh grid has {sh.shape[-1]} channels, expected 3 x {self.n_coeffs} for degree {config.sh_degree}"
            )
        self.sigma_raw = sigma_raw
        self.sh = sh
        self._sigma_tex = _texture(mi.Texture3f, sigma_raw)
        self._sh_tex = _texture(mi.Texture3f, sh)

    @classmethod
    def create(cls, config: VoxelFieldConfig, resolution: int, TensorXf, box: Box) -> VoxelField:
        """Uniform grids: density ``sigma_init`` everywhere, the SH colour grey 0.5 in every direction
        (:func:`~mitsnerf.fields.sh.colour_start`: whatever ``c_max`` is)."""
        r = int(resolution)
        sigma_raw = dr.full(TensorXf, config.raw_sigma_init, (r, r, r, config.density_channels))
        start = colour_start(config.sh_degree, config.c_max)
        sh = TensorXf(dr.tile(dr.array_t(TensorXf)(start), r ** 3), (r, r, r, len(start)))
        return cls(config, sigma_raw, sh, box)

    @property
    def resolution(self) -> int:
        return int(self.sigma_raw.shape[0])

    def with_grids(self, sigma_raw=None, sh=None) -> VoxelField:
        """The same field over new grid tensors (e.g. the optimiser's, or upsampled ones)."""
        return VoxelField(
            self.config,
            self.sigma_raw if sigma_raw is None else sigma_raw,
            self.sh if sh is None else sh,
            self.box,
        )

    @property
    def sigma_channels(self) -> int:
        """The density's channels: 1, or 3 (``sigma`` an Array3f, one extinction per colour)."""
        return self.config.density_channels

    def _sigma(self, raw, Array3f):
        return extinction([self.config.sigma_scale * softplus(v) for v in raw], Array3f)

    def density(self, x):
        """``sigma(x)``, Float (M,) (an Array3f with ``density_channels = 3``)."""
        return self._sigma(self._sigma_tex.eval(self.box.to_unit(x)), type(x))

    def textures(self) -> tuple:
        """The raw density and the SH textures (a :class:`~mitsnerf.fields.protocols.TextureField`)."""
        return (self._sigma_tex, self._sh_tex)

    def __call__(self, x, d):
        p = self.box.to_unit(x)
        return self.head([tex.eval(p) for tex in self.textures()], x, d)

    def head(self, values, x, d):
        """``(rgb, sigma)`` from the two grids' lookups at ``x``: the activations of the module docstring."""
        sigma = self._sigma(values[0], type(x))
        coeffs = values[1]
        Y = sh_basis(d, self.config.sh_degree)
        raw = [sum(coeffs[3 * k + c] * Y[k] for k in range(self.n_coeffs)) for c in range(3)]
        c_max = self.config.c_max
        Array3f = type(x)
        return Array3f(*(c_max * sigmoid(v) for v in raw)), sigma


def _tv_terms(flat, shape):
    """Per-axis neighbour differences of a flat (R0, R1, R2, C) grid: [(stride, coord, n, count)]."""
    r0, r1, r2, c = shape
    UInt32 = dr.uint32_array_t(type(flat))
    e = dr.arange(UInt32, r0 * r1 * r2 * c)
    v = e // c
    coords = (v // (r1 * r2), (v // r2) % r1, v % r2)  # (z, y, x) for axes 0, 1, 2
    strides = (r1 * r2 * c, r2 * c, c)
    sizes = (r0, r1, r2)
    out = []
    for axis in range(3):
        n = sizes[axis]
        if n < 2:
            continue
        count = (r0 * r1 * r2 // n) * (n - 1) * c
        out.append((strides[axis], coords[axis], n, count))
    return e, out


class _TotalVariation(dr.CustomOp):
    """TV value and its exact gradient by a gather stencil (no scattered atomics in the backward pass)."""

    def eval(self, grid):
        self.grid = grid
        Float = dr.leaf_t(type(grid))
        g = grid.array
        e, terms = _tv_terms(g, grid.shape)
        value = Float(0.0)
        for stride, coord, n, count in terms:
            upper = coord + 1 < n
            d = dr.gather(Float, g, e + stride, upper) - dr.select(upper, g, 0.0)
            value = value + dr.sum(dr.square(d)) / count
        return value

    def forward(self):
        raise NotImplementedError("total_variation: forward-mode derivatives are not implemented")

    def backward(self):
        grid = self.grid
        TensorXf = type(grid)
        Float = dr.leaf_t(TensorXf)
        g = grid.array
        e, terms = _tv_terms(g, grid.shape)
        grad = dr.zeros(Float, dr.width(g))
        for stride, coord, n, count in terms:
            lower, upper = coord > 0, coord + 1 < n
            below = dr.select(lower, g - dr.gather(Float, g, e - stride, lower), 0.0)
            above = dr.select(upper, dr.gather(Float, g, e + stride, upper) - g, 0.0)
            grad = grad + (2.0 / count) * (below - above)
        self.set_grad_in("grid", TensorXf(grad * self.grad_out(), shape=grid.shape))

    def name(self):
        return "total_variation"


def total_variation(grid):
    """Mean squared difference between neighbouring voxels, summed over the 3 axes, mean over channels.

    ``grid``: a (R, R, R, C) tensor (differentiable) -> Float of width 1. The gradient is
    computed directly by a stencil, ``dTV/dg_v = sum_a 2/n_a ((g_v - g_{v-e_a}) - (g_{v+e_a} - g_v))``
    (terms at the border dropped; ``n_a`` the number of pairs along axis a times C),
    instead of by differentiating the differences: at 64^3 that took 280 ms of a step.

    >>> import mitsuba as mi
    >>> g = mi.TensorXf(np.arange(8, dtype=np.float32).reshape(2, 2, 2, 1))  # +1 in x, +2 in y, +4 in z
    >>> total_variation(g)
    [21]
    """
    if grid.ndim != 4:
        raise ValueError(f"total_variation: expected a (R, R, R, C) tensor, got shape {grid.shape}")
    return dr.custom(_TotalVariation, grid)


def upsample(grid, resolution: int):
    """Resample a (R, R, R, C) grid to (R', R', R', C) by its trilinear lookup at the new voxel centres.

    The same clamped trilinear interpolation the field renders with, so the field changes
    only by the interpolation of an interpolation. Returns a detached tensor.

    >>> import mitsuba as mi
    >>> up = upsample(dr.full(mi.TensorXf, 2.0, (2, 2, 2, 1)), 4)
    >>> up.shape, float(dr.max(up.array)[0]), float(dr.min(up.array)[0])
    ((4, 4, 4, 1), 2.0, 2.0)
    """
    import mitsuba as mi

    TensorXf = type(grid)
    Float = dr.leaf_t(TensorXf)
    UInt32 = dr.uint32_array_t(Float)
    r = int(resolution)
    channels = grid.shape[-1]
    with dr.suspend_grad():
        tex = _texture(mi.Texture3f, dr.detach(grid))
        idx = dr.arange(UInt32, r**3)
        i, j, k = idx % r, (idx // r) % r, idx // (r * r)
        p = mi.Point3f((Float(i) + 0.5) / r, (Float(j) + 0.5) / r, (Float(k) + 0.5) / r)
        values = tex.eval(p)
        out = TensorXf(dr.ravel(values, order="F"), shape=(r, r, r, channels))
        dr.eval(out)
    return out
