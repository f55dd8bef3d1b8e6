"""The primitive field found through its cell lists is the sum over every kernel, computed directly."""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.primitives import CellLists, Kernels, PrimitiveField, PrimitiveFieldConfig
from mitsnerf.fields.sh import sh_basis
from mitsnerf.math.box import Box

BOX = Box((-0.6, -0.5, -0.4), (0.5, 0.5, 0.7))


def _params(rng, n: int, channels: int = 1, degree: int = 1):
    k = (degree + 1) ** 2
    return {"mean": rng.uniform(-0.7, 0.7, (n, 3)), "log_scale": np.log(rng.uniform(0.03, 0.2, (n, 3))),
            "rotation": rng.normal(size=(n, 4)), "density": np.log(rng.uniform(0.5, 10.0, (n, channels))),
            "sh": rng.normal(size=(n, 3 * k))}


def _tensors(p):
    return {key: mi.TensorXf(v.astype(np.float32)) for key, v in p.items()}


def _brute(p, x, d, degree: int, kernel: str = "gaussian"):
    """``(rgb, sigma per channel)`` at numpy points ``x`` (M, 3), every kernel summed (float64)."""
    q = p["rotation"] / np.linalg.norm(p["rotation"], axis=1, keepdims=True)
    qx, qy, qz, qw = q.T
    R = np.stack([1 - 2 * (qy**2 + qz**2), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw),
                  2 * (qx * qy + qz * qw), 1 - 2 * (qx**2 + qz**2), 2 * (qy * qz - qx * qw),
                  2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx**2 + qy**2)], 1).reshape(-1, 3, 3)
    local = np.einsum("nji,mnj->mni", R, x[:, None, :] - p["mean"][None]) / np.exp(p["log_scale"])[None]
    m2 = np.sum(local**2, axis=2)
    g = np.where(m2 <= 9.0, np.exp(-0.5 * m2), 0.0) if kernel == "gaussian" else np.where(m2 <= 5.0, 1.0, 0.0)
    sigma = np.exp(p["density"])
    sigma = np.repeat(sigma, 3, axis=1) if sigma.shape[1] == 1 else sigma
    w = g[:, :, None] * sigma[None]
    Y = np.stack([np.asarray(v) for v in sh_basis(mi.Array3f(*(float(c) for c in d)), degree)]).ravel()
    raw = np.einsum("nkc,k->nc", p["sh"].reshape(len(sigma), -1, 3), Y)
    colour = 1.0 / (1.0 + np.exp(-raw))
    inside = np.all((x >= np.asarray(BOX.lo)) & (x < np.asarray(BOX.hi)), axis=1)
    density = w.sum(axis=1) * inside[:, None]
    rgb = np.einsum("mnc,nc->mc", w, colour) / np.maximum(w.sum(axis=1), 1e-30)
    return rgb, density


@pytest.mark.parametrize("channels, cells, kernel", [(1, 5, "gaussian"), (3, 7, "gaussian"), (1, 1, "gaussian"),
                                                     (1, 5, "ellipsoid"), (3, 3, "ellipsoid")])
def test_the_field_is_the_sum_over_every_kernel(channels, cells, kernel):
    rng = np.random.default_rng(channels + cells)
    p = _params(rng, 60, channels)
    config = PrimitiveFieldConfig(density_channels=channels, cells=cells, kernel=kernel)
    field = PrimitiveField(Kernels(config, _tensors(p)), BOX)
    x = rng.uniform(-0.75, 0.75, (3000, 3))  # inside and outside the box
    X = mi.Array3f(*(x.T.astype(np.float32)))
    d = np.array([0.3, -0.5, 0.8]) / math.sqrt(0.98)
    rgb, sigma = field(X, mi.Array3f(*(float(c) for c in d)))
    rgb_ref, sigma_ref = _brute(p, x.astype(np.float32).astype(np.float64), d, 1, kernel)
    sigma = _channels(sigma, channels)
    np.testing.assert_array_equal(_channels(field.density(X), channels), sigma)
    np.testing.assert_allclose(sigma, sigma_ref[:, :channels], rtol=1e-4, atol=1e-5)
    dense = sigma_ref[:, 0] > 1e-3
    assert dense.sum() > 300 and (sigma_ref[:, 0] == 0).sum() > 100  # both cases were seen
    rgb = np.stack([np.asarray(c) for c in rgb], 1)
    np.testing.assert_allclose(rgb[dense], rgb_ref[dense], atol=1e-4)


def _channels(sigma, channels: int) -> np.ndarray:
    """(M, channels) numpy of a Float or Array3f density."""
    return np.stack([np.asarray(s) for s in sigma], 1) if channels == 3 else np.asarray(sigma)[:, None]


def test_lists_hold_every_kernel_that_overlaps_a_cell_and_none_outside_the_box():
    rng = np.random.default_rng(3)
    p = _params(rng, 30)
    p["mean"][0] = (3.0, 0.0, 0.0)  # far outside: listed nowhere
    kernels = Kernels(PrimitiveFieldConfig(cells=6), _tensors(p))
    lists = CellLists.build(kernels, BOX, mi.UInt32)
    items = np.asarray(lists.items)[: lists.pairs]
    offsets = np.asarray(lists.offsets)
    assert offsets[-1] == lists.pairs and len(offsets) == 6**3 + 1 and np.all(np.diff(offsets.astype(int)) >= 0)
    assert 0 not in items and set(items) == set(range(1, 30)) - _outside(p)
    for c in range(6**3):  # sorted, unique kernel indices per cell
        cell = items[offsets[c]:offsets[c + 1]]
        assert np.all(np.diff(cell.astype(int)) > 0)


def _outside(p) -> set:
    """Kernels whose shell's bounding box misses the box."""
    from mitsnerf.fields.primitives import shell_extents

    _, M = Kernels(PrimitiveFieldConfig(), _tensors(p)).numpy_geometry()
    ext = shell_extents(M, 3.0)
    lo, hi = np.asarray(BOX.lo), np.asarray(BOX.hi)
    miss = np.any((p["mean"] + ext < lo) | (p["mean"] - ext >= hi), axis=1)
    return set(np.flatnonzero(miss)) - {0}
