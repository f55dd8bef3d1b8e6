"""A medium that knows its lights: single scattering computed through the learned medium, a learned remainder.

Emission-absorption whose colour is computed from the learned medium (:mod:`mitsnerf.fields.media`: extinction
``sigma``, albedo ``a`` and remainder coefficients ``k``, on grids or a hash grid) and the scene's known lights and
phase function (``g``: Henyey-Greenstein's, 0 for an isotropic medium)::

    c(x, d)   = a(x) max(S(x, d) + Rem(x, d), 0)
    S(x, d)   = sum_l p(w_l . d) E_l(x) T_l(x)              single scattering of every delta light l
    T_l(x)    = exp(-int_0^{s_l} sigma(x + s w_l) ds)       through the learned density, to the light

``w_l`` is the direction light ``l`` arrives from, ``E_l`` its irradiance before the medium
(:func:`mitsnerf.scene.lights.light_terms`), ``p`` the phase function (:func:`mitsnerf.math.phase.hg`, directions
as there: ``w . d`` is the scattering angle's cosine). The remainder ``Rem`` is the rest of the in-scattered
light (the environment, and every light scattered more than once) acting through the phase function: with the
rest of the incident radiance expanded as ``L_rest(x, w) = sum_k k_k(x) B_k(w)``, Funk-Hecke gives ::

    Rem(x, d) = sum_k g^{l_k} k_k(x) B_k(d)

over a basis of ``K`` functions: the real spherical harmonics ``Y_lm`` up to ``remainder_degree`` L_f
(Dr.Jit's ``sh_eval``), and for every delta light the zonal harmonics ``sqrt((2l + 1) / 4 pi) P_l(w . w_l)``
around its direction for ``L_f < l <= zonal_degree``: forward-scattered light gathers around the light's
direction, which the zonal terms describe with one coefficient per order instead of ``2 l + 1``. With
``g = 0`` only order 0 survives: ``Rem`` is a colour per point and ``c = a (S + Rem)`` is the oracle's ``J``.

The transmittance to each light is a cache: the optical depth ``tau_l`` to it at the centres of an ``R_t^3`` grid
(``shadow_resolution``) by the midpoint rule with ``shadow_samples`` samples
(:func:`mitsnerf.math.box.march_optical_depth`) through the medium's shadow density, looked up trilinearly, ``T_l =
exp(-tau_l)``. :meth:`ScatterField.with_shadows` computes it from the current
medium; when the medium's gradients are enabled the cache keeps its AD graph, so a loss on the colours reaches
the density along the shadow rays too. ``shadow_resolution = 0`` marches from every sample instead (exact up to
the march's own quadrature; for checks).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr

from mitsnerf.config import check_fields, param
from mitsnerf.fields.media import cell_centres, grid_of, texture
from mitsnerf.math.box import Box, march_optical_depth
from mitsnerf.math.phase import hg, scattering_cosine
from mitsnerf.scene.lights import light_terms

#: The highest spherical-harmonic order Dr.Jit evaluates (``dr.sh_eval``).
MAX_SH_ORDER = 9


@dataclass(frozen=True)
class ScatterFieldConfig:
    """The remainder's basis, the albedo's start and how the shadows are computed."""

    albedo_init: float = param(0.8, lo=0.0, hi=1.0, lo_open=True, hi_open=True)
    """Initial albedo everywhere."""
    remainder_degree: int = param(3, lo=0, hi=MAX_SH_ORDER)
    """L_f: the remainder's spherical harmonics, every ``m`` of orders ``0 .. L_f`` (all but order 0 vanish in an
    isotropic medium, where the method drops them). 3: the smallest order whose basis (with the zonal terms to 8)
    holds the directional oracle within 0.5 dB on cloud_hg50 and cloud_hg85 (0.04 and 0.31 dB under it; at 1,
    the default until 2026-11-29, 1.89 and 4.05: docs/notes/scatter.md, "Its ceiling by basis, at format 7")."""
    zonal_degree: int = param(8, lo=0, hi=32)
    """Orders ``L_f < l <= zonal_degree`` of zonal harmonics around each delta light (0 or <= L_f: none)."""
    shadow_resolution: int = param(32, lo=0, hi=256)
    """R_t: the transmittance cache's cells per axis (0: march from every sample, no cache)."""
    shadow_samples: int = param(32, lo=1, hi=1024)
    """Midpoint samples per march to a light."""
    shadow_density_resolution: int = param(32, lo=2, hi=256)
    """The grid a hash medium's density is sampled on for the marches (a grid medium marches its own grid)."""
    shadow_gradient: bool = param(True)
    """Differentiate the shadows: a training loss reaches the density along the shadow rays (false: the cache is
    a constant of each step)."""
    shadow_gradient_power: float = param(0.0, lo=0.0, hi=8.0)
    """The shadow rays weighted by the light they see: the gradient of each point's ``T_l(x)`` scaled by
    ``T_l(x)^power`` (its value unchanged; 0: the exact gradient). A point deep in a shadow, whose single scattering
    is a small part of its colour, then no longer moves the density between it and the light to correct what the
    remainder gets wrong there. Measured on four scenes (docs/notes/scatter.md, "The density: where its error
    sits"): on the isotropic cloud it halves the excess the exact gradient grows in the sun's shadow (``shadow_gradient
    = false`` removes it); on cloud_hg50 and the smoke within 0.03 of the exact gradient's density error; on
    cloud_hg85 it loses the core's mass, as false does."""

    def __post_init__(self) -> None:
        check_fields(self)

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


@dataclass(frozen=True)
class Shadows:
    """The transmittance to each delta light: cached on a grid (``textures``), or marched per point (None) through
    ``density`` (the medium's shadow density)."""

    textures: tuple[Any, ...] | None
    density: Any


class ScatterField:
    """The field callable ``(x, d) -> (rgb, sigma)`` of the module docstring; also ``density(x)``,
    ``transmittance(x)`` and the colour's parts.

    ``medium``: a :class:`~mitsnerf.fields.media.GridMedium` or :class:`~mitsnerf.fields.media.HashMedium` whose
    remainder has ``3 K`` values (:meth:`ScatterFieldConfig.n_remainder`); ``lights``: the scene spec's delta
    lights (:func:`mitsnerf.scene.lights.delta_lights`); ``g``: the phase function's asymmetry.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.fields.media import GridMedium, GridMediumConfig
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> from mitsnerf.scene.spec import DirectionalLight
    >>> sun = DirectionalLight(direction=(0.0, 0.0, -1.0), irradiance=(4 * math.pi, 4 * math.pi, 4 * math.pi))
    >>> import numpy as np
    >>> medium = GridMedium.create(GridMediumConfig(sigma_init=2.0), (4, 4, 2), mi.TensorXf, UNIT_BOX, 1,
    ...                            np.zeros(3), 0.5)
    >>> f = ScatterField(ScatterFieldConfig(remainder_degree=0, zonal_degree=0), medium, UNIT_BOX, [sun],
    ...                  0.0).with_shadows()
    >>> rgb, sigma = f(mi.Array3f(0.0, 0.0, 0.0), mi.Array3f(1, 0, 0))  # T = exp(-2 x 0.5), p = 1 / 4 pi
    >>> round(sigma[0], 4), round(rgb.x[0], 3), round(0.5 * math.exp(-1.0), 3)  # cached on a 32^3 grid
    (2.0, 0.184, 0.184)
    """

    def __init__(self, config: ScatterFieldConfig, medium, box: Box, lights: Sequence[Any], g: float,
                 shadows: Shadows | None = None, keep: Callable[[Any], Any] | None = None) -> None:
        self.config, self.medium, self.box, self.lights, self.g = config, medium, box, tuple(lights), float(g)
        k = config.n_remainder(len(self.lights))
        if medium.n_rest != 3 * k:
            raise ValueError(f"scatter field: the medium holds {medium.n_rest} remainder values, the basis needs "
                             f"3 x {k}")
        self.shadows = shadows
        self.keep = keep
        """An emptiness mask ``x -> Float`` (0 where carved, 1 elsewhere: :class:`mitsnerf.fields.media.Carved`)
        the medium's density is multiplied by, in the view rays and the shadows alike; None: none."""

    def _new(self, medium, shadows: Shadows | None) -> ScatterField:
        return ScatterField(self.config, medium, self.box, self.lights, self.g, shadows, self.keep)

    def with_medium(self, medium) -> ScatterField:
        """The same field over another medium (new parameters); its shadows are to be recomputed."""
        return self._new(medium, None)

    def with_keep(self, keep: Callable[[Any], Any] | None) -> ScatterField:
        """The same field with an emptiness mask (None: without); its shadows are to be recomputed."""
        return ScatterField(self.config, self.medium, self.box, self.lights, self.g, None, keep)

    def _carved(self, sigma, x):
        return sigma if self.keep is None else sigma * self.keep(x)

    @property
    def sigma_channels(self) -> int:
        """The density's channels: 1, or 3 (``sigma`` an Array3f, one extinction per colour)."""
        return self.medium.density_channels

    def density(self, x):
        """``sigma(x)``: Float (M,) (an Array3f with 3 density channels), times the emptiness mask."""
        return self._carved(self.medium.density(x), x)

    # -- shadows ---------------------------------------------------------------------------------------------

    def with_shadows(self) -> ScatterField:
        """This field with its transmittance cache computed from the current medium (kept in the AD graph where
        the medium's gradients are enabled; ``shadow_resolution = 0``: marched per point instead)."""
        if not self.config.shadow_gradient:
            with dr.suspend_grad():
                return self._with_shadows()
        return self._with_shadows()

    def _with_shadows(self) -> ScatterField:
        import mitsuba as mi

        cfg = self.config
        shadow_density = self.medium.shadow_density(cfg.shadow_density_resolution)
        density = shadow_density if self.keep is None else lambda x: self._carved(shadow_density(x), x)
        if cfg.shadow_resolution == 0:
            return self._new(self.medium, Shadows(None, density))
        r = cfg.shadow_resolution
        TensorXf = mi.TensorXf
        x = cell_centres(self.box, r, mi.Array3f)
        textures = tuple(texture(grid_of(tau, r, TensorXf)) for tau in self._march(density, x))
        return self._new(self.medium, Shadows(textures, density))

    def _march(self, density, x) -> list:
        """``tau_l(x)``, the optical depth to every delta light, marched through ``density`` (Float, or Array3f
        per colour)."""
        return [march_optical_depth(density, x, w, self.config.shadow_samples, self.box, s_max)
                for w, _, s_max in light_terms(self.lights, x)]

    def transmittance(self, x) -> list:
        """``T_l(x) = exp(-tau_l(x))`` for every delta light (Float (M,), or Array3f per colour): the cache's
        optical depth looked up trilinearly (the optical depth, not ``T``: along a light's direction it is linear in
        a uniform medium, so the lookup is exact there, where interpolating the convex ``exp(-tau)`` would be
        too bright between cells), or marched at ``x``."""
        if self.shadows is None:
            raise RuntimeError("scatter field: call with_shadows() before evaluating it (the transmittance to "
                               "the lights is computed from the current density)")
        if self.shadows.textures is None:
            return [self._seen(tau) for tau in self._march(self.shadows.density, x)]
        p = self.box.to_unit(x)
        out = []
        for tex in self.shadows.textures:
            values = tex.eval(p)
            out.append(self._seen(values[0] if len(values) == 1 else type(x)(*values)))
        return out

    def _seen(self, tau):
        """``exp(-tau)``, its gradient scaled by ``exp(-tau)^shadow_gradient_power`` (the value is unchanged)."""
        power = self.config.shadow_gradient_power
        if power == 0.0 or not dr.grad_enabled(tau):
            return dr.exp(-tau)
        still = dr.detach(tau)
        return dr.exp(-(still + dr.exp(-power * still) * (tau - still)))

    # -- the colour ------------------------------------------------------------------------------------------

    def single_scatter(self, x, d):
        """``S(x, d) = sum_l p(w_l . d) E_l T_l(x)``: Array3f (M,) (before the albedo)."""
        Array3f = type(x)
        total = Array3f(0.0)
        for (w, E, _), T in zip(light_terms(self.lights, x), self.transmittance(x)):
            total = total + E * T * hg(scattering_cosine(w, d), self.g)
        return total

    def remainder(self, x, d, rest: Sequence[Any]):
        """``Rem(x, d)`` from the medium's coefficients ``rest`` at ``x``: Array3f (M,) (before the albedo)."""
        axes = [w for w, _, _ in light_terms(self.lights, x)]
        basis = remainder_basis(d, axes, self.g, self.config.remainder_degree, self.config.zonal_degree)
        return type(x)(*(sum(rest[3 * i + c] * b for i, b in enumerate(basis)) for c in range(3)))

    def __call__(self, x, d):
        width = dr.width(x)
        if dr.width(d) != width:
            d = d + dr.zeros(type(d), width)
        sigma, albedo, rest = self.medium.lookup(x)
        return albedo * dr.maximum(self.single_scatter(x, d) + self.remainder(x, d, rest), 0.0), self._carved(sigma, x)
