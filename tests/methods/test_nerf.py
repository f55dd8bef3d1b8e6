import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.nerf import NeRFConfig
from mitsnerf.methods.base import SceneInfo
from mitsnerf.methods.nerf import NeRFMethodConfig, NeRFModel
from mitsnerf.render.background import ConstantBackground
from mitsnerf.train import TrainConfig, train
from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.rays import RayBatch

SMALL = NeRFConfig(width=32, depth=2, pos_octaves=6)


def _colour_and_density_along_two_directions(network: NeRFConfig):
    info = SceneInfo(UNIT_BOX, ConstantBackground((0, 0, 0)), 1.0)
    model = NeRFModel(NeRFMethodConfig(network=network), info)
    x = mi.Array3f([0.1, 0.1], [0.2, 0.2], [-0.3, -0.3])
    d = mi.Array3f([1.0, 0.0], [0.0, 0.0], [0.0, 1.0])
    rgb, sigma = model.field()(x, d)
    return np.asarray(rgb.x), np.asarray(sigma)


def test_nerf_density_depends_on_position_only_and_colour_on_the_direction_when_asked():
    r, s = _colour_and_density_along_two_directions(NeRFConfig(width=16, depth=2, use_direction=True))
    assert s[0] == s[1]
    assert not np.allclose(r[0], r[1])


def test_without_the_direction_input_the_colour_is_the_same_from_every_direction():
    r, s = _colour_and_density_along_two_directions(NeRFConfig(width=16, depth=2, use_direction=False))
    assert s[0] == s[1] and r[0] == r[1]


def test_the_direction_encoding_is_nerfs():
    """``gamma((d + 1) / 2)`` at period 1 is ``sin(2^k pi d)`` up to sign (NeRF's encoding of d)."""
    import drjit.nn as nn

    d = np.linspace(-1.0, 1.0, 9, dtype=np.float32)
    enc = nn.SinEncode(3)(mi.TensorXf(np.array([(d + 1) / 2], np.float32)))
    got = np.asarray(enc)[[0, 2, 4], :]  # the sines of octaves 0, 1, 2
    want = np.stack([np.sin(2.0**k * np.pi * d) for k in range(3)])
    assert np.allclose(np.abs(got), np.abs(want), atol=1e-5)


def test_the_default_is_nerfs_design_without_the_direction():
    config = NeRFMethodConfig()
    assert config.n_importance > 0 and config.coarse_network.width <= config.network.width
    assert (config.network.pos_octaves, config.network.use_direction) == (4, False)
    assert config.network.dir_octaves == 4  # NeRF's, when use_direction is set
    assert config.network.skip is not None and config.network.skip < config.network.depth


def test_single_pass_training_lowers_the_loss(tiny_views):
    data, info = tiny_views()
    model = NeRFModel(NeRFMethodConfig.single_pass(24, network=SMALL), info)
    assert not model.hierarchical and not any(k.startswith("coarse.") for k in model.parameters())
    result, _ = train(model, data, TrainConfig(steps=80, batch_rays=256, log_every=10), 2e-2, progress=False)
    losses = [h["loss"] for h in result.history]
    assert result.steps == 80
    assert np.mean(losses[-2:]) < 0.5 * losses[0]
    assert result.rays_per_s > 0
    assert result.samples_per_s == pytest.approx(result.rays_per_s * 24)


def test_training_on_cooperative_vectors_follows_tensor_mode_and_its_weights_render_on_either(tiny_views,
                                                                                            require_network_path):
    """The same seed and batches on both paths: the fp32 losses agree to round-off growing over the steps,
    and the trained parameters, shared by the paths, render the same image on each."""
    import dataclasses

    require_network_path("coopvec-fp32")
    data, info = tiny_views()
    losses, models = {}, {}
    for path in ("tensor", "coopvec-fp32"):
        config = NeRFMethodConfig.single_pass(16, network=dataclasses.replace(SMALL, network_path=path))
        models[path] = NeRFModel(config, info)
        result, _ = train(models[path], data, TrainConfig(steps=30, batch_rays=128, log_every=10), 2e-2, progress=False)
        losses[path] = [h["loss"] for h in result.history]
    np.testing.assert_allclose(losses["coopvec-fp32"], losses["tensor"], rtol=1e-3)
    assert losses["tensor"][-1] < 0.7 * losses["tensor"][0]
    x, d = mi.Array3f([0.1, -0.2], [0.0, 0.1], [0.05, 0.2]), mi.Array3f(0.0, 0.0, 1.0)
    models["tensor"].set_parameters(dict(models["coopvec-fp32"].parameters().items()))
    (rgb_c, sigma_c), (rgb_t, sigma_t) = (models[p].field()(x, d) for p in ("coopvec-fp32", "tensor"))
    for a, b in zip((*rgb_c, sigma_c), (*rgb_t, sigma_t)):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-5, atol=1e-6)


def test_hierarchical_training_lowers_both_losses(tiny_views):
    data, info = tiny_views()
    config = NeRFMethodConfig(network=SMALL, coarse_network=NeRFConfig(width=16, depth=1, pos_octaves=4),
                              n_samples=12, n_importance=16)
    model = NeRFModel(config, info)
    params = model.parameters()
    assert "coarse.trunk.0.weights" in params and "fine.trunk.0.weights" in params
    assert model.jitter_size() == 28 and model.samples_per_ray() == 12 + 28

    rays = RayBatch(*data.pixels.rays(mi.UInt32(np.arange(64, dtype=np.uint32)), mi.Float(0.5), mi.Float(0.5)))
    target = dr.gather(mi.Array3f, data.rgb, mi.UInt32(np.arange(64, dtype=np.uint32)))

    def errors():
        with dr.suspend_grad():
            out = model.render_rays(rays.o, rays.d, u=dr.full(mi.Float, 0.5, 64 * 28), training=True)
        fine = dr.mean(dr.square(out.rgb - target), axis=None)[0]
        coarse = dr.mean(dr.square(out.aux_rgb["coarse"] - target), axis=None)[0]
        return fine, coarse

    fine0, coarse0 = errors()
    train(model, data, TrainConfig(steps=80, batch_rays=256, log_every=10), 2e-2, progress=False)
    fine1, coarse1 = errors()
    assert fine1 < 0.3 * fine0 and coarse1 < 0.3 * coarse0
    # evaluation renders the fine pass only, deterministically
    a = model.render_rays(rays.o, rays.d).rgb
    b = model.render_rays(rays.o, rays.d).rgb
    assert model.render_rays(rays.o, rays.d).aux_rgb is None
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_fine_samples_gather_where_the_coarse_weights_are(tiny_views):
    # Ground truth as the "coarse network": the importance samples of rays through the blob
    # must crowd into it.
    from mitsnerf.fields.grid import GridField
    from mitsnerf.math.composite import weights
    from mitsnerf.math.sampling import sample_pdf
    from mitsnerf.methods.nerf import coarse_edges, importance_strata
    from mitsnerf.render.volume import sample_rays

    blob = np.zeros((16, 16, 16), np.float32)
    blob[7:9, 7:9, 7:9] = 50.0
    gt = GridField.from_arrays(blob, UNIT_BOX)
    o, d = mi.Array3f(0.0, 0.0, -2.0), mi.Array3f(0.0, 0.0, 1.0)
    s, _ = sample_rays(o, d, 32, UNIT_BOX)
    w, _ = weights(gt.density(s.x), s.delta, 32)
    _, t_f, _ = UNIT_BOX.intersect(o, d)
    t = np.asarray(sample_pdf(coarse_edges(s.t, t_f, 32), w, 32, 64, importance_strata(1, 64, None, mi.Float)))
    z = -2.0 + t
    assert np.mean(np.abs(z) < 0.15) > 0.9


def test_training_is_deterministic_for_a_seed(tiny_views):
    data, info = tiny_views(n_views=3, size=8)
    params = []
    for _ in range(2):
        config = NeRFMethodConfig(network=NeRFConfig(width=8, depth=1), n_samples=8, n_importance=8)
        model = NeRFModel(config, info, seed=3)
        train(model, data, TrainConfig(steps=5, batch_rays=64, seed=7), 1e-2, progress=False)
        params.append({k: np.asarray(v) for k, v in model.parameters().items()})
    # Equal up to float rounding: Dr.Jit's LLVM matrix product reduces the weight gradient
    # over points on several threads, and one run in many differs by an ulp there.
    for key in params[0]:
        np.testing.assert_allclose(params[0][key], params[1][key], rtol=1e-5, atol=1e-8)


def test_config_is_validated():
    with pytest.raises(ValueError, match="n_importance"):
        NeRFMethodConfig(n_importance=-1)
    with pytest.raises(ValueError, match="skip"):
        NeRFConfig(skip=-1)


def test_empty_space_skipping_is_exact_where_it_claims(blob_grid):
    """Both passes skip what the grid marks empty. With a medium of compact support (as the scenes' are:
    exactly 0 beyond their envelope) as both networks, nothing of it lies below the grid's threshold, so
    the render with skipping equals the unskipped one while most samples are never evaluated. (Where a
    medium has long thin tails, the difference is bounded by the skipped optical depth:
    tests/fields/test_occupancy.py.)"""
    blob_grid = np.where(blob_grid > 1.0, blob_grid, 0.0).astype(np.float32)  # compact support
    from mitsnerf.fields.grid import GridField
    from mitsnerf.fields.occupancy import OccupancyConfig
    from mitsnerf.math.camera import Camera, look_at
    from mitsnerf.math.rays import camera_rays

    info = SceneInfo(UNIT_BOX, ConstantBackground((0.2, 0.3, 0.4)), 1.0)
    config = NeRFMethodConfig(network=SMALL, coarse_network=SMALL, n_samples=32, n_importance=32,
                              occupancy=OccupancyConfig(resolution=24, update_every=1))
    model = NeRFModel(config, info)
    truth = GridField.from_arrays(blob_grid, UNIT_BOX, color=(1.0, 0.9, 0.1))
    model.base_field, model._coarse = truth, truth  # the true field as the fine and the coarse network
    model.grid.update(truth.density, seed=0, step=0)
    cams = [Camera.from_fov(look_at(p), 12, 12, 40.0) for p in ((0.0, -2.0, 0.3), (1.5, 1.2, -0.4))]
    rays = camera_rays(mi.Array3f, cams)
    with dr.suspend_grad():
        skipped = model.render_rays(rays.o, rays.d).rgb
        mask = model.grid.sample_mask(*_fine_samples(model, rays))
        grid, model.grid = model.grid, None
        full = model.render_rays(rays.o, rays.d).rgb
    diff = max(float(dr.max(dr.abs(a - b))[0]) for a, b in zip(skipped, full))
    assert diff < 1e-4, diff
    assert 0.01 < float(dr.mean(mi.Float(mask))[0]) < 0.4  # most fine samples are never evaluated


def _fine_samples(model, rays):
    """Positions and deltas of stratified samples (the density the grid's mask needs), N = 64 per ray."""
    from mitsnerf.render.volume import sample_rays

    s, _ = sample_rays(rays.o, rays.d, 64, UNIT_BOX)
    return s.x, s.delta, 64


def test_proposal_sampling_trains_the_fine_network_and_the_proposal(tiny_views):
    data, info = tiny_views()
    config = NeRFMethodConfig(network=SMALL, sampler="proposal", n_samples=16, n_importance=16)
    model = NeRFModel(config, info)
    params = model.parameters()
    assert "coarse.trunk.0.weights" in params and "coarse.head.0.weights" not in params  # density only
    assert model.samples_per_ray() == 32 and model.jitter_size() == 32
    before = {k: np.array(v) for k, v in params.items() if k.startswith("coarse.")}
    result, _ = train(model, data, TrainConfig(steps=60, batch_rays=256, log_every=10), 2e-2, progress=False)
    losses = [h["loss"] for h in result.history]
    assert np.mean(losses[-2:]) < 0.5 * losses[0]
    moved = [k for k, v in before.items() if not np.array_equal(v, np.array(model.parameters()[k]))]
    assert moved  # the interlevel loss reaches the proposal network
    rays = RayBatch(*data.pixels.rays(mi.UInt32(np.arange(64, dtype=np.uint32)), mi.Float(0.5), mi.Float(0.5)))
    out = model.render_rays(rays.o, rays.d)
    assert not out.extra_losses and dr.all(dr.isfinite(out.rgb.x))


def test_parameters_of_another_shape_are_refused_by_name():
    from mitsnerf.methods.base import ParameterShapeError

    info = SceneInfo(UNIT_BOX, ConstantBackground((0, 0, 0)), 1.0)
    model = NeRFModel(NeRFMethodConfig(network=NeRFConfig(width=16, depth=2)), info)
    wrong = dr.zeros(mi.TensorXf, (16, 3))
    with pytest.raises(ParameterShapeError, match=r"has shape \(16, 3\), the method's config builds \(16, 27\)") as e:
        model.set_parameters({"fine.trunk.0.weights": wrong})
    assert e.value.key == "fine.trunk.0.weights"


def test_a_bright_colour_range_does_not_start_the_medium_empty(tiny_views, blob_grid):
    """cloud_hg85's training views hold the sun's forward peak (radiance ~10), so ``cover_radiance`` raises
    ``c_max`` to ~12: a colour head starting at ``c_max / 2`` (~6) on dim images made the fit clear the medium
    (the quickest way to darken every pixel) and the density never came back. It starts where it does with
    ``c_max = 1`` (0.5), so the fit finds the blob."""
    from dataclasses import replace

    data, info = tiny_views()
    bright = replace(info, radiance_max=10.0)
    model = NeRFModel(NeRFMethodConfig(network=SMALL, coarse_network=NeRFConfig(width=16, depth=1, pos_octaves=4),
                                       n_samples=12, n_importance=12), bright)
    assert model.base_field.config.c_max == pytest.approx(12.5)
    x = mi.Array3f(*(np.random.default_rng(1).uniform(-0.5, 0.5, (3, 512)).astype(np.float32)))
    rgb, _ = model.base_field(x, mi.Array3f(0.0, 0.0, 1.0))
    assert np.all(np.abs(np.asarray(rgb.x) - 0.5) < 0.3)
    train(model, data, TrainConfig(steps=60, batch_rays=256, log_every=10), 2e-2, progress=False)
    learned = float(np.mean(np.asarray(model.field().density(x))))
    true = float(np.mean(blob_grid))
    assert learned > 0.3 * true, (learned, true)
