"""The closed-form line integral of a truncated anisotropic Gaussian is the integral of its point values."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.math.gaussian import (
    ELLIPSOID_RADIUS,
    ellipsoid_value,
    inverse_frame,
    kernel_value,
    ray_profile,
    segment_integral,
    segment_length,
)


def _floats(values):
    return [float(v) for v in values]


def _kernel(rng):
    q, log_scale = rng.normal(size=4), np.log(rng.uniform(0.05, 0.3, 3))
    return mi.Array3f(*_floats(rng.uniform(-0.2, 0.2, 3))), inverse_frame(mi.Array4f(*_floats(q)),
                                                                          mi.Array3f(*_floats(log_scale)))


@pytest.mark.parametrize("seed", range(4))
def test_segment_integral_is_the_integral_of_the_point_values(seed):
    rng = np.random.default_rng(seed)
    mean, M = _kernel(rng)
    n_rays = 64
    o = rng.normal(size=(n_rays, 3))
    o = 2.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-0.3, 0.3, (n_rays, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t0, t1 = rng.uniform(1.0, 2.0, n_rays), rng.uniform(2.0, 3.2, n_rays)  # segments cutting the shell too
    origins, dirs = mi.Array3f(*(o.T.astype(np.float32))), mi.Array3f(*(d.T.astype(np.float32)))
    closed = np.asarray(segment_integral(ray_profile(origins, dirs, mean, M, 3.0), mi.Float(t0.astype(np.float32)),
                                        mi.Float(t1.astype(np.float32))))
    n = 20000  # midpoint rule on the truncated kernel's point values
    u = (np.arange(n) + 0.5) / n
    t = (t0[:, None] + u[None] * (t1 - t0)[:, None]).ravel()
    x = mi.Array3f(*((o[:, None, k] + t.reshape(n_rays, n) * d[:, None, k]).ravel().astype(np.float32)
                     for k in range(3)))
    g = np.asarray(kernel_value(x, mean, M, 3.0), np.float64).reshape(n_rays, n)
    numeric = g.mean(axis=1) * (t1 - t0)
    assert np.count_nonzero(numeric > 1e-3) > 10  # many rays cross the kernel
    np.testing.assert_allclose(closed, numeric, atol=2e-4 * numeric.max())
    chord = np.asarray(segment_length(ray_profile(origins, dirs, mean, M, ELLIPSOID_RADIUS),
                                      mi.Float(t0.astype(np.float32)), mi.Float(t1.astype(np.float32))))
    inside = np.asarray(ellipsoid_value(x, mean, M), np.float64).reshape(n_rays, n).mean(axis=1) * (t1 - t0)
    assert np.count_nonzero(inside > 1e-3) > 10
    np.testing.assert_allclose(chord, inside, atol=2e-3 * inside.max())


@pytest.mark.parametrize("kernel", ["gaussian", "ellipsoid"])
def test_the_profile_gradient_is_the_finite_difference(kernel):
    rng = np.random.default_rng(5)
    q = mi.Array4f(*_floats(rng.normal(size=4)))
    ls = mi.Array3f(*_floats(np.log(rng.uniform(0.1, 0.3, 3))))
    mean = mi.Array3f(0.05, -0.02, 0.03)
    o, d = mi.Array3f(0.1, 0.0, -2.0), dr.normalize(mi.Array3f(-0.05, 0.02, 1.0))

    def value(q, ls, mean):  # a segment that cuts the kernel (the ray passes 0.05 from its centre: no grazing)
        if kernel == "gaussian":
            return segment_integral(ray_profile(o, d, mean, inverse_frame(q, ls), 3.0), mi.Float(1.8), mi.Float(2.05))
        profile = ray_profile(o, d, mean, inverse_frame(q, ls), ELLIPSOID_RADIUS)
        return segment_length(profile, mi.Float(1.8), mi.Float(2.05)) + segment_length(profile, mi.Float(1.0),
                                                                                       mi.Float(3.0))

    dr.enable_grad(q, ls, mean)
    dr.backward(value(q, ls, mean))
    for name, arr, size in (("q", q, 4), ("ls", ls, 3), ("mean", mean, 3)):
        for i in range(size):
            eps = 1e-3
            plus, minus = [type(arr)(*(dr.detach(arr[j]) + (s * eps if j == i else 0.0) for j in range(size)))
                           for s in (1, -1)]
            args = {"q": dr.detach(q), "ls": dr.detach(ls), "mean": dr.detach(mean)}
            fd = (value(**{**args, name: plus})[0] - value(**{**args, name: minus})[0]) / (2 * eps)
            assert dr.grad(arr)[i][0] == pytest.approx(fd, abs=2e-3), (name, i)
