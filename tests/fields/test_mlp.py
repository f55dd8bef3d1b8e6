"""The point-major products of :mod:`mitsnerf.fields.mlp` in row slices (CUDA's launch-grid cap) and in split-k
batches (CUDA's default: the weight gradient over many blocks)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mitsnerf.fields.mlp as mlp
from mitsnerf.fields.mlp import dense_apply, dense_init, matmul_rows


@pytest.mark.parametrize(("max_rows", "slices"), [
    (1, 0), (3, 0), (7, 0), (11, 0), (None, 0),                  # row slices, one product each
    (None, 2), (None, 4), (None, 11), (0, 5), (3, 2), (2, 3),    # split-k, with and without a remainder or cap
])
def test_a_product_in_row_slices_is_the_whole_product_and_so_are_its_gradients(max_rows, slices):
    rng = np.random.default_rng(0)
    X, W = rng.normal(size=(11, 5)).astype(np.float32), rng.normal(size=(5, 3)).astype(np.float32)
    x, w = mi.TensorXf(X), mi.TensorXf(W)
    dr.enable_grad(x, w)
    y = matmul_rows(x, w, max_rows=max_rows, slices=slices)
    assert y.shape == (11, 3)
    np.testing.assert_allclose(np.asarray(y), X @ W, rtol=1e-5, atol=1e-6)
    dr.backward(dr.sum(y * y, axis=None))
    np.testing.assert_allclose(np.asarray(dr.grad(w)), X.T @ (2 * X @ W), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(dr.grad(x)), (2 * X @ W) @ W.T, rtol=1e-4, atol=1e-5)


def test_the_fields_networks_multiply_within_the_backends_row_cap(monkeypatch):
    """dense_apply (ngp's MLPs) goes through matmul_rows: under a cap of 3 rows no product sees more, and the
    output is the uncapped one (CUDA's cap is 65535 x 8 rows; past it ngp's batches failed on an H200)."""
    params = dense_init([4, 8, 3], mi.TensorXf, dr.rng(seed=0))
    x = mi.TensorXf(np.random.default_rng(1).normal(size=(10, 4)).astype(np.float32))
    whole = np.asarray(dense_apply(params, "", 2, x))
    rows, matmul = [], dr.matmul

    def spy(a, b, *args, **kwargs):
        rows.append(a.shape[0])
        return matmul(a, b, *args, **kwargs)

    monkeypatch.setattr(mlp, "gemm_row_cap", lambda x: 3)
    monkeypatch.setattr(dr, "matmul", spy)
    capped = np.asarray(dense_apply(params, "", 2, x))
    assert rows and max(rows) == 3 and sum(rows) == 2 * 10  # two layers, 10 rows each, in slices of 3
    np.testing.assert_allclose(capped, whole, rtol=1e-6, atol=1e-7)


def test_the_fields_networks_use_split_k_where_the_backend_asks_for_it(monkeypatch):
    """dense_apply (ngp's MLPs) multiplies in split-k batches when :func:`~mitsnerf.fields.mlp.gemm_split_k` says so
    (CUDA: 64), one batched product per layer plus the remainder's, with the output of one plain product."""
    params = dense_init([4, 8, 3], mi.TensorXf, dr.rng(seed=0))
    x = mi.TensorXf(np.random.default_rng(1).normal(size=(10, 4)).astype(np.float32))
    whole = np.asarray(dense_apply(params, "", 2, x))
    shapes, matmul = [], dr.matmul

    def spy(a, b, *args, **kwargs):
        shapes.append(a.shape)
        return matmul(a, b, *args, **kwargs)

    monkeypatch.setattr(mlp, "gemm_split_k", lambda x: 4)
    monkeypatch.setattr(dr, "matmul", spy)
    split = np.asarray(dense_apply(params, "", 2, x))
    assert shapes == [(4, 2, 4), (2, 4), (4, 2, 8), (2, 8)]  # per layer: 4 batches of 2 rows, then 2 rows
    np.testing.assert_allclose(split, whole, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize(("split_k", "batches"), [(-1, 0), (0, 0), (4, 4)])
def test_ngps_split_k_setting_sets_its_products_batches(monkeypatch, split_k, batches):
    """ngp's ``split_k`` (-1: the backend's default, one product on LLVM) reaches every product of its MLPs, and a
    split field's values are the unsplit one's (what lets a benchmark time ngp with and without it)."""
    import dataclasses

    from mitsnerf.fields.ngp import NGPConfig, NGPField
    from mitsnerf.math.box import UNIT_BOX

    config = NGPConfig(n_levels=2, max_resolution=16, hidden=8, geo_features=3, color_hidden=8, sh_degree=1)
    x = mi.Point3f(*(mi.Float(np.random.default_rng(k).uniform(-0.4, 0.4, 10)) for k in range(3)))
    d = mi.Vector3f(0, 0, 1)
    plain = NGPField(dataclasses.replace(config, split_k=0), mi.TensorXf, UNIT_BOX, seed=2)(x, d)
    shapes, matmul = [], dr.matmul

    def spy(a, b, *args, **kwargs):
        shapes.append(a.shape)
        return matmul(a, b, *args, **kwargs)

    monkeypatch.setattr(dr, "matmul", spy)
    c, sigma = NGPField(dataclasses.replace(config, split_k=split_k), mi.TensorXf, UNIT_BOX, seed=2)(x, d)
    assert shapes and all((len(s) == 3 and s[0] == batches) if batches else len(s) == 2 for s in shapes[::2])
    np.testing.assert_allclose(np.asarray(sigma), np.asarray(plain[1]), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(c), np.asarray(plain[0]), rtol=1e-5, atol=1e-6)
