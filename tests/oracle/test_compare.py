"""The oracle agrees with volpath on a tiny multiple-scattering scene, and not with a broken quadrature."""

from __future__ import annotations

import drjit as dr
import numpy as np
import pytest

import mitsnerf.math.composite as composite_module
from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.math.rays import to_array3f
from mitsnerf.oracle.compare import PointSource, agreement, render_with_variance
from mitsnerf.oracle.source import inner_max_depth
from mitsnerf.render.background import ConstantBackground
from mitsnerf.scene.spec import DirectionalLight
from mitsnerf.verify import mitsuba_refs as M

ENV = (0.4, 0.5, 0.6)
SUN = DirectionalLight(direction=(-0.4, -0.8, -0.45), irradiance=(3.0, 2.8, 2.5))
N = 32


def _blob(r: int = 16, peak: float = 6.0) -> np.ndarray:
    """Dense at the centre, zero at the box faces (so the quadrature's first-order error vanishes)."""
    c = (np.arange(r) + 0.5) / r - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    return (peak * np.clip(1 - (x * x + y * y + z * z) / 0.45**2, 0, None) ** 2).astype(np.float32)


def _case(max_depth: int, spp_ref: int = 512, spp_j: int = 32):
    """(volpath reference (H, W, 3), oracle mean, oracle variance) of a 6x6 view, albedo (0.8, 0.7, 0.6)."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField

    sigma_t = _blob()
    albedo = np.zeros(sigma_t.shape + (3,), np.float32) + np.array([0.8, 0.7, 0.6], np.float32)
    emitters = {"env": M.constant_environment(ENV), "sun": M.directional_light(SUN.direction, SUN.irradiance)}
    camera = Camera.from_fov(look_at((0.3, -2.2, 0.5)), 6, 6, 30.0)
    ref = M.render_reference(M.scene_dict(sigma_t, albedo, emitters, max_depth), camera, spp_ref, seed=1)
    inner = mi.load_dict(M.scene_dict(sigma_t, albedo, emitters, inner_max_depth(max_depth)))
    source = PointSource(inner, GridField.from_arrays(sigma_t, UNIT_BOX, color=albedo), [SUN], UNIT_BOX,
                         spp_j, 64, seed=2)
    o, d = camera.pixel_rays()

    def render():
        mean, var = render_with_variance(source, to_array3f(mi.Array3f, o), to_array3f(mi.Array3f, d), N,
                                         UNIT_BOX, ConstantBackground(ENV))
        return mean.reshape(ref.mean.shape), var.reshape(ref.mean.shape)

    return ref, render


@pytest.fixture(scope="module")
def multiple():
    return _case(-1)


def test_oracle_agrees_with_volpath_under_multiple_scattering(multiple):
    ref, render = multiple
    mean, var = render()
    result = agreement(mean, var, ref.mean, ref.var, ref.n)
    assert result.passed, result.summary()
    # J's own noise is part of the test, and not a negligible part
    assert np.mean(var) > 0.05 * np.mean(ref.var / ref.n)


def test_oracle_fails_with_the_quadrature_mutated(multiple, monkeypatch):
    """T_i = exp(-sum_{j<=i} sigma_j delta_j): each sample's own interval counted in its transmittance."""
    def off_by_one(sigma, delta, n):
        tau = sigma * delta
        T = dr.exp(-dr.block_prefix_sum(tau, n, exclusive=False))
        return T * composite_module.one_minus_exp_neg(tau), dr.exp(-dr.block_sum(tau, n))

    ref, render = multiple
    monkeypatch.setattr(composite_module, "weights", off_by_one)
    mean, var = render()
    result = agreement(mean, var, ref.mean, ref.var, ref.n)
    assert not result.passed, result.summary()
    assert np.abs(result.z_means).max() > 2 * result.critical_mean


@pytest.mark.slow  # its own volpath kernels at max_depth 2: about 15 s here
def test_single_scattering_is_the_delta_term_plus_the_attenuated_environment():
    """max_depth 2 (one scattering): J = albedo (Lbar of paths of depth 1 + the sun's term)."""
    ref, render = _case(2, spp_ref=256, spp_j=16)
    mean, var = render()
    result = agreement(mean, var, ref.mean, ref.var, ref.n)
    assert result.passed, result.summary()
