"""The single-scattering rung's ceiling keeps what its basis can hold of the oracle's remainder (the orders up to
L_f whole, above them only what is zonal around each delta light), and each row is held to its own rung's
ceiling."""

from __future__ import annotations

import numpy as np
import pytest

from mitsnerf.oracle.rungs import PERFECT_DB, project_remainder
from mitsnerf.oracle.source import sh_basis


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _values(coefficients: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The function sum_k a_k Y_k(w) (red channel) at directions w (M, 3)."""
    order = int(np.sqrt(coefficients.shape[0])) - 1
    return sh_basis(w, order) @ coefficients[:, 0]


def _around(axis: np.ndarray, angle: float, n: int = 7) -> np.ndarray:
    """n directions at ``angle`` from ``axis``, spread around it."""
    helper = _unit(np.cross(axis, [0.3, 0.5, 0.8]))
    other = np.cross(axis, helper)
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)[:, None]
    return np.cos(angle) * axis + np.sin(angle) * (np.cos(phi) * helper + np.sin(phi) * other)


def test_orders_up_to_the_degree_are_kept_whole_and_above_it_only_the_zonal_part():
    rng = np.random.default_rng(0)
    sh = rng.normal(size=(25, 3))                       # orders 0..4
    axis = _unit([0.2, -0.7, 0.4])
    out = project_remainder(sh, axis[None], degree=1, zonal=3)
    assert out.shape == (16, 3)                        # order 4 dropped
    np.testing.assert_array_equal(out[:4], sh[:4])     # orders 0, 1 whole
    high = out.copy()
    high[:4] = 0.0
    ring = _values(high, _around(axis, 0.9))           # what is left above L_f is symmetric about the light
    np.testing.assert_allclose(ring, ring[0], atol=1e-6)  # Dr.Jit evaluates the harmonics in float32
    np.testing.assert_allclose(project_remainder(out, axis[None], 1, 3), out, atol=1e-6)   # a projection


def test_with_two_lights_the_residual_is_orthogonal_to_both_zonal_harmonics():
    rng = np.random.default_rng(1)
    sh = rng.normal(size=(16, 3))
    axes = np.stack([_unit([0, 0, 1]), _unit([1, 0.5, -0.2])])
    out = project_remainder(sh, axes, degree=0, zonal=3)
    for order in (1, 2, 3):
        band = slice(order * order, (order + 1) ** 2)
        z = sh_basis(axes, order)[:, band]
        residual = sh[band] - out[band]
        np.testing.assert_allclose(z @ residual, 0.0, atol=1e-6)


def test_each_row_is_held_to_the_ceiling_of_its_own_rung():
    from mitsnerf.oracle.rungs import ceiling_figures

    class Oracle:
        info: dict = {}

        def metrics(self, footprint):
            return {"psnr_test_medium": 40.0}

    metrics = {"psnr_test_medium": 35.0, "oracle_psnr_test_medium": 41.0, "noise_floor_psnr_medium": 38.0}
    ea = ceiling_figures("emission-absorption", None, Oracle(), None, 3, None, metrics)
    ss = ceiling_figures("single scattering", (1, 8), Oracle(), None, 3, None, metrics)  # isotropic: the oracle's
    ft = ceiling_figures("full transport", None, Oracle(), None, 3, None, metrics)
    assert ea == {"ceiling_psnr_test_medium": 41.0, "gap_to_ceiling": 6.0}
    assert ss == {"ceiling_psnr_test_medium": 40.0, "gap_to_ceiling": 5.0}
    assert ft["ceiling_psnr_test_medium"] == pytest.approx(38.0 + PERFECT_DB)
