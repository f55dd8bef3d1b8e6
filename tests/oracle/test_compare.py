"""The oracle agrees with volpath on a tiny multiple-scattering scene, and not with a broken quadrature."""

from __future__ import annotations

import numpy as np
import pytest

from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.math.rays import to_array3f
from mitsnerf.oracle.compare import PointSource, agreement, render_with_variance
from mitsnerf.oracle.source import inner_max_depth
from mitsnerf.render.background import ConstantBackground
from mitsnerf.scene.spec import DirectionalLight
from mitsnerf.verify import mitsuba_refs as M
from mitsnerf.verify.cases import CAMERA_FOV_DEG, CAMERA_ORIGIN, front_heavy_sigma_t, procedural_albedo
from mitsnerf.verify.mutations import MUTATIONS, planted

ENV = (0.4, 0.5, 0.6)
SUN = DirectionalLight(direction=(-0.4, -0.8, -0.45), irradiance=(3.0, 2.8, 2.5))
N = 16


def _case(max_depth: int, spp_ref: int = 1024, spp_j: int = 32):
    """(volpath reference (H, W, 3), a renderer of the oracle's mean and variance) of an 8x8 view of the
    check's front-heavy medium (dense where the camera's rays enter, vanishing where they leave, so the
    quadrature's first-order error is zero and a delta from the wrong end is not), procedural albedo."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField

    sigma_t, albedo = front_heavy_sigma_t(16, 8.0), procedural_albedo(16)
    emitters = {"env": M.constant_environment(ENV), "sun": M.directional_light(SUN.direction, SUN.irradiance)}
    camera = Camera.from_fov(look_at(CAMERA_ORIGIN, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)), 8, 8, CAMERA_FOV_DEG)
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


@pytest.mark.parametrize("name", ["T_off_by_one", "delta_wrong_end", "no_background"])
def test_oracle_fails_with_the_quadrature_mutated(multiple, name):
    """Each of the check's planted value bugs in the compositing and the sampling is seen."""
    ref, render = multiple
    with planted(MUTATIONS[name]):
        mean, var = render()
    result = agreement(mean, var, ref.mean, ref.var, ref.n)
    assert not result.passed, result.summary()


@pytest.mark.slow  # its own volpath kernels at max_depth 2: about 15 s here
def test_single_scattering_is_the_delta_term_plus_the_attenuated_environment():
    """max_depth 2 (one scattering): J = albedo (Lbar of paths of depth 1 + the sun's term)."""
    ref, render = _case(2, spp_ref=256, spp_j=16)
    mean, var = render()
    result = agreement(mean, var, ref.mean, ref.var, ref.n)
    assert result.passed, result.summary()
