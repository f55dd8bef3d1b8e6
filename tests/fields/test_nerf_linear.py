"""``mitsnerf.fields.nerf.linear``: nn.Linear's values, with a bias gradient summed in a fixed order."""

from __future__ import annotations

import drjit as dr
import drjit.nn as nn
import mitsuba as mi
import numpy as np

from mitsnerf.fields.nerf import linear


def _grads(fn, layer, x, g):
    w, b = mi.TensorXf(layer.weights), mi.TensorXf(layer.bias)
    dr.enable_grad(w, b)
    probe = nn.Linear(w.shape[1], w.shape[0])
    probe.weights, probe.bias = w, b
    y = fn(probe, x)
    dr.backward(dr.sum(y * g, axis=None))
    return np.array(dr.detach(y)), np.array(dr.grad(w)), np.array(dr.grad(b))


def test_linear_matches_nn_linear_and_its_bias_gradient_is_reproducible():
    # M large enough that the LLVM backend splits the work between threads: nn.Linear's own
    # bias adjoint (a scatter-add into per-thread copies) then varies in the last bit between runs.
    c_in, c_out, m = 16, 8, 100_000
    rng = np.random.default_rng(0)
    layer, _ = nn.Linear(c_in, c_out)._alloc(mi.TensorXf, c_in, dr.rng(seed=1))
    layer.bias = mi.TensorXf(rng.normal(size=c_out).astype(np.float32))
    x = mi.TensorXf(rng.normal(size=(c_in, m)).astype(np.float32))
    g = mi.TensorXf(rng.normal(size=(c_out, m)).astype(np.float32))

    y, gw, gb = _grads(linear, layer, x, g)
    y_ref, gw_ref, gb_ref = _grads(lambda layer, x: layer(x), layer, x, g)
    np.testing.assert_array_equal(y, y_ref)
    np.testing.assert_array_equal(gw, gw_ref)
    exact = np.array(g, dtype=np.float64).sum(axis=1)
    np.testing.assert_allclose(gb, exact, rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(gb_ref, exact, rtol=1e-4, atol=1e-3)
    for _ in range(20):
        np.testing.assert_array_equal(_grads(linear, layer, x, g)[2], gb)


def test_linear_forward_mode_derivative_of_the_bias():
    layer, _ = nn.Linear(2, 3)._alloc(mi.TensorXf, 2, dr.rng(seed=0))
    b = mi.TensorXf(layer.bias)
    dr.enable_grad(b)
    layer.bias = b
    y = linear(layer, dr.ones(mi.TensorXf, (2, 5)))
    dr.set_grad(b, mi.TensorXf([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(np.array(dr.forward_to(y)), np.repeat([[1.0], [2.0], [3.0]], 5, axis=1))
