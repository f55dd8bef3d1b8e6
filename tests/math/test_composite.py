import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.math.composite import composite, weights


def _np(x):
    return np.asarray(x, dtype=np.float64)


def _reference(sigma, delta, c, bg):
    """Direct transcription of the quadrature in docs/conventions.md, one ray at a time."""
    R, N = sigma.shape
    C = np.zeros((R, 3))
    for r in range(R):
        T = 1.0
        for i in range(N):
            a = 1.0 - np.exp(-sigma[r, i] * delta[r, i])
            C[r] += T * a * c[r, i]
            T *= np.exp(-sigma[r, i] * delta[r, i])
        C[r] += T * bg
    return C


def test_composite_matches_the_formula_on_random_rays():
    rng = np.random.default_rng(0)
    R, N = 37, 11
    sigma = rng.exponential(3.0, (R, N)).astype(np.float32)
    delta = rng.uniform(0.0, 0.2, (R, N)).astype(np.float32)
    c = rng.uniform(0, 1, (R, N, 3)).astype(np.float32)
    bg = np.array([0.2, 0.5, 0.9])
    out = composite(mi.Float(sigma.ravel()), mi.Float(delta.ravel()),
                    mi.Color3f(*np.ascontiguousarray(c.reshape(-1, 3).T)), N, background=mi.Color3f(*bg.tolist()))
    got = np.stack([_np(ch) for ch in out.rgb], -1)
    np.testing.assert_allclose(got, _reference(sigma, delta, c, bg), rtol=2e-5, atol=2e-6)
    T_N = np.exp(-(sigma * delta).sum(1))
    np.testing.assert_allclose(_np(out.T_final), T_N, rtol=1e-5)
    np.testing.assert_allclose(_np(out.opacity), 1 - T_N, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("tau", [0.01, 0.5, 2.0, 8.0])
@pytest.mark.parametrize("n", [1, 3, 64])
def test_homogeneous_slab_opacity_is_exact(tau, n):
    # sigma L = tau split into n equal intervals: opacity 1 - exp(-tau) for any n, and with c
    # constant the colour is c times the opacity.
    L = 1.7
    sigma = mi.Float([tau / L] * n)
    delta = mi.Float([L / n] * n)
    out = composite(sigma, delta, mi.Color3f(0.3, 0.6, 0.9), n)
    np.testing.assert_allclose(_np(out.opacity), [1 - np.exp(-tau)], rtol=1e-5)
    np.testing.assert_allclose(_np(out.rgb.y), [0.6 * (1 - np.exp(-tau))], rtol=1e-5)


def test_piecewise_constant_density_gives_exact_transmittance():
    sigma = np.array([0.0, 2.0, 0.5, 7.0], np.float32)
    delta = np.array([0.3, 0.1, 0.4, 0.05], np.float32)
    w, _ = weights(mi.Float(sigma), mi.Float(delta), 4)
    T = 1.0 - np.concatenate([[0], np.cumsum(_np(w))[:-1]])  # T_i = 1 - sum_{j<i} w_j
    np.testing.assert_allclose(T, np.exp(-np.concatenate([[0], np.cumsum(sigma * delta)[:-1]])), rtol=1e-6)


def test_weights_and_final_transmittance_sum_to_one():
    rng = np.random.default_rng(5)
    sigma = mi.Float(rng.exponential(10, 400).astype(np.float32))
    delta = mi.Float(rng.uniform(0, 0.1, 400).astype(np.float32))
    w, T_final = weights(sigma, delta, 20)
    total = _np(dr.block_sum(w, 20)) + _np(T_final)
    np.testing.assert_allclose(total, 1.0, rtol=1e-5)


def test_gradient_of_opacity_wrt_density_is_analytic():
    # d/dsigma (1 - exp(-sigma L)) = L exp(-sigma L)
    sigma = mi.Float([1.5] * 4)
    dr.enable_grad(sigma)
    delta = mi.Float([0.25] * 4)
    out = composite(sigma, delta, mi.Color3f(1.0), 4)
    dr.backward(out.opacity)
    np.testing.assert_allclose(_np(dr.grad(sigma)), [0.25 * np.exp(-1.5)] * 4, rtol=1e-5)


def test_one_interval_alpha_and_the_weighted_depth():
    # one sample: alpha = 1 - exp(-sigma delta) is the weight; depth = sum_i w_i t_i per ray
    np.testing.assert_allclose(_np(weights(mi.Float(2.0), mi.Float(0.5), 1)[0]), [1 - np.exp(-1.0)], rtol=1e-6)
    sigma, delta, t = mi.Float(1, 2, 3, 4), mi.Float(0.5, 0.5, 0.25, 0.25), mi.Float(1, 1, 2, 2)
    w, _ = weights(sigma, delta, 2)
    depth = composite(sigma, delta, mi.Color3f(0.0), 2, t=t).depth
    np.testing.assert_allclose(_np(depth), (_np(w) * _np(t)).reshape(2, 2).sum(1), rtol=1e-6)
