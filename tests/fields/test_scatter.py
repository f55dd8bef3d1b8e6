"""The single-scattering field: its shadows are the exact transmittance of its own density to each light, its colour
the phase function times the light's irradiance there, and its remainder the phase function acting on a radiance
in its basis (Funk-Hecke). References are written again here in float64 numpy (slab test, trilinear lookup,
Henyey-Greenstein, quadrature over the sphere), sharing nothing with the field but its grids."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.media import GridMedium, GridMediumConfig
from mitsnerf.fields.scatter import ScatterField, ScatterFieldConfig, legendre, remainder_basis
from mitsnerf.math.box import UNIT_BOX
from mitsnerf.scene.spec import DirectionalLight, PointLight
from mitsnerf.verify.mutations import MUTATIONS, Mutation, planted

R = 12
SUN = DirectionalLight(direction=(-0.4, -0.8, -0.45), irradiance=(4.0, 3.8, 3.5))
LAMP = PointLight(position=(0.3, 0.9, 0.2), intensity=(2.0, 2.5, 3.0))


def _raw_density(r: int = R) -> np.ndarray:
    """A smooth, lumpy raw density grid (R, R, R, 1): softplus of it times 10 spans ~0.1 to ~15."""
    z, y, x = np.meshgrid(*(np.linspace(-1, 1, r),) * 3, indexing="ij")
    return (1.2 - 3.0 * (x * x + 0.6 * y * y + z * z) + 0.5 * np.sin(3 * x + 2 * y)).astype(np.float32)[..., None]


def _field(config: ScatterFieldConfig, lights, g: float = 0.0) -> ScatterField:
    """A grid medium (raw density :func:`_raw_density`, an albedo ramp, no remainder) lit by ``lights``."""
    rest = dr.zeros(mi.TensorXf, (2, 2, 2, 3 * config.n_remainder(len(lights))))
    albedo = np.stack(np.meshgrid(*(np.linspace(-1.0, 1.5, R),) * 3, indexing="ij"), axis=-1).astype(np.float32)
    medium = GridMedium(GridMediumConfig(), mi.TensorXf(_raw_density()), mi.TensorXf(albedo), rest, UNIT_BOX)
    return ScatterField(config, medium, UNIT_BOX, lights, g)


def _config(shadow_resolution: int) -> ScatterFieldConfig:
    return ScatterFieldConfig(remainder_degree=0, zonal_degree=0, shadow_resolution=shadow_resolution,
                              shadow_samples=256)


def _trilinear(grid: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Clamped trilinear lookup of a (R, R, R, C) grid at unit positions p (M, 3), voxel centres at (i + 1/2) / R."""
    r = grid.shape[0]
    u = np.clip(p * r - 0.5, 0.0, r - 1.0)
    i0 = np.minimum(np.floor(u).astype(int), r - 2)
    f = u - i0
    out = 0.0
    for corner in range(8):
        o = [(corner >> a) & 1 for a in range(3)]
        w = np.prod([f[:, a] if o[a] else 1.0 - f[:, a] for a in range(3)], axis=0)
        out = out + w[:, None] * grid[i0[:, 2] + o[2], i0[:, 1] + o[1], i0[:, 0] + o[0]]
    return out


def _density64(p_world: np.ndarray) -> np.ndarray:
    raw = _trilinear(_raw_density().astype(np.float64), p_world + 0.5)[:, 0]
    return 10.0 * np.logaddexp(0.0, raw)


def _exact_T(x: np.ndarray, light, n: int = 4000, density=None) -> np.ndarray:
    """exp(-int sigma) from x to the light (point) or to where the ray leaves the box (sun), float64 midpoints
    (``density``: :func:`_density64` unless given)."""
    if isinstance(light, DirectionalLight):
        w = -np.asarray(light.direction) / np.linalg.norm(light.direction)
        w = np.broadcast_to(w, x.shape)
        with np.errstate(divide="ignore"):
            t = np.maximum((0.5 - x) / w, (-0.5 - x) / w)
        s = np.min(t, axis=1)
    else:
        v = np.asarray(light.position) - x
        s_light = np.linalg.norm(v, axis=1)
        w = v / s_light[:, None]
        with np.errstate(divide="ignore"):
            t = np.maximum((0.5 - x) / w, (-0.5 - x) / w)
        s = np.minimum(np.min(t, axis=1), s_light)
    k = (np.arange(n) + 0.5) / n
    pts = x[:, None, :] + (s[:, None, None] * k[None, :, None]) * w[:, None, :]
    tau = (density or _density64)(pts.reshape(-1, 3)).reshape(len(x), n).mean(axis=1) * s
    return np.exp(-tau)


def _points(m: int = 300, seed: int = 1):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-0.45, 0.45, (m, 3))
    d = rng.normal(size=(m, 3))
    return x, d / np.linalg.norm(d, axis=1, keepdims=True)


def _hg(cos: np.ndarray, g: float) -> np.ndarray:
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * cos) ** 1.5)


def _host(v) -> np.ndarray:
    """A Float as (M,), an Array3f as (M, 3), float64."""
    return np.asarray(v, np.float64).T if isinstance(v, mi.Array3f) else np.asarray(v, np.float64)


def _check_transmittance(shadow_resolution: int, atol: float) -> None:
    x, _ = _points()
    field = _field(_config(shadow_resolution), [SUN, LAMP])
    T = field.with_shadows().transmittance(mi.Array3f(*x.T.astype(np.float32)))
    for light, got in zip((SUN, LAMP), T):
        np.testing.assert_allclose(_host(got), _exact_T(x, light), atol=atol, err_msg=light.type)


def test_shadow_transmittance_is_the_exact_transmittance_of_its_density():
    """Marched per point (shadow_resolution 0), T is the float64 transmittance to within the midpoint rule's error;
    the 32^3 cache (the default) within its trilinear interpolation's (measured: up to 4.8e-3 here; 1.9e-2 at 16^3,
    1.2e-3 at 64^3: second order)."""
    _check_transmittance(0, 2e-4)
    _check_transmittance(32, 1e-2)


def _check_colour(g: float) -> None:
    x, d = _points(seed=2)
    field = _field(_config(0), [SUN, LAMP], g).with_shadows()
    xs, ds = mi.Array3f(*x.T.astype(np.float32)), mi.Array3f(*d.T.astype(np.float32))
    rgb, _ = field(xs, ds)
    albedo = 1.0 / (1.0 + np.exp(-_trilinear(np.stack(np.meshgrid(*(np.linspace(-1.0, 1.5, R),) * 3,
                                                                   indexing="ij"), axis=-1), x + 0.5)))
    expected = 0.0
    for light in (SUN, LAMP):
        if isinstance(light, DirectionalLight):
            w = np.broadcast_to(-np.asarray(light.direction) / np.linalg.norm(light.direction), x.shape)
            E = np.broadcast_to(light.irradiance, x.shape)
        else:
            v = np.asarray(light.position) - x
            r2 = np.sum(v * v, axis=1, keepdims=True)
            w, E = v / np.sqrt(r2), np.asarray(light.intensity) / r2
        expected = expected + E * (_hg(np.sum(w * d, axis=1), g) * _exact_T(x, light))[:, None]
    np.testing.assert_allclose(_host(rgb), albedo * expected, rtol=2e-3, atol=1e-5)


@pytest.mark.parametrize("g", [0.0, 0.7])
def test_colour_is_albedo_times_the_phase_function_times_each_lights_attenuated_irradiance(g):
    _check_colour(g)


@pytest.mark.parametrize(("mutation", "check"), [
    ("light_direction_flipped", lambda: _check_transmittance(0, 2e-4)),
    ("phase_factor_missing", lambda: _check_colour(0.7)),
])
def test_the_checks_fail_on_a_planted_bug(mutation, check):
    with planted(MUTATIONS[mutation]), pytest.raises(AssertionError):
        check()


def _sphere_quadrature(n: int = 200_000, seed: int = 3) -> np.ndarray:
    w = np.random.default_rng(seed).normal(size=(n, 3))
    return w / np.linalg.norm(w, axis=1, keepdims=True)


@pytest.mark.parametrize("g", [0.5, 0.85])
def test_the_remainder_is_the_phase_function_acting_on_its_radiance(g):
    """Funk-Hecke, checked by Monte Carlo: a remainder coefficient 1 on basis function k (the radiance arriving
    from w is B_k(w)) scatters towards -d as int p(w . d) B_k(w) dw, which the field computes as g^l B_k(d)."""
    axis = np.array([0.3, -0.5, 0.81])
    axis /= np.linalg.norm(axis)
    w = _sphere_quadrature()
    d = np.array([[0.0, 0.6, 0.8], [-0.7, 0.1, -0.7071], [axis[0], axis[1], axis[2]]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    degree, zonal = 1, 4
    basis_w = remainder_basis(mi.Array3f(*w.T.astype(np.float32)), [mi.Array3f(*(float(a) for a in axis))], 1.0,
                              degree, zonal)  # g = 1: the bare basis B_k(w)
    got = remainder_basis(mi.Array3f(*d.T.astype(np.float32)), [mi.Array3f(*(float(a) for a in axis))], g, degree,
                          zonal)
    for k, (b_w, b_d) in enumerate(zip(basis_w, got)):
        p = _hg(w @ d.T, g)  # (n, 3): the phase function for each d
        expected = 4 * math.pi * np.mean(p * np.asarray(b_w, np.float64)[:, None], axis=0)
        np.testing.assert_allclose(np.broadcast_to(np.asarray(b_d, np.float64), (3,)), expected, atol=0.02,
                                   err_msg=f"basis {k}")


def test_legendre_polynomials_are_orthogonal():
    t = np.linspace(-1.0, 1.0, 200001)
    p = legendre(t, 6)
    gram = np.array([[np.trapezoid(a * b, t) for b in p] for a in p])
    np.testing.assert_allclose(gram, np.diag([2.0 / (2 * n + 1) for n in range(7)]), atol=1e-6)


def _shadow_gradient(**settings) -> tuple[np.ndarray, float, float]:
    """The gradient (R^3 [z, y, x]) of the single scattering at a point lit straight down through the lumpy grid
    with respect to the raw density, with the field's ``settings``; that colour, and the point's ``T``."""
    config = ScatterFieldConfig(remainder_degree=0, zonal_degree=0, shadow_resolution=16, shadow_samples=32,
                                **settings)
    field = _field(config, [DirectionalLight(direction=(0.0, 0.0, -1.0), irradiance=(1.0, 1.0, 1.0))])
    sigma = field.medium.params["sigma_raw"]
    dr.enable_grad(sigma)
    field = field.with_medium(field.medium.with_params({"sigma_raw": sigma})).with_shadows()
    x = mi.Array3f(0.1, -0.2, -0.4)            # under the lumpy medium: the sun comes down through it
    colour = dr.sum(field.single_scatter(x, mi.Array3f(0.0, 0.0, -1.0)).x)
    dr.backward(colour, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    with dr.suspend_grad():
        T = float(field.transmittance(x)[0][0])
    return np.asarray(dr.grad(sigma), np.float64).reshape(R, R, R), float(colour[0]), T


@pytest.mark.parametrize("shadow_gradient", [True, False])
def test_a_loss_on_the_colour_reaches_the_density_along_the_shadow_rays(shadow_gradient):
    """The single scattering at points in front of a slab of the grid, lit through it: the colour there depends on
    the slab's density only through the transmittance to the light, which the cache keeps in the AD graph (or not,
    with ``shadow_gradient = false``)."""
    g = np.abs(_shadow_gradient(shadow_gradient=shadow_gradient)[0])
    assert (g.sum() > 0) == shadow_gradient
    if shadow_gradient:  # the sun comes straight down: only the column above (x, y) = (0.1, -0.2) is on its rays
        assert g[:, :, :5].sum() == 0 and g[:, :, 9:].sum() == 0 and g[:, 6:, :].sum() == 0


def _check_shadow_weight(power: float) -> None:
    exact, colour, T = _shadow_gradient()
    weighted, weighted_colour, _ = _shadow_gradient(shadow_gradient_power=power)
    assert 1e-3 < T < 0.95 and np.abs(exact).sum() > 0
    assert weighted_colour == colour
    np.testing.assert_allclose(weighted, exact * T ** power, rtol=1e-4, atol=1e-12)


@pytest.mark.parametrize("power", [1.0, 2.5])
def test_the_shadow_rays_weighted_by_the_light_they_see_scale_the_exact_gradient_by_T_to_the_power(power):
    """``shadow_gradient_power``: the colour is unchanged, its gradient along the shadow rays is the exact one times
    ``T_l(x)^power`` at the lit point."""
    _check_shadow_weight(power)


#: The shadow rays weighted by ``T`` whatever the power: planted in the field's own weighting.
POWER_IGNORED = Mutation("shadow_weight_power_ignored", "the shadow rays weighted by T whatever the power",
                         "mitsnerf.fields.scatter", "ScatterField._seen", "dr.exp(-power * still)", "dr.exp(-still)",
                         kind="gradient")


def test_the_shadow_weight_check_fails_on_a_weight_that_ignores_the_power():
    with planted(POWER_IGNORED), pytest.raises(AssertionError):
        _check_shadow_weight(2.5)


def _carved_density64(p: np.ndarray) -> np.ndarray:
    """:func:`_density64` with the half ``x < 0`` of the box carved."""
    return np.where(p[:, 0] < 0.0, 0.0, _density64(p))


def _check_carved() -> None:
    """With half the box carved (the half x < 0), the density is 0 there and the shadows are the exact transmittance
    of the carved density."""
    from mitsnerf.fields.media import Carved

    keep = np.ones((2, 2, 2), dtype=bool)
    keep[:, :, 0] = False
    x, _ = _points()
    xs = mi.Array3f(*x.T.astype(np.float32))
    field = _field(_config(0), [SUN, LAMP]).with_keep(Carved(keep, UNIT_BOX)).with_shadows()
    sigma = _host(field.density(xs))
    np.testing.assert_array_equal(sigma[x[:, 0] < 0.0], 0.0)
    np.testing.assert_allclose(sigma[x[:, 0] >= 0.0], _density64(x[x[:, 0] >= 0.0]), rtol=1e-4)
    for light, got in zip((SUN, LAMP), field.transmittance(xs)):
        exact, uncarved = _exact_T(x, light, density=_carved_density64), _exact_T(x, light)
        np.testing.assert_allclose(_host(got), exact, atol=1e-2, err_msg=light.type)
        assert np.max(np.abs(exact - uncarved)) > 0.3, light.type


def test_an_emptiness_mask_carves_the_density_in_the_view_and_the_shadow_rays():
    _check_carved()


def test_the_carving_check_fails_when_the_shadows_skip_the_mask():
    """Planted in the field's own shadow computation: the marches through the uncarved density (carved haze would
    still cast its shadow)."""
    from mitsnerf.verify.mutations import Mutation

    bug = Mutation("carve_skips_shadows", "the shadows marched through the uncarved density", "mitsnerf.fields.scatter",
                   "ScatterField._with_shadows", "density = shadow_density if self.keep is None else",
                   "density = shadow_density if True else")
    with planted(bug), pytest.raises(AssertionError):
        _check_carved()
