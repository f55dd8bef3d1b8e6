"""Any pixels through the path tracer (:mod:`mitsnerf.render.path_batch`): the same image and the same gradient, in
expectation, as Mitsuba's own film and ``mi.render``'s adjoint pass over the same view."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.math.rays import PixelRays
from mitsnerf.methods.mitsuba_inverse import MitsubaInverseConfig, MitsubaInverseModel, _rgb_sensor
from mitsnerf.render.path_batch import PathBatch, render_pixels, trace_primal
from mitsnerf.scene.spec import parse_scene
from mitsnerf.scene.to_mitsuba import scene_box

from ..conftest import tiny_scene

SPEC = tiny_scene({"cameras.width": 6, "cameras.height": 6, "render.max_depth": 4})


@pytest.fixture(scope="module")
def model():
    from mitsnerf.methods.base import SceneInfo
    from mitsnerf.render.background import ConstantBackground
    from mitsnerf.scene.rigs import camera_rig

    spec = parse_scene(SPEC, "tiny")
    info = SceneInfo(scene_box(spec), ConstantBackground((0.5, 0.55, 0.6)), 1.0, {"spec": SPEC})
    m = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), init_depth=6.0, carve=False), info)
    m.camera = camera_rig(spec.cameras, "train")[0]
    return m


def _batch(model) -> PathBatch:
    pixels = PixelRays(mi.Float, [model.camera])
    return PathBatch(model.scene, model.scene.integrator(), dr.arange(mi.UInt32, pixels.size), pixels.rays)


def _film_image(model, spp: int, seed: int) -> np.ndarray:
    img = mi.render(model.scene, sensor=_rgb_sensor(model.camera, spp), spp=spp, seed=seed)
    return np.asarray(img, np.float64).reshape(-1, 3)


def test_the_pixels_primal_is_the_films_box_filtered_image(model):
    ours = np.asarray(trace_primal(_batch(model), 4096, seed=7), np.float64).T
    film, again = _film_image(model, 4096, 1), _film_image(model, 4096, 2)
    noise = np.mean(np.abs(film - again))  # two films differ by their noise alone
    assert np.mean(np.abs(ours - film)) < 1.5 * noise, (np.mean(np.abs(ours - film)), noise)
    assert np.abs(ours.mean() - film.mean()) < 0.02 * film.mean()


def _weights(n: int) -> np.ndarray:
    return np.random.default_rng(3).uniform(0.5, 1.5, (n, 3)).astype(np.float32)


def _our_gradient(model, seed: int, spp: int) -> np.ndarray:
    batch, w = _batch(model), _weights(36)
    sigma = mi.TensorXf(model.sigma_t)
    dr.enable_grad(sigma)
    model.params[model._key_sigma] = sigma
    model.params.update()
    image = render_pixels(batch, {"sigma_t": sigma}, spp=4, spp_grad=spp, seed=seed, seed_grad=seed + 1)
    loss = dr.sum(sum(image[c] * mi.Float(w[:, c]) for c in range(3)))
    dr.backward(loss)
    return np.asarray(dr.grad(sigma), np.float64)


def _film_gradient(model, seed: int, spp: int) -> np.ndarray:
    w = _weights(36)
    sigma = mi.TensorXf(model.sigma_t)
    dr.enable_grad(sigma)
    model.params[model._key_sigma] = sigma
    model.params.update()
    img = mi.render(model.scene, model.params, sensor=_rgb_sensor(model.camera, 4), spp=4, spp_grad=spp, seed=seed,
                    seed_grad=seed + 1)
    dr.backward(dr.sum(img.array * mi.Float(w.ravel())))
    return np.asarray(dr.grad(sigma), np.float64)


def test_the_pixels_gradient_is_the_films_in_expectation(model):
    # A linear loss sum_p w_p . I_p: its gradient through any pixels is the film's adjoint pass's, in expectation.
    # Projected on the whole grid and on a ramp across it (a direction the lights make uneven), over independent
    # seeds.
    direction = np.linspace(0.0, 1.0, 8)[None, None, :, None] ** 2 * np.ones(model.sigma_t.shape)
    ours = np.array([[g.sum(), (g * direction).sum()] for g in (_our_gradient(model, 11 + 7 * k, 256)
                                                                for k in range(4))])
    film = np.array([[g.sum(), (g * direction).sum()] for g in (_film_gradient(model, 101 + 7 * k, 256)
                                                                for k in range(4))])
    se = np.sqrt(ours.var(axis=0, ddof=1) / 4 + film.var(axis=0, ddof=1) / 4)
    z = np.abs(ours.mean(axis=0) - film.mean(axis=0)) / se
    assert np.all(z < 4.5), (ours.mean(axis=0), film.mean(axis=0), z)
    assert np.all(np.abs(ours.mean(axis=0)) > 3 * se)  # the gradient is measured, not noise
    assert np.allclose(ours.mean(axis=0), film.mean(axis=0), rtol=0.1), (ours.mean(axis=0), film.mean(axis=0))
