"""``mitsuba-inverse`` on a tiny generated dataset: it trains, upsamples, clamps, evaluates and resumes."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.train.checkpoint import capture, restore_optimizer
from mitsnerf.errors import DatasetError
from mitsnerf.train.evaluate import render_views, stack_rgb
from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.metrics import psnr
from mitsnerf.methods.base import SceneInfo
from mitsnerf.methods.mitsuba_inverse import MitsubaInverseConfig, MitsubaInverseModel
from mitsnerf.render.background import ConstantBackground
from mitsnerf.train import PixelData, TrainConfig, TrainState, make_optimizer, train

from ..conftest import tiny_scene

TINY = tiny_scene({"name": "tiny-inverse", "description": "a 16^3 cloud, 12x12 views", "cameras.n_train": 4,
                   "cameras.width": 12, "cameras.height": 12, "render.spp_train": 32, "render.spp_test": 32,
                   "render.max_depth": 8, "render.noise_floor": False})

CONFIG = MitsubaInverseConfig(resolutions=(8, 16), upsample_at=(10,), spp=16, eval_spp=32, sigma_t_max=40.0, lr=1.0)
FLAT = TrainConfig(steps=20, log_every=5, lr_final_factor=1.0)  # no decay: 20 steps only


def _mean_psnr(model, images, cameras) -> float:
    return float(np.mean(psnr(np.clip(stack_rgb(render_views(model, cameras)[0]), 0, 1), np.clip(images, 0, 1))))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.runs.fit import scene_info
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import parse_scene

    root = generate_dataset(parse_scene(TINY, "tiny"), tmp_path_factory.mktemp("inverse"), progress=False)
    dataset = load_dataset(root)
    views = dataset.views("train")
    return dataset, scene_info(dataset, views.images), PixelData.from_views(views.images, views.cameras)


def test_a_few_steps_lower_the_image_error_and_upsample(tiny):
    dataset, info, data = tiny
    model = MitsubaInverseModel(CONFIG, info)
    assert model.max_depth == 8  # the dataset's, not prbvolpath's default 6
    before = _mean_psnr(model, data.images, data.cameras)
    result, opt = train(model, data, FLAT, CONFIG.lr, progress=False)
    after = _mean_psnr(model, data.images, data.cameras)
    assert after > before + 1.0, (before, after)
    assert result.steps == 20 and result.rays_per_s > 0
    assert model.resolution == 16 and opt["sigma_t"].shape == (16, 16, 16, 1) and opt["albedo"].shape == (16, 16, 16, 3)
    sigma = np.asarray(model.sigma_t)
    assert sigma.min() >= 0 and sigma.max() <= CONFIG.sigma_t_max
    assert model.lr_scales(9) == {"sigma_t": 1.0, "albedo": CONFIG.albedo_lr_factor}
    assert model.lr_scales(10)["sigma_t"] == 0.5

    test = dataset.views("test")
    rendered = render_views(model, test.cameras)[0][0]
    assert rendered.rgb.shape == (12, 12, 3) and rendered.opacity.shape == (12, 12)
    assert 0 < rendered.opacity.max() <= 1
    field_sigma = model.field().density(mi.Array3f(0.0, 0.0, 0.0))
    assert np.asarray(field_sigma)[0] > CONFIG.init_sigma_t  # the cloud's centre got denser


def test_a_checkpoint_restores_the_upsampled_grids(tiny):
    _, info, data = tiny
    model = MitsubaInverseModel(CONFIG, info)
    _, opt = train(model, data, TrainConfig(steps=11, log_every=11), CONFIG.lr, progress=False)
    ckpt = capture(11, opt)
    fresh = MitsubaInverseModel(CONFIG, info)
    opt2 = make_optimizer(fresh, CONFIG.lr)
    restore_optimizer(opt2, ckpt)
    fresh.set_parameters(opt2)
    assert fresh.resolution == 16
    np.testing.assert_array_equal(np.asarray(fresh.sigma_t), np.asarray(model.sigma_t))
    result, _ = train(fresh, data, TrainConfig(steps=12, log_every=1), CONFIG.lr, state=TrainState(opt2, 11),
                      progress=False)
    assert result.steps == 12 and np.isfinite(result.final_loss)


def test_a_fixed_albedo_is_not_optimised(tiny):
    _, info, data = tiny
    model = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=2, optimize_albedo=False), info)
    assert set(model.parameters()) == {"sigma_t"} and set(model.lr_scales(0)) == {"sigma_t"}
    train(model, data, TrainConfig(steps=2, log_every=1), 0.5, progress=False)
    np.testing.assert_array_equal(np.asarray(model.albedo), np.float32(0.6))


def test_it_needs_a_generated_dataset_and_valid_settings():
    info = SceneInfo(UNIT_BOX, ConstantBackground((1, 1, 1)), 1.0)
    with pytest.raises(DatasetError, match="mitsnerf generate"):
        MitsubaInverseModel(CONFIG, info)
    with pytest.raises(ValueError, match="upsample_at"):
        MitsubaInverseConfig(resolutions=(8, 16), upsample_at=())


def test_the_sparsity_prior_lowers_the_extinction(tiny):
    _, info, data = tiny
    means = {}
    for l1 in (0.0, 50.0):
        model = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=4, l1=l1), info)
        train(model, data, TrainConfig(steps=4, log_every=4, seed=3), 0.5, progress=False)
        means[l1] = float(np.mean(np.asarray(model.sigma_t)))
    assert means[50.0] < means[0.0] - 0.1, means


def test_the_emptiness_mask_zeroes_the_voxels_that_unattenuated_pixels_cross(tiny):
    from mitsnerf.methods.mitsuba_inverse import carve_mask, unattenuated_pixels

    _, info, data = tiny
    empty = unattenuated_pixels(data.images, data.cameras, info.background, 1e-4)
    assert 0 < np.mean(np.concatenate(empty)) < 1  # the views show both the sky and the medium
    assert carve_mask(data.cameras, [np.zeros_like(e) for e in empty], info.box, 8).all()
    assert not carve_mask(data.cameras, [np.ones_like(e) for e in empty], info.box, 8)[4, 4, 4]  # centre seen
    config = MitsubaInverseConfig(resolutions=(8, 16), upsample_at=(2,), spp=4, carve=True)
    model = MitsubaInverseModel(config, info)
    train(model, data, TrainConfig(steps=3, log_every=3), 0.5, progress=False)
    keep = carve_mask(data.cameras, empty, info.box, 16)
    assert 0 < keep.mean() < 1, keep.mean()
    sigma = np.asarray(model.sigma_t)[..., 0]
    assert np.all(sigma[~keep] == 0) and sigma[keep].mean() > 0


def test_late_samples_are_used_from_their_step(tiny):
    _, info, _ = tiny
    model = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=4, spp_late=16,
                                                     spp_late_at=5), info)
    assert [model.spp_at(s) for s in (0, 4, 5, 9)] == [4, 4, 16, 16]
    with pytest.raises(ValueError, match="spp_late_at"):
        MitsubaInverseConfig(spp_late=32)


def test_a_zero_start_learns_only_under_a_fixed_majorant(tiny):
    _, info, data = tiny
    means = {}
    for majorant in (0.0, 20.0):
        config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=4, init_sigma_t=0.0, majorant=majorant,
                                      sigma_t_max=40.0)
        model = MitsubaInverseModel(config, info)
        train(model, data, TrainConfig(steps=4, log_every=4), 0.5, progress=False)
        means[majorant] = float(np.mean(np.asarray(model.sigma_t)))
        assert np.asarray(model.sigma_t).max() <= config.sigma_t_clamp == (majorant or 40.0)
    assert means[0.0] == 0.0 and means[20.0] > 0.01, means  # no collisions, no gradient under a zero maximum


def test_several_views_per_step_are_rendered_and_averaged(tiny):
    from mitsnerf.train.schedule import step_rng

    _, info, data = tiny
    model = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=2, views_per_step=3), info)
    step = model.training_loss(data, 0, step_rng(0, 0))
    assert step.rays == 3 * 12 * 12 and np.isfinite(float(step.mse[0]))
