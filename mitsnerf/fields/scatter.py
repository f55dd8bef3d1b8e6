"""A medium that knows its lights: density and albedo grids, single scattering computed, a learned remainder.

Emission-absorption whose colour is computed from the learned medium and the scene's known lights and phase
function (``g``: Henyey-Greenstein's, 0 for an isotropic medium)::

    sigma(x)  = sigma_scale softplus(s(x))                  s: density grid (R, R, R, C), C = 1 or 3 (per colour)
    a(x)      = sigmoid(q(x))                               q: albedo grid (R, R, R, 3)
    (or ``density_activation = "relu"``: ``sigma_scale max(s, 0)``; ``albedo_activation = "clamp"``:
    ``clip(q, 0, 1)``: then a grid of the true values is the true medium, trilinear as Mitsuba's gridvolume)
    c(x, d)   = a(x) [ S(x, d) + Rem(x, d) ]
    S(x, d)   = sum_l p(w_l . d) E_l(x) T_l(x)              single scattering of every delta light l
    T_l(x)    = exp(-int_0^{s_l} sigma(x + s w_l) ds)       through the learned density, to the light

``w_l`` is the direction light ``l`` arrives from, ``E_l`` its irradiance before the medium
(:func:`mitsnerf.scene.lights.light_terms`), ``p`` the phase function (:func:`mitsnerf.math.phase.hg`, directions
as there: ``w . d`` is the scattering angle's cosine). The remainder ``Rem`` is the rest of the in-scattered
light (the environment, and every light scattered more than once) acting through the phase function: with the
rest of the incident radiance expanded as ``L_rest(x, w) = sum_k k_k(x) B_k(w)``, Funk-Hecke gives ::

    Rem(x, d) = sum_k g^{l_k} k_k(x) B_k(d)                 k: remainder grid (R_r, R_r, R_r, 3 K)

over a basis of ``K`` functions: the real spherical harmonics ``Y_lm`` up to ``remainder_degree`` L_f
(Dr.Jit's ``sh_eval``), and for every delta light the zonal harmonics ``sqrt((2l + 1) / 4 pi) P_l(w . w_l)``
around its direction for ``L_f < l <= zonal_degree``: forward-scattered light gathers around the light's
direction, which the zonal terms describe with one coefficient per order instead of ``2 l + 1``. With
``g = 0`` only order 0 survives: ``Rem`` is a grid of colours and ``c = a (S + Rem)`` is the oracle's ``J``.

The transmittance to each light is a cache: ``T_l`` at the centres of an ``R_t^3`` grid (``shadow_resolution``)
by the midpoint rule with ``shadow_samples`` samples (:func:`mitsnerf.math.box.march_transmittance`), looked up
trilinearly. :meth:`ScatterField.with_shadows` computes it from the current density; when the density's
gradients are enabled the cache keeps its AD graph, so a loss on the colours reaches the density along the
shadow rays too. ``shadow_resolution = 0`` marches from every sample instead (exact up to the march's own
quadrature; for checks).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.fields.grid import extinction
from mitsnerf.math.activations import sigmoid, softplus
from mitsnerf.math.box import Box, march_transmittance
from mitsnerf.math.phase import hg, scattering_cosine
from mitsnerf.scene.lights import light_terms

#: The highest spherical-harmonic order Dr.Jit evaluates (``dr.sh_eval``).
MAX_SH_ORDER = 9


@dataclass(frozen=True)
class ScatterFieldConfig:
    """What the single-scattering field's grids hold and how its shadows are computed."""

    sigma_scale: float = param(10.0, lo=0.0, lo_open=True)
    """``sigma = sigma_scale * softplus(s)``."""
    sigma_init: float = param(0.1, lo=0.0, lo_open=True)
    """Initial density everywhere (world units^-1)."""
    albedo_init: float = param(0.5, lo=0.0, hi=1.0, lo_open=True, hi_open=True)
    """Initial albedo everywhere."""
    density_activation: str = param("softplus", choices=("softplus", "relu"))
    """After the trilinear lookup: ``sigma_scale softplus(s)`` (smooth, never 0), or ``sigma_scale max(s, 0)``."""
    albedo_activation: str = param("sigmoid", choices=("sigmoid", "clamp"))
    """After the trilinear lookup: ``sigmoid(q)``, or ``clip(q, 0, 1)``."""
    density_channels: int = param(1, choices=(1, 3))
    """1: one density for every colour; 3: one per colour channel (chromatic extinction: each colour's shadows
    and compositing through its own)."""
    remainder_degree: int = param(0, lo=0, hi=MAX_SH_ORDER)
    """L_f: the remainder's spherical harmonics, every ``m`` of orders ``0 .. L_f``."""
    zonal_degree: int = param(0, lo=0, hi=32)
    """Orders ``L_f < l <= zonal_degree`` of zonal harmonics around each delta light (0 or <= L_f: none)."""
    shadow_resolution: int = param(32, lo=0, hi=256)
    """R_t: the transmittance cache's cells per axis (0: march from every sample, no cache)."""
    shadow_samples: int = param(32, lo=1, hi=1024)
    """Midpoint samples per march to a light."""

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def raw_sigma_init(self) -> float:
        """``s`` with ``sigma(s) = sigma_init``."""
        return float(self.raw_sigma(np.float64(self.sigma_init)))

    @property
    def raw_albedo_init(self) -> float:
        """``q`` with ``a(q) = albedo_init``."""
        return float(self.raw_albedo(np.float64(self.albedo_init)))

    def raw_sigma(self, sigma: np.ndarray) -> np.ndarray:
        """The density grid's values ``s`` that give ``sigma`` (numpy; the inverse of the activation).

        >>> ScatterFieldConfig(density_activation="relu").raw_sigma(np.array([0.0, 5.0])).tolist()
        [0.0, 0.5]
        """
        y = np.asarray(sigma, np.float64) / self.sigma_scale
        if self.density_activation == "relu":
            return y
        return y + np.log(-np.expm1(-np.maximum(y, 1e-30)))

    def raw_albedo(self, albedo: np.ndarray) -> np.ndarray:
        """The albedo grid's values ``q`` that give ``albedo`` (numpy)."""
        a = np.asarray(albedo, np.float64)
        if self.albedo_activation == "clamp":
            return a
        a = np.clip(a, 1e-6, 1.0 - 1e-6)
        return np.log(a / (1.0 - a))

    def n_remainder(self, n_lights: int) -> int:
        """K: remainder coefficients per colour channel with ``n_lights`` delta lights.

        >>> ScatterFieldConfig(remainder_degree=1, zonal_degree=8).n_remainder(1)   # 4 + 7
        11
        """
        return (self.remainder_degree + 1) ** 2 + n_lights * max(0, self.zonal_degree - self.remainder_degree)


def legendre(t, order: int) -> list:
    """Legendre polynomials ``P_0 .. P_order`` at ``t`` (Bonnet's recursion ``(l + 1) P_{l+1} = (2 l + 1) t P_l -
    l P_{l-1}``), for floats, numpy arrays and Dr.Jit arrays alike.

    >>> [round(v, 6) for v in legendre(0.5, 3)]
    [1.0, 0.5, -0.125, -0.4375]
    """
    out = [t * 0.0 + 1.0, t]
    for n in range(1, order):
        out.append(((2 * n + 1) * t * out[n] - n * out[n - 1]) / (n + 1))
    return out[: order + 1]


def remainder_basis(d, axes: Sequence[Any], g: float, degree: int, zonal_degree: int) -> list:
    """The remainder's basis at camera directions ``d`` times ``g^l``: ``g^l Y_lm(d)`` for ``l <= degree`` and, per
    axis ``w_j`` (the directions the delta lights arrive from, Array3f), ``g^l sqrt((2l+1)/4 pi) P_l(w_j . d)``
    for ``degree < l <= zonal_degree`` (module docstring). ``d``: Array3f (M,); a list of Floats.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> b = remainder_basis(mi.Array3f(0, 0, 1), [mi.Array3f(0, 0, 1)], 0.5, 0, 1)
    >>> len(b), round(b[0][0] * math.sqrt(4 * math.pi), 6), round(b[1][0] * math.sqrt(4 * math.pi / 3), 6)
    (2, 1.0, 0.5)
    """
    out = []
    if g == 0.0:  # g^l = 0 for l > 0: only Y_00 counts, and 0^0 = 1
        sh = [dr.sh_eval(d, 0)[0]] + [d.x * 0.0] * ((degree + 1) ** 2 - 1)
    else:
        sh = dr.sh_eval(d, degree)
    for k, y in enumerate(sh):
        out.append(y * g ** math.isqrt(k))
    for w in axes:
        p = legendre(scattering_cosine(w, d), zonal_degree)
        for n in range(degree + 1, zonal_degree + 1):
            out.append(p[n] * (g**n * math.sqrt((2 * n + 1) / (4.0 * math.pi))))
    return out


def _texture(tensor):
    import mitsuba as mi

    return mi.Texture3f(tensor, use_accel=False, filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)


def cell_centres(box: Box, resolution: int, Array3f):
    """World positions (Array3f (R^3,)) of an ``R^3`` grid's voxel centres over ``box``, x fastest (``[z, y, x]``
    order, as a tensor (R, R, R, C) is laid out)."""
    Float = type(Array3f().x)
    UInt32 = dr.uint32_array_t(Float)
    r = int(resolution)
    idx = dr.arange(UInt32, r**3)
    i, j, k = idx % r, (idx // r) % r, idx // (r * r)
    return box.from_unit(Array3f((Float(i) + 0.5) / r, (Float(j) + 0.5) / r, (Float(k) + 0.5) / r))


@dataclass(frozen=True)
class Shadows:
    """The transmittance to each delta light: cached on a grid (``textures``), or marched per point (None)."""

    textures: tuple[Any, ...] | None


class ScatterField:
    """The field callable ``(x, d) -> (rgb, sigma)`` of the module docstring; also ``density(x)``, ``albedo(x)``,
    ``transmittance(x)`` and the colour's parts.

    ``sigma_raw`` (R, R, R, C), ``albedo_raw`` (R, R, R, 3) and ``rest`` (R_r, R_r, R_r, 3 K) are Dr.Jit tensors
    (channel ``3 k + c`` of ``rest`` is coefficient ``k`` of colour ``c``); ``lights``: the scene spec's delta
    lights (:func:`mitsnerf.scene.lights.delta_lights`); ``g``: the phase function's asymmetry.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> from mitsnerf.scene.spec import DirectionalLight
    >>> sun = DirectionalLight(direction=(0.0, 0.0, -1.0), irradiance=(4 * math.pi, 4 * math.pi, 4 * math.pi))
    >>> f = ScatterField.create(ScatterFieldConfig(sigma_init=2.0, albedo_init=0.5), 4, 2, mi.TensorXf,
    ...                         UNIT_BOX, [sun], 0.0).with_shadows()
    >>> rgb, sigma = f(mi.Array3f(0.0, 0.0, 0.0), mi.Array3f(1, 0, 0))  # T = exp(-2 x 0.5), p = 1 / 4 pi
    >>> round(sigma[0], 4), round(rgb.x[0], 3), round(0.5 * math.exp(-1.0), 3)  # cached on a 32^3 grid
    (2.0, 0.184, 0.184)
    """

    def __init__(self, config: ScatterFieldConfig, sigma_raw, albedo_raw, rest, box: Box,
                 lights: Sequence[Any], g: float, shadows: Shadows | None = None) -> None:
        self.config, self.box, self.lights, self.g = config, box, tuple(lights), float(g)
        self.n_remainder = config.n_remainder(len(self.lights))
        expected = {"sigma_raw": config.density_channels, "albedo_raw": 3, "rest": 3 * self.n_remainder}
        for name, grid in (("sigma_raw", sigma_raw), ("albedo_raw", albedo_raw), ("rest", rest)):
            if grid.ndim != 4 or grid.shape[-1] != expected[name]:
                raise ValueError(f"scatter field: {name} has shape {tuple(grid.shape)}, expected (R, R, R, "
                                 f"{expected[name]})")
        self.sigma_raw, self.albedo_raw, self.rest = sigma_raw, albedo_raw, rest
        self._sigma_tex, self._albedo_tex, self._rest_tex = (_texture(t) for t in (sigma_raw, albedo_raw, rest))
        self.shadows = shadows

    @classmethod
    def create(cls, config: ScatterFieldConfig, resolution: int, rest_resolution: int, TensorXf, box: Box,
               lights: Sequence[Any], g: float, rest_init: Sequence[float] = (0.0, 0.0, 0.0)) -> ScatterField:
        """Uniform grids: ``sigma_init``, ``albedo_init``, and a remainder of incident radiance ``rest_init`` (RGB)
        from every direction (its order-0 coefficient ``sqrt(4 pi) rest_init``; the rest 0)."""
        r, rr = int(resolution), int(rest_resolution)
        sigma_raw = dr.full(TensorXf, config.raw_sigma_init, (r, r, r, config.density_channels))
        albedo_raw = dr.full(TensorXf, config.raw_albedo_init, (r, r, r, 3))
        channels = 3 * config.n_remainder(len(lights))
        first = np.zeros(channels, dtype=np.float32)
        first[:3] = np.asarray(rest_init, dtype=np.float32) * math.sqrt(4.0 * math.pi)
        rest = TensorXf(np.ascontiguousarray(np.broadcast_to(first, (rr, rr, rr, channels))))
        return cls(config, sigma_raw, albedo_raw, rest, box, lights, g)

    def with_grids(self, sigma_raw=None, albedo_raw=None, rest=None) -> ScatterField:
        """The same field over new grids (the optimiser's, or resampled ones); its shadows are to be recomputed."""
        return ScatterField(self.config, self.sigma_raw if sigma_raw is None else sigma_raw,
                            self.albedo_raw if albedo_raw is None else albedo_raw,
                            self.rest if rest is None else rest, self.box, self.lights, self.g)

    @property
    def resolution(self) -> int:
        return int(self.sigma_raw.shape[0])

    @property
    def sigma_channels(self) -> int:
        """The density's channels: 1, or 3 (``sigma`` an Array3f, one extinction per colour)."""
        return self.config.density_channels

    # -- the medium ------------------------------------------------------------------------------------------

    def density(self, x):
        """``sigma(x)``: Float (M,) (an Array3f with ``density_channels = 3``)."""
        raw = self._sigma_tex.eval(self.box.to_unit(x))
        act = softplus if self.config.density_activation == "softplus" else (lambda v: dr.maximum(v, 0.0))
        return extinction([self.config.sigma_scale * act(v) for v in raw], type(x))

    def albedo(self, x):
        """``a(x)``: Array3f (M,) in [0, 1]."""
        act = sigmoid if self.config.albedo_activation == "sigmoid" else (lambda v: dr.clip(v, 0.0, 1.0))
        return type(x)(*(act(v) for v in self._albedo_tex.eval(self.box.to_unit(x))))

    # -- shadows ---------------------------------------------------------------------------------------------

    def with_shadows(self) -> ScatterField:
        """This field with its transmittance cache computed from the current density (kept in the AD graph
        where the density's gradients are enabled; ``shadow_resolution = 0``: nothing to cache)."""
        r = self.config.shadow_resolution
        if r == 0:
            return ScatterField(self.config, self.sigma_raw, self.albedo_raw, self.rest, self.box, self.lights,
                                self.g, Shadows(None))
        import mitsuba as mi

        TensorXf = type(self.sigma_raw)
        textures = []
        for T in self._march(cell_centres(self.box, r, mi.Array3f)):
            channels = [T] if self.config.density_channels == 1 else [T.x, T.y, T.z]
            rows = dr.ravel(mi.ArrayXf(*channels), order="F")  # (R^3, C) row-major: channels interleaved
            textures.append(_texture(TensorXf(rows, shape=(r, r, r, len(channels)))))
        return ScatterField(self.config, self.sigma_raw, self.albedo_raw, self.rest, self.box, self.lights, self.g,
                            Shadows(tuple(textures)))

    def _march(self, x) -> list:
        """``T_l(x)`` for every delta light, marched through :meth:`density` (Float, or Array3f per colour)."""
        return [march_transmittance(self.density, x, w, self.config.shadow_samples, self.box, s_max)
                for w, _, s_max in light_terms(self.lights, x)]

    def transmittance(self, x) -> list:
        """``T_l(x)`` for every delta light (Float (M,), or Array3f per colour): the cache's lookup, or a march."""
        if self.shadows is None:
            raise RuntimeError("scatter field: call with_shadows() before evaluating it (the transmittance to "
                               "the lights is computed from the current density)")
        if self.shadows.textures is None:
            return self._march(x)
        p = self.box.to_unit(x)
        out = []
        for tex in self.shadows.textures:
            values = tex.eval(p)
            out.append(values[0] if len(values) == 1 else type(x)(*values))
        return out

    # -- the colour ------------------------------------------------------------------------------------------

    def single_scatter(self, x, d):
        """``S(x, d) = sum_l p(w_l . d) E_l T_l(x)``: Array3f (M,) (before the albedo)."""
        Array3f = type(x)
        total = Array3f(0.0)
        for (w, E, _), T in zip(light_terms(self.lights, x), self.transmittance(x)):
            total = total + E * T * hg(scattering_cosine(w, d), self.g)
        return total

    def remainder(self, x, d):
        """``Rem(x, d)``: Array3f (M,) (before the albedo)."""
        axes = [w for w, _, _ in light_terms(self.lights, x)]
        basis = remainder_basis(d, axes, self.g, self.config.remainder_degree, self.config.zonal_degree)
        k = self._rest_tex.eval(self.box.to_unit(x))
        return type(x)(*(sum(k[3 * i + c] * b for i, b in enumerate(basis)) for c in range(3)))

    def __call__(self, x, d):
        width = dr.width(x)
        if dr.width(d) != width:
            d = d + dr.zeros(type(d), width)
        c = self.albedo(x) * dr.maximum(self.single_scatter(x, d) + self.remainder(x, d), 0.0)
        return c, self.density(x)
