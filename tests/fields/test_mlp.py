"""The point-major products of :mod:`mitsnerf.fields.mlp` in row slices (CUDA's launch-grid cap)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.mlp import CUDA_GEMM_ROWS, matmul_rows


@pytest.mark.parametrize("max_rows", [1, 3, 7, 11, None])
def test_a_product_in_row_slices_is_the_whole_product_and_so_are_its_gradients(max_rows):
    rng = np.random.default_rng(0)
    X, W = rng.normal(size=(11, 5)).astype(np.float32), rng.normal(size=(5, 3)).astype(np.float32)
    x, w = mi.TensorXf(X), mi.TensorXf(W)
    dr.enable_grad(x, w)
    y = matmul_rows(x, w, max_rows=max_rows)
    assert y.shape == (11, 3)
    np.testing.assert_allclose(np.asarray(y), X @ W, rtol=1e-5, atol=1e-6)
    dr.backward(dr.sum(y * y, axis=None))
    np.testing.assert_allclose(np.asarray(dr.grad(w)), X.T @ (2 * X @ W), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(dr.grad(x)), (2 * X @ W) @ W.T, rtol=1e-4, atol=1e-5)


def test_the_cap_is_cudas_for_8_row_tiles():
    assert CUDA_GEMM_ROWS == 65535 * 8 < 8192 * 64  # an 8192-ray batch at 64 samples passes it
