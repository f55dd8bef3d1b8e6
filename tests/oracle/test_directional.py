"""The directional oracle's algebra: Henyey-Greenstein acts on spherical harmonics as g^l (Funk-Hecke), with the
conventions the field uses (w where light arrives from, d the camera ray); at g = 0 it is the isotropic oracle."""

from __future__ import annotations

import numpy as np
import pytest

import mitsnerf  # noqa: F401  (sets up LLVM before drjit loads anywhere)
from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.phase import hg, sample_hg, scattering_cosine
from mitsnerf.oracle.field import DirectionalOracleField, OracleField
from mitsnerf.oracle.source import sh_basis

A = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])


def radiance(w: np.ndarray) -> np.ndarray:
    """A smooth, asymmetric radiance L(w) (where light arrives from), RGB."""
    lobe = np.exp(3.0 * scattering_cosine(w, A))
    return np.stack([lobe, 0.5 * lobe + 1.0, np.ones_like(lobe)], axis=-1)


def uniform_sphere(n: int, seed: int) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def coefficients() -> np.ndarray:
    """L_lm of ``radiance`` up to order 6 by quadrature on 200k uniform directions: (2, 2, 2, 49, 3)."""
    w = uniform_sphere(200_000, 0)
    c = 4 * np.pi * (sh_basis(w, 6)[:, :, None] * radiance(w)[:, None, :]).mean(axis=0)
    return np.broadcast_to(c, (2, 2, 2) + c.shape).astype(np.float32)


@pytest.mark.parametrize("g", [0.5, -0.3])
def test_the_field_is_the_phase_weighted_integral(coefficients, g):
    import mitsuba as mi

    from mitsnerf.env import set_variant

    set_variant(mi.variant())
    field = DirectionalOracleField.from_grids(np.ones((2, 2, 2)), (1.0, 1.0, 1.0), coefficients, g, [],
                                              np.zeros((2, 2, 2, 0, 3), np.float32), UNIT_BOX, window="none")
    d = uniform_sphere(6, 1)
    got = np.stack([np.asarray(c) for c in field(mi.Array3f(np.zeros(6), np.zeros(6), np.zeros(6)),
                                                 mi.Array3f(*d.T))[0]], axis=-1)
    # int p(w . d) L(w) dw with directions drawn from the lobe (math.phase.sample_hg), 200k per d
    rng = np.random.default_rng(2)
    want = np.stack([radiance(sample_hg(np.tile(v, (200_000, 1)), rng.random((200_000, 2)), g)).mean(axis=0)
                     for v in d])
    np.testing.assert_allclose(got, want, rtol=0.01)  # order 6: |g|^7 <= 0.008


def test_at_g_zero_it_is_the_isotropic_oracle():
    import mitsuba as mi

    from mitsnerf.env import set_variant
    from mitsnerf.oracle.field import render_field
    from mitsnerf.math.camera import Camera, look_at
    from mitsnerf.scene.spec import DirectionalLight

    set_variant(mi.variant())
    rng = np.random.default_rng(0)
    sigma_t, albedo = 4.0 * rng.random((4, 4, 4)), rng.random((4, 4, 4, 3))
    lbar, e = rng.random((4, 4, 4, 3)), rng.random((4, 4, 4, 1, 3))
    sh = np.zeros((4, 4, 4, 9, 3), np.float32)
    sh[..., 0, :] = np.sqrt(4 * np.pi) * lbar  # L_00 = sqrt(4 pi) Lbar
    sun = DirectionalLight(direction=(0.2, 0.3, -1.0), irradiance=(1.0, 1.0, 1.0))
    directional = DirectionalOracleField.from_grids(sigma_t, albedo, sh, 0.0, [sun], e.astype(np.float32), UNIT_BOX)
    isotropic = OracleField.from_grids(sigma_t, albedo, lbar, e[..., 0, :] / (4 * np.pi), UNIT_BOX)
    cams = [Camera.from_fov(look_at((0.0, -2.5, 0.3)), 8, 8, 40.0)]
    a, b = (render_field(f, cams, UNIT_BOX, 32) for f in (directional, isotropic))
    np.testing.assert_allclose(a, b, rtol=2e-5, atol=1e-6)


def test_hg_is_what_mitsuba_evaluates():
    """Mitsuba's hg plugin, asked for light arriving from w seen along d (wi = -d), gives math.phase.hg."""
    import mitsuba as mi

    from mitsnerf.env import set_variant

    set_variant(mi.variant())
    phase = mi.load_dict({"type": "hg", "g": 0.7})
    w, d = uniform_sphere(64, 3), uniform_sphere(64, 4)
    ctx, mei = mi.PhaseFunctionContext(), mi.MediumInteraction3f()
    mei.wi = mi.Vector3f(*(-d).T)
    mei.sh_frame = mi.Frame3f(mei.wi)
    value = phase.eval_pdf(ctx, mei, mi.Vector3f(*w.T))[0]
    np.testing.assert_allclose(np.asarray(value)[0], hg(scattering_cosine(w, d), 0.7), rtol=1e-5)  # every channel


def test_the_error_patterns_carry_the_estimates_variance():
    """The colour seen looking at the sun through a g = 0.9 medium, from the coefficients: its spread over 40
    independent estimates matches the mean square of the same colour computed from the error patterns, which
    carry the coefficients' covariance; their variances alone (as if independent) would miss most of it."""
    import mitsuba as mi

    from mitsnerf.env import set_variant
    from mitsnerf.math.phase import band_factors
    from mitsnerf.oracle.source import radiance_sh
    from mitsnerf.scene.to_mitsuba import medium_box

    set_variant(mi.variant())
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "volpath"},
        "box": medium_box(np.full((2, 2, 2), 3.0, np.float32), 0.8, UNIT_BOX, {"type": "hg", "g": 0.9}),
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [0.2, 0.2, 0.2]}},
        "sun": {"type": "directional", "direction": [0.0, 0.3, -1.0], "irradiance": {"type": "rgb", "value": [5.0] * 3}},
    })
    points, order = np.array([[0.0, 0.0, 0.0], [0.2, -0.1, 0.3], [-0.3, 0.2, -0.2]]), 6
    towards_sun = np.array([0.0, -0.3, 1.0]) / np.linalg.norm([0.0, -0.3, 1.0])
    weights = sh_basis(towards_sun, order) * band_factors(0.9, order, "none")   # c(d) per coefficient

    def colour(coefficients: np.ndarray) -> np.ndarray:
        return np.einsum("k,...kc->...c", weights, coefficients)

    estimates = [radiance_sh(scene, points, 128, order, seed=s, replicas=4) for s in range(40)]
    spread = np.var([colour(e.mean) for e in estimates], axis=0, ddof=1).mean()
    predicted = np.mean([np.square(colour(e.errors)).mean() for e in estimates])
    independent = np.mean([np.einsum("k,...kc->...c", weights**2, e.se**2).mean() for e in estimates])
    assert 0.7 < predicted / spread < 1.4  # 40 estimates: the spread itself is known to about 20%
    assert independent / spread < 0.5     # measured 0.12: the covariance is most of it
