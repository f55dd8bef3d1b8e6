"""``mitsuba-inverse`` on a tiny generated dataset: it trains, upsamples, clamps, evaluates and resumes."""

from __future__ import annotations

from dataclasses import replace

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.errors import DatasetError
from mitsnerf.fields.grid import GridField
from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.metrics import psnr
from mitsnerf.methods.base import SceneInfo
from mitsnerf.methods.mitsuba_inverse import MitsubaInverseConfig, MitsubaInverseModel
from mitsnerf.render.background import ConstantBackground
from mitsnerf.scene.to_mitsuba import volume_grids
from mitsnerf.train import PixelData, TrainConfig, TrainState, make_optimizer, train
from mitsnerf.train.checkpoint import capture, restore_optimizer
from mitsnerf.train.evaluate import render_views, stack_rgb
from mitsnerf.train.schedule import step_rng

from ..conftest import tiny_scene

TINY = tiny_scene({"name": "tiny-inverse", "description": "a 16^3 cloud, 12x12 views", "cameras.n_train": 4,
                   "cameras.width": 12, "cameras.height": 12, "render.spp_train": 32, "render.spp_test": 32,
                   "render.max_depth": 8, "render.noise_floor": False})

CONFIG = MitsubaInverseConfig(resolutions=(8, 16), upsample_at=(0.5,), lr_decay_at=(0.8,), upsample_lr_factor=0.5,
                              spp=4, eval_spp=32, depth_max=40.0, lr=1.0, init_depth=1.0)
FLAT = TrainConfig(steps=20, log_every=5, lr_final_factor=1.0, batch_rays=512)  # no decay: 20 steps only


def _mean_psnr(model, images, cameras) -> float:
    return float(np.mean(psnr(np.clip(stack_rgb(render_views(model, cameras)[0]), 0, 1), np.clip(images, 0, 1))))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.runs.fit import scene_info
    from mitsnerf.scene.spec import parse_scene

    root = generate_dataset(parse_scene(TINY, "tiny"), tmp_path_factory.mktemp("inverse"), progress=False)
    dataset = load_dataset(root)
    views = dataset.views("train")
    return dataset, scene_info(dataset, views), PixelData.from_views(views.images, views.cameras)


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
    assert sigma.min() >= 0 and sigma.max() <= CONFIG.depth_max
    assert model.lr_scales(9) == {"sigma_t": 1.0, "albedo": CONFIG.albedo_lr_factor}
    assert model.lr_scales(10)["sigma_t"] == 0.5 and model.lr_scales(15)["sigma_t"] == 0.5
    assert model.lr_scales(16)["sigma_t"] == 0.25  # halved at 80% of the 20 steps

    test = dataset.views("test")
    rendered = render_views(model, test.cameras)[0][0]
    assert rendered.rgb.shape == (12, 12, 3) and rendered.opacity.shape == (12, 12)
    assert 0 < rendered.opacity.max() <= 1
    field_sigma = model.field().density(mi.Array3f(0.0, 0.0, 0.0))
    assert np.asarray(field_sigma)[0] > CONFIG.init_depth  # the centre got denser (unit box: tau = sigma_t)


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
    config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=2, optimize_albedo=False)
    model = MitsubaInverseModel(config, info)
    model.set_budget(2)
    assert set(model.parameters()) == {"sigma_t"} and set(model.lr_scales(0)) == {"sigma_t"}
    assert model.given() == ("lights", "phase function", "albedo")
    given = np.asarray(model.albedo).copy()
    truth = volume_grids(model.spec)[1]
    assert given.shape == (8, 8, 8, 3) and abs(given.mean() - truth.mean()) < 0.02  # the spec's, resampled
    train(model, data, TrainConfig(steps=2, log_every=1, batch_rays=64), 0.5, progress=False)
    np.testing.assert_array_equal(np.asarray(model.albedo), given)


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
        config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=4, l1=l1, carve=False, init_depth=1.0)
        model = MitsubaInverseModel(config, info)
        train(model, data, TrainConfig(steps=4, log_every=4, seed=3), 0.5, progress=False)
        means[l1] = float(np.mean(np.asarray(model.sigma_t)))
    assert means[50.0] < means[0.0] - 0.1, means


def test_the_emptiness_mask_zeroes_the_voxels_that_unattenuated_pixels_cross(tiny):
    from mitsnerf.math.carve import carve_mask, unattenuated_pixels

    _, info, data = tiny
    empty = unattenuated_pixels(data.images, data.cameras, info.background, 1e-4)
    assert 0 < np.mean(np.concatenate(empty)) < 1  # the views show both the sky and the medium
    assert carve_mask(data.cameras, [np.zeros_like(e) for e in empty], info.box, 8).all()
    assert not carve_mask(data.cameras, [np.ones_like(e) for e in empty], info.box, 8)[4, 4, 4]  # centre seen
    config = MitsubaInverseConfig(resolutions=(8, 16), upsample_at=(0.5,), spp=4, carve=True)
    model = MitsubaInverseModel(config, info)
    train(model, data, TrainConfig(steps=3, log_every=3), 0.5, progress=False)
    keep = carve_mask(data.cameras, empty, info.box, 16)
    assert 0 < keep.mean() < 1, keep.mean()
    sigma = np.asarray(model.sigma_t)[..., 0]
    assert np.all(sigma[~keep] == 0) and sigma[keep].mean() > 0


def test_a_step_traces_the_primal_at_its_multiple_of_the_gradients_paths(tiny):
    _, info, data = tiny
    model = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=3, spp_primal_factor=5),
                                info)
    assert model.samples_per_ray() == 3 * 6
    step = model.pixel_batch_loss(data, 100, 0, step_rng(0, 0))
    assert step.rays == 100 and np.isfinite(float(step.mse[0]))


def test_a_zero_start_learns_under_a_majorant_floor_and_not_under_prbvolpaths_grid_maximum(tiny):
    _, info, data = tiny
    means = {}
    for name, settings in {"prbvolpath": {"estimator": "prbvolpath"},
                           "prbvolpath, majorant 20": {"estimator": "prbvolpath", "majorant_depth": 20.0},
                           "drt": {}, "drt, no floor": {"majorant_floor": 0.0}}.items():
        config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=4, init_depth=0.0, depth_max=40.0,
                                      **settings)
        model = MitsubaInverseModel(config, info)
        train(model, data, TrainConfig(steps=4, log_every=4), 0.5, progress=False)
        means[name] = float(np.mean(np.asarray(model.sigma_t)))
        assert np.asarray(model.sigma_t).max() <= config.depth_clamp
    # No collisions, no gradient: under a zero grid maximum, or a majorant grid without its floor.
    assert means["prbvolpath"] == 0.0 and means["drt, no floor"] == 0.0, means
    assert means["prbvolpath, majorant 20"] > 0.01 and means["drt"] > 0.01, means


def test_several_views_per_step_are_rendered_and_averaged(tiny):
    _, info, data = tiny
    model = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=2, views_per_step=3,
                                                     batch="views"), info)
    step = model.pixel_batch_loss(data, 64, 0, step_rng(0, 0))
    assert step.rays == 3 * 12 * 12 and np.isfinite(float(step.mse[0]))


def test_the_batch_sensor_renders_every_view_in_order_at_its_coarse_size(tiny):
    """batch = "sensor": one render holds every training view at 1/2 of its size, side by side in the cameras'
    order; at the true medium each tile matches its own view's box-averaged image, not another view's."""
    _, info, data = tiny
    config = MitsubaInverseConfig(resolutions=(16,), upsample_at=(), init_from="truth", batch="sensor",
                                  sensor_scale=2, spp=2)
    model = MitsubaInverseModel(config, info)
    step = model.pixel_batch_loss(data, 64, 0, step_rng(0, 0))
    assert step.rays == 4 * 6 * 6 and np.isfinite(float(step.mse[0]))
    sensor, target = model._batch_sensor
    with dr.suspend_grad():
        image = np.array(mi.render(model.scene, sensor=sensor, spp=256, seed=1))
    tiles, targets = np.split(image, 4, axis=1), np.split(np.array(target), 4, axis=1)
    mse = np.array([[np.mean((tile - want) ** 2) for want in targets] for tile in tiles])
    own, others = np.diag(mse), mse[~np.eye(4, dtype=bool)].reshape(4, 3)
    assert np.all(own < 0.25 * others.min(axis=1)), mse
    box = np.asarray(data.images[2], np.float32).reshape(6, 2, 6, 2, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(targets[2], box, rtol=1e-6)


def test_a_sensor_scale_that_does_not_divide_the_views_is_refused_in_one_line(tiny):
    from mitsnerf.errors import SpecError

    _, info, _ = tiny
    with pytest.raises(SpecError, match=r"^sensor_scale: must divide the training views' 12 x 12 pixels, got 5$"):
        MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), batch="sensor", sensor_scale=5),
                            info)


def test_more_views_per_step_than_the_data_has_is_refused_in_one_line(tiny, monkeypatch):
    """views_per_step above the 4 training views path-traced the same views again each step without a word; with
    whole views a step (batch = "views") it is refused before the model builds anything, naming the field and the
    data's count (with ray batches the setting is unused). emissive_rays is bounded as a step's batch_rays is."""
    from mitsnerf.config import from_dict
    from mitsnerf.errors import SpecError

    _, info, _ = tiny
    monkeypatch.setattr(mi, "load_dict", lambda *a, **k: pytest.fail("built a scene before refusing"))
    monkeypatch.setattr(MitsubaInverseModel, "_emptiness_masks", lambda *a: pytest.fail("carved before refusing"))
    with pytest.raises(SpecError, match=r"^views_per_step: must be at most the dataset's 4 training views .*"
                                        r"got 5$"):
        MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), views_per_step=5, batch="views"),
                            info)
    with pytest.raises(SpecError, match=r"^emissive_rays: must be an integer in \[1, 4194304\], got 100000000$"):
        from_dict(MitsubaInverseConfig, {"emissive_rays": 10**8})


def _info(overrides: dict) -> SceneInfo:
    """The scene a model sees, from a spec alone (no images are needed to build one)."""
    from mitsnerf.scene.spec import parse_scene
    from mitsnerf.scene.to_mitsuba import scene_box

    spec = tiny_scene(overrides)
    return SceneInfo(scene_box(parse_scene(spec, "tiny")), ConstantBackground((0.5, 0.55, 0.6)), 1.0, {"spec": spec})


def test_its_settings_are_optical_depths_whatever_the_box():
    # The same config in a box twice as large: the same optical depths, half the extinction per unit length.
    config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), init_depth=4.0, majorant_floor=3.0, carve=False)
    for scale in (1.0, 2.0):
        model = MitsubaInverseModel(config, _info({"world.scale": scale}))
        assert model.side == scale
        np.testing.assert_allclose(np.asarray(model.sigma_t), 4.0)
        density = model.field().density(mi.Array3f(0.1 * scale, 0.0, -0.2 * scale))
        assert np.asarray(density)[0] == pytest.approx(4.0 / scale)
        assert model.scene.integrator().majorant_floor == pytest.approx(3.0 / scale)


def test_a_chromatic_spec_gets_one_extinction_per_colour():
    chromatic = _info({"volume.sigma_t_scale": [20.0, 30.0, 45.0]})
    free = MitsubaInverseConfig(carve=False)
    assert MitsubaInverseModel(free, chromatic).sigma_t.shape[-1] == 3
    assert MitsubaInverseModel(replace(free, density_channels=1), chromatic).sigma_t.shape[-1] == 1
    assert MitsubaInverseModel(free, _info({})).sigma_t.shape[-1] == 1


@pytest.mark.parametrize("estimator", ["drt", "prbvolpath"])
def test_three_extinction_channels_train(tiny, estimator):
    _, info, data = tiny
    config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=4, density_channels=3, estimator=estimator)
    model = MitsubaInverseModel(config, info)
    before = np.asarray(model.sigma_t).copy()
    train(model, data, TrainConfig(steps=3, log_every=3), 0.5, progress=False)
    after = np.asarray(model.sigma_t)
    assert after.shape == (8, 8, 8, 3) and model.field().sigma_channels == 3
    changed = np.abs(after - before).reshape(-1, 3).sum(axis=0)
    assert np.all(changed > 0), changed  # every channel got its own gradient
    assert not np.allclose(after[..., 0], after[..., 2])


def _export(tmp_path, model_box, blob):
    from mitsnerf.runs.export import export_field

    field = GridField.from_arrays(blob, model_box)
    export_field(field, tmp_path / "export", resolution=blob.shape[0], box=model_box, info={"method": "test"})
    (tmp_path / "config.json").write_text("{}")  # a run directory holding its export


def test_it_starts_from_another_runs_exported_density(tmp_path):
    info = _info({"world.scale": 2.0})
    z, y, x = np.meshgrid(*(np.linspace(-1, 1, 16),) * 3, indexing="ij")
    blob = (6.0 * np.exp(-(x**2 + y**2 + z**2) / 0.3)).astype(np.float32)  # world units^-1
    _export(tmp_path, info.box, blob)
    model = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(4, 8), upsample_at=(0.5,), init_from=str(tmp_path),
                                                     carve=False), info)
    tau = np.asarray(model.sigma_t)[..., 0]
    model.set_budget(10)
    assert tau.shape == (8, 8, 8) and model.level(0) == 1  # a start with its structure begins at the last resolution
    # tau = side x the exported density at the grid's voxel centres (world units^-1 there, trilinear)
    x = info.box.voxel_centres(8).reshape(-1, 3).astype(np.float32)
    exported = np.asarray(GridField.from_arrays(blob, info.box).density(mi.Array3f(*x.T))).reshape(8, 8, 8)
    np.testing.assert_allclose(tau, 2.0 * exported, rtol=1e-4, atol=1e-4)
    assert tau.max() > 5.0 and tau[0, 0, 0] < 0.05 * tau.max()
    # the export directory itself works as well as the run holding it
    config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), init_from=str(tmp_path / "export"), carve=False)
    again = MitsubaInverseModel(config, info)
    np.testing.assert_array_equal(np.asarray(again.sigma_t), np.asarray(model.sigma_t))


def test_the_albedo_follows_the_resolutions_up_to_its_own(tiny):
    _, info, data = tiny
    config = MitsubaInverseConfig(resolutions=(4, 8, 16), upsample_at=(0.3, 0.6), albedo_resolution=8, spp=2)
    model = MitsubaInverseModel(config, info)
    assert model.albedo.shape == (4, 4, 4, 3)
    train(model, data, TrainConfig(steps=5, log_every=5, batch_rays=64), 0.5, progress=False)
    assert model.sigma_t.shape == (16, 16, 16, 1) and model.albedo.shape == (8, 8, 8, 3)
    assert model.render_view(data.cameras[0]).rgb.shape == (12, 12, 3)


def test_the_truth_start_is_the_datasets_own_grids(tiny):
    dataset, info, _ = tiny
    by_name = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(16,), upsample_at=(), init_from="truth"), info)
    by_path = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(16,), upsample_at=(), init_from=str(dataset.root)),
                                  info)
    sigma, albedo = volume_grids(by_name.spec)  # the tiny spec's grids are 16^3: the start is them, carved
    keep = by_name._keep_mask(16)
    tau = np.asarray(by_name.sigma_t)[..., 0]
    np.testing.assert_allclose(tau, sigma * by_name.side * keep, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.asarray(by_name.albedo), albedo, atol=1e-5)
    np.testing.assert_allclose(np.asarray(by_path.sigma_t), np.asarray(by_name.sigma_t), rtol=1e-4, atol=1e-4)
    assert np.sum(sigma * (~keep)) < 1e-3 * np.sum(sigma)  # the mask carves none of the true mass


def test_a_run_without_an_export_is_one_clear_error(tmp_path):
    (tmp_path / "config.json").write_text("{}")
    with pytest.raises(DatasetError, match=r"init_from: no exported density .*run 'mitsnerf export"):
        MitsubaInverseModel(MitsubaInverseConfig(init_from=str(tmp_path), carve=False), _info({}))
    with pytest.raises(DatasetError, match="init_from: no exported density"):
        MitsubaInverseModel(MitsubaInverseConfig(init_from=str(tmp_path / "missing"), carve=False), _info({}))


def test_the_emissive_start_fits_an_emission_grid_then_hands_over(tiny):
    _, info, data = tiny
    config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=2, emissive_steps=6, emissive_rays=128,
                                  init_depth=2.0)
    model = MitsubaInverseModel(config, info)
    assert set(model.parameters()) == {"sigma_t", "albedo", "emission"}
    first = model.pixel_batch_loss(data, 64, 0, step_rng(0, 0))
    assert first.rays == 128
    emission = np.asarray(model.emission).copy()
    train(model, data, TrainConfig(steps=6, log_every=1, lr_final_factor=1.0), 0.5, progress=False)
    assert not np.allclose(np.asarray(model.emission), emission)
    assert float(model.pixel_batch_loss(data, 64, 0, step_rng(0, 0)).mse[0]) < float(first.mse[0])  # the same pixels
    assert model.pixel_batch_loss(data, 64, 6, step_rng(0, 6)).rays == 64  # the path tracer's batch


def test_total_variation_smooths_inside_the_mask_only(tiny):
    from mitsnerf.methods.inverse_start import masked_tv, tv_pairs

    keep = np.ones((4, 4, 4), bool)
    keep[:, :, :2] = False
    grid = mi.TensorXf(np.where(keep, 5.0, 0.0).astype(np.float32)[..., None])
    assert float(masked_tv(grid, tv_pairs(keep), 1)[0]) == 0.0  # the carved edge costs nothing
    assert float(masked_tv(grid, tv_pairs(np.ones((4, 4, 4), bool)), 1)[0]) > 0.0
    _, info, data = tiny
    tvs = {}
    for weight in (0.0, 200.0):
        config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=4, tv_sigma=weight, carve=True,
                                      init_depth=5.0)
        model = MitsubaInverseModel(config, info)
        train(model, data, TrainConfig(steps=4, log_every=4, seed=3), 0.5, progress=False)
        pairs = tv_pairs(model._keep_mask(8))
        tvs[weight] = float(masked_tv(model.sigma_t, pairs, 1)[0])
    assert tvs[200.0] < 0.7 * tvs[0.0], tvs


def test_the_switch_from_the_emissive_fit_is_not_taken_for_a_divergence(tiny):
    # The path tracer's loss carries its render noise, far above the emissive fit's: the trainer's divergence check
    # starts afresh at the switch instead of stopping the run. Its tight factor (1.5 over 2 intervals) at 1 spp is
    # within the path-traced loss's own noise, so the run's sequence is pinned: plain Adam's, whose losses after the
    # switch stay under the trip (the monitor, not the optimiser, is under test).
    _, info, data = tiny
    config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=1, spp_primal_factor=1, emissive_steps=6,
                                  emissive_rays=256, init_depth=2.0, optimizer="adam")
    model = MitsubaInverseModel(config, info)
    assert [model.objective_stage(s) for s in (0, 5, 6, 20)] == [0, 0, 1, 1]
    result, _ = train(model, data, TrainConfig(steps=14, log_every=1, divergence_factor=1.5, divergence_patience=2,
                                               batch_rays=128), 0.5, progress=False)
    losses = [h["loss"] for h in result.history]
    assert result.steps == 14 and np.median(losses[6:]) > 1.5 * min(losses[:6]), losses  # the jump it forgave


def test_the_albedo_can_be_fitted_first_with_the_extinction_held(tiny):
    _, info, data = tiny
    config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), spp=4, albedo_first=3, init_depth=4.0)
    model = MitsubaInverseModel(config, info)
    model.set_budget(5)
    assert model.lr_scales(2)["sigma_t"] == 0.0 and model.lr_scales(3)["sigma_t"] == 1.0
    sigma, albedo = np.asarray(model.sigma_t).copy(), np.asarray(model.albedo).copy()
    _, opt = train(model, data, TrainConfig(steps=3, log_every=3), 0.5, progress=False)
    np.testing.assert_array_equal(np.asarray(model.sigma_t), sigma)
    assert not np.allclose(np.asarray(model.albedo), albedo)
    train(model, data, TrainConfig(steps=5, log_every=5), 0.5, state=TrainState(opt, 3), progress=False)
    assert not np.allclose(np.asarray(model.sigma_t), sigma)
    with pytest.raises(ValueError, match="albedo_first"):
        MitsubaInverseConfig(albedo_first=2, optimize_albedo=False)


def test_the_trainer_builds_the_adam_variant_the_method_chooses(tiny):
    _, info, _ = tiny
    for name in ("adam", "sparse", "uniform", "amsgrad", "quantile"):
        model = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(8,), upsample_at=(), optimizer=name,
                                                         beta_1=0.8, moment_quantile=0.7), info)
        opt = make_optimizer(model, 0.5)
        assert (opt.mask_updates, opt.uniform, opt.amsgrad) == (name == "sparse", name == "uniform",
                                                               name == "amsgrad")
        assert opt.beta_1 == 0.8 and set(opt.keys()) == set(model.parameters())
        assert getattr(opt, "quantile", None) == (0.7 if name == "quantile" else None)


def _noise_and_signal(info, **settings) -> tuple[float, float]:
    """Mean extinction, after 100 steps from an empty 8^3 grid, of the voxels whose gradient is only weak
    zero-mean noise (a voxel few paths see), and of those pulled steadily toward density (one the views fix):
    the optimiser the trainer builds for the method, its learning rate and the method's own clamp at 0."""
    from mitsnerf.train.step import apply_step

    config = MitsubaInverseConfig(resolutions=(8,), upsample_at=(), lr_decay_at=(), carve=False, init_depth=0.0,
                                  optimize_albedo=False, **settings)
    model = MitsubaInverseModel(config, info)
    model.set_budget(100)
    opt = make_optimizer(model, config.lr)
    seen = np.zeros((8, 8, 8, 1), bool)
    seen[:4] = True
    rng = np.random.default_rng(0)
    for step in range(100):
        g = np.where(seen, -1.0, 0.01 * rng.standard_normal(seen.shape)).astype(np.float32)
        dr.backward(dr.sum(opt["sigma_t"] * mi.TensorXf(g), axis=None))
        apply_step(model, opt, step)
    tau = np.asarray(model.sigma_t)
    return float(tau[~seen].mean()), float(tau[seen].mean())


def test_noise_alone_does_not_grow_the_extinction(tiny):
    """The smoke's excess mass (docs/notes/mitsuba-inverse.md, "The smoke's mass, diagnosed"): plain Adam steps
    every voxel by about the learning rate whatever its gradient's size, so a voxel whose gradient is noise
    random-walks as far as one the views fix, and the clamp at 0 turns the walk into growth (here to about 6 x
    the learning rate). The method's optimiser moves a voxel in proportion to its gradient: the noise-only voxels
    stay within a tenth of a step of empty while the others fill."""
    _, info, _ = tiny
    noise, signal = _noise_and_signal(info)
    assert signal > 10.0, signal
    assert noise < 0.1 * MitsubaInverseConfig().lr, (noise, signal)
