"""The ``mitsnerf_ea`` Mitsuba integrator renders a field as an independent float64 quadrature does."""

import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.grid import GridField
from mitsnerf.math.box import UNIT_BOX
from mitsnerf.render.mitsuba_plugin import NAME, register
from mitsnerf.verify import cases as C
from mitsnerf.verify import mitsuba_refs as M
from mitsnerf.verify.mutations import MUTATIONS, planted
from mitsnerf.verify.runner import plugin_case
from mitsnerf.verify.sources import render_image

QUALITY = C.QUALITIES["quick"]
CASES = {p.name: p for p in C.PLUGIN_CASES}


@pytest.mark.parametrize("name", list(CASES))
def test_plugin_render_equals_the_float64_quadrature(name):
    r = plugin_case(CASES[name], QUALITY)
    assert r.passed, r.error


@pytest.mark.parametrize("name,mutation", [(p.name, m) for p in C.PLUGIN_CASES for m in p.detects])
def test_a_bug_in_the_shared_quadrature_is_detected(name, mutation):
    # Planted in the package's own function: the plugin runs it, the numpy reference does not.
    with planted(MUTATIONS[mutation]):
        assert not plugin_case(CASES[name], QUALITY).passed


def _scene(n_samples=16, environment=True, width=4):
    register()
    cam = C.Quality("t", width=width, spp=16, n_samples=n_samples).camera()
    d = {"type": "scene", "integrator": {"type": NAME, "n_samples": n_samples},
         "sensor": M.sensor_dict(cam, 1, pixel_centres=True)}
    if environment:
        d["environment"] = M.constant_environment((0.2, 0.4, 0.6))
    return mi.load_dict(d), cam


def test_without_an_environment_the_background_is_black_and_a_set_background_is_used():
    scene, cam = _scene(environment=False)
    field = GridField.from_arrays(np.zeros((4, 4, 4), np.float32), UNIT_BOX)  # empty box: only background
    scene.integrator().field = field
    scene.integrator().box = UNIT_BOX
    assert np.all(np.asarray(mi.render(scene)) == 0.0)
    scene.integrator().background = 0.5
    np.testing.assert_allclose(np.asarray(mi.render(scene)), 0.5)


def test_rendering_before_setting_a_field_says_how_to_fix_it():
    # mi.render wraps the integrator's error; ours is the cause in the chain.
    scene, _ = _scene()
    with pytest.raises(Exception) as info:
        mi.render(scene)
    chain, exc = [], info.value
    while exc is not None:
        chain.append(str(exc))
        exc = exc.__cause__ or exc.__context__
    assert any("set scene.integrator().field" in message for message in chain), chain


def test_n_samples_is_validated():
    register()
    with pytest.raises(Exception, match="n_samples must be an integer >= 1"):
        mi.load_dict({"type": NAME, "n_samples": 0})


def test_register_is_idempotent_and_the_render_uses_n_samples():
    assert register() is register()
    scene, cam = _scene(n_samples=8)
    field = GridField.from_arrays(C.front_heavy_sigma_t(8, 6.0), UNIT_BOX, color=(1.0, 0.5, 0.2))
    scene.integrator().field = field
    scene.integrator().box = UNIT_BOX
    from mitsnerf.render.background import EnvmapBackground

    expected = render_image(field, cam, 8, EnvmapBackground(scene.environment()))
    np.testing.assert_allclose(np.asarray(mi.render(scene)), expected, atol=1e-5)
